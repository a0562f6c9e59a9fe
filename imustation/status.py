"""The capture status: one model of what a capture has recorded, from a live station or from its run file.

Three readers report a capture's progress: the station itself (``capture``'s
live status, ``--json-status`` and ``--status-file``, docs/capture.md), the
monitor beside a running capture (``/api/status``, docs/monitor.md) and
``imustation inspect`` on a file. They describe the same things - per device the
samples, the rate achieved against the rate configured, gaps, samples lost,
faults, the temperature; per thermometer its readings - and this module defines
them once:

* :class:`DeviceStatus`, :class:`ThermometerStatus`: the model;
* :func:`capture_status`: the station's status document (``imustation-status``)
  from its live counts;
* :class:`EventTally`, :func:`device_status_from_run`, :func:`thermometer_status`:
  the same model read back from a run file (its rows and its event log), for the
  monitor (which feeds the tally as the file grows) and ``inspect``.

Units: s, Hz, degC; times of a run file are ns since ``started_utc``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from imustation.runfile import DeviceInfo, Event, RunFile
from imustation.runfile.schema import LOSS_KINDS

#: the station's status document (docs/capture.md, "The live status")
STATUS_FORMAT = "imustation-status"
STATUS_VERSION = 1
#: station seconds over which a run file's recent rate is measured
RATE_WINDOW_S = 10.0


def finite(x: float | None) -> float | None:
    """``x``, or None for NaN, infinities and None (JSON has no NaN)."""
    return x if x is not None and math.isfinite(x) else None


@dataclass
class DeviceStatus:
    """One device as a status reports it.

    ``rate_hz``: samples per second achieved over the run (Hz); ``rate_recent_hz``:
    over a recent window (None where not measured); ``rate_cfg_hz``: configured.
    ``gaps``: loss events; ``lost``: samples they lost; ``faults``: bus/device
    faults (a stall included); ``temp_c``: the device's last temperature (degC) or None.
    ``state``: "ok"; "failed" while it is re-opened after a fault; "stalled" while it
    answers without delivering samples (live only; a run file's reader sets its own).
    From a run file only: ``events`` (all events of the device) and the times of
    its first and last sample (``first_t_s``, ``last_t_s``, s since the start).
    """

    rate_cfg_hz: float
    samples: int = 0
    gaps: int = 0
    lost: int = 0
    faults: int = 0
    temp_c: float | None = None
    state: str = "ok"
    rate_hz: float | None = None
    rate_recent_hz: float | None = None
    events: int = 0
    first_t_s: float | None = None
    last_t_s: float | None = None

    @property
    def duration_s(self) -> float:
        """Time the samples cover: first to last sample plus one configured period (s; 0 without samples)."""
        if self.first_t_s is None or self.last_t_s is None:
            return 0.0
        return self.last_t_s - self.first_t_s + 1.0 / self.rate_cfg_hz

    def live(self, station_s: float, recent_samples: int | None, window_s: float) -> DeviceStatus:
        """These counts with the live rates: samples over ``station_s`` (s of station time) and
        ``recent_samples`` over the last ``window_s`` wall seconds (None: not measured)."""
        recent = recent_samples / window_s if recent_samples is not None and window_s > 0 else None
        return replace(self, rate_hz=self.samples / station_s if station_s > 0 else 0.0, rate_recent_hz=recent)


@dataclass
class ThermometerStatus:
    """One thermometer: readings taken, readings missed (``lost``), faults, the last reading (degC)."""

    readings: int = 0
    lost: int = 0
    faults: int = 0
    celsius: float | None = None
    state: str = "ok"
    #: time of the last reading (s since the start; from a run file only)
    last_t_s: float | None = None


def capture_status(
    devices: Mapping[str, DeviceStatus],
    thermometers: Mapping[str, ThermometerStatus],
    *,
    state: str,
    reason: str,
    elapsed_s: float,
    duration_s: float,
    wall_s: float,
    file: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The station's status document (docs/capture.md): JSON-ready, NaN as None.

    ``state``: "recording", "done" or "stopped" (with ``reason``); ``elapsed_s``,
    ``duration_s``: station time recorded and planned (s); ``wall_s``: host s since
    the start; ``file``: the recorder's details (``file``, ``part``, ``file_bytes``,
    ``on_disk``, ``disk_free_bytes``), merged in.
    """
    status: dict[str, Any] = {
        "format": STATUS_FORMAT,
        "version": STATUS_VERSION,
        "state": state,
        "reason": reason,
        "elapsed_s": elapsed_s,
        "duration_s": duration_s,
        "remaining_s": max(0.0, duration_s - elapsed_s),
        "wall_s": wall_s,
        "speed": elapsed_s / wall_s if wall_s > 0 else None,
        "devices": {
            name: {
                "state": d.state,
                "samples": d.samples,
                "rate_hz": d.rate_hz,
                "rate_recent_hz": d.rate_recent_hz,
                "rate_cfg_hz": d.rate_cfg_hz,
                "gaps": d.gaps,
                "lost": d.lost,
                "faults": d.faults,
                "temp_c": finite(d.temp_c),
            }
            for name, d in devices.items()
        },
        "thermometers": {
            name: {
                "state": t.state,
                "readings": t.readings,
                "lost": t.lost,
                "faults": t.faults,
                "celsius": finite(t.celsius),
            }
            for name, t in thermometers.items()
        },
    }
    if file:
        status.update(file)
    return status


# -- from a run file ---------------------------------------------------------------------------
@dataclass
class SourceTally:
    """What the event log says of one source (device, thermometer or "station")."""

    events: int = 0
    #: events of LOSS_KINDS, and the samples they lost
    gaps: int = 0
    lost: int = 0
    faults: int = 0
    #: samples or readings lost by events of any kind (a thermometer's missed readings)
    lost_any: int = 0


class EventTally:
    """Per-source counts of a run file's events, fed in file order: all at once or as the file grows."""

    def __init__(self) -> None:
        self.sources: dict[str, SourceTally] = {}

    def add(self, events: Iterable[Event]) -> None:
        for ev in events:  # events are rare (one per gap or fault), not per sample
            s = self.sources.get(ev.source)
            if s is None:
                s = self.sources[ev.source] = SourceTally()
            s.events += 1
            s.lost_any += ev.lost
            if ev.kind in LOSS_KINDS:
                s.gaps += 1
                s.lost += ev.lost
            elif ev.kind == "fault":
                s.faults += 1

    def of(self, source: str) -> SourceTally:
        return self.sources.get(source) or SourceTally()


def device_status_from_run(run: RunFile, info: DeviceInfo, tally: EventTally, rows: int | None = None) -> DeviceStatus:
    """A device of an open run file (``info``: ``run.devices[name]``): its first ``rows`` samples (default: all)
    and its events.

    Rates: ``rate_hz`` = samples per second of the time they cover (:attr:`DeviceStatus.duration_s`),
    so that with logged losses ``rate_hz / rate_cfg_hz`` = written / (written + lost);
    ``rate_recent_hz``: sample intervals per second over the last ``RATE_WINDOW_S`` of
    station time (None with fewer than two samples there). ``temp_c``: the last row of the
    ``temp`` channel (mean over its axes), converted. ``state`` is left "ok": only
    the reader knows whether the file still grows.
    """
    name = info.name
    n = info.n if rows is None else min(rows, info.n)
    s = tally.of(name)
    d = DeviceStatus(rate_cfg_hz=info.rate_hz, samples=n, gaps=s.gaps, lost=s.lost, faults=s.faults, events=s.events)
    if n == 0:
        return d
    # only the recent window is read: a 12 h file costs what a minute does
    k = min(n, int(info.rate_hz * RATE_WINDOW_S * 2) + 16)
    t = run.read(name, "t", n - k, n).astype(np.int64)
    t_last = int(t[-1])
    first = int(run.read(name, "t", 0, 1)[0])
    d.first_t_s, d.last_t_s = first * 1e-9, t_last * 1e-9
    recent = t[t >= t_last - int(RATE_WINDOW_S * 1e9)]
    if len(recent) > 1 and recent[-1] > recent[0]:
        d.rate_recent_hz = (len(recent) - 1) / ((recent[-1] - recent[0]) * 1e-9)
    d.rate_hz = n / d.duration_s
    if "temp" in info.channels:
        ch = info.channels["temp"]
        d.temp_c = float(np.mean(run.read(name, "temp", n - 1, n))) * ch.scale + ch.offset
    return d


def thermometer_status(name: str, t_s: np.ndarray, celsius: np.ndarray, tally: EventTally) -> ThermometerStatus:
    """Thermometer ``name`` from its readings (times s, degC) and the event log (missed readings, faults)."""
    s = tally.of(name)
    th = ThermometerStatus(readings=len(t_s), lost=s.lost_any, faults=s.faults)
    if len(t_s):
        th.celsius, th.last_t_s = float(celsius[-1]), float(t_s[-1])
    return th


def elapsed_from_run(devices: Iterable[DeviceStatus], thermometers: Iterable[ThermometerStatus]) -> float:
    """Station time a run file has reached: its newest sample or reading (s; 0 when empty)."""
    last = [d.last_t_s for d in (*devices, *thermometers) if d.last_t_s is not None]
    return max(last) if last else 0.0
