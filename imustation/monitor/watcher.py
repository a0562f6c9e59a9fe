"""Read a run file while it is written and keep JSON-ready snapshots for the server.

:class:`Monitor` runs two daemon threads:

* the **poller** opens the file read-only in SWMR mode every ``poll_s``
  seconds (a fresh open also sees ``ended_utc`` and the next part of a rotated
  capture), refreshes its datasets, reads only what was added since the last
  poll (events, temperatures, gyro counts; at most ``max_read_rows`` rows per
  device per poll, so catching up on a 12 h file never stalls the status) and
  closes it again;
* the **analyser** recomputes the Allan curves from the in-memory gyro buffers
  at most every ``allan_every_s`` seconds and the ML_i model overlay at most
  every ``fit_every_s`` seconds once a device holds ``model_after_s`` seconds
  of data. It never touches the file.

(Over 500 lines on purpose: the two threads share the snapshot and its lock; the
status itself comes from imustation/status.py, the curves from live_allan.py.)

The server's handlers only read the latest snapshots (dicts swapped whole), so
a slow computation never blocks a page. Times are s since ``started_utc``
(station time: virtual in simulations), temperatures degC, rates Hz, Allan
deviations rad/s.
"""

from __future__ import annotations

import collections
import datetime as _dt
import math
import os
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imustation.analysis.estimators.classical.temperature import fit_warmup
from imustation.analysis.estimators.models.standard import StandardModel
from imustation.analysis.pipeline.loaders import TEMP_READ_HZ, locate_breaks
from imustation.errors import ImustationError
from imustation.monitor.live_allan import MAX_ROWS, GyroBuffer, allan_curves, model_curves
from imustation.runfile import Event, RunFile, latest_part, open_run
from imustation.runfile.checks import damaged_file, parse_events
from imustation.status import LOSS_KINDS, EventTally, device_status_from_run, elapsed_from_run, thermometer_status

#: a device whose row count has not grown for this many wall seconds is reported stalled
STALL_S = 10.0
#: events kept for the page (newest last)
EVENTS_KEPT = 100
#: window (s) and limit (degC/h) of the warm-up detection and the "steady" flag
WARMUP_WINDOW_S = 600.0
STEADY_C_PER_H = 1.0
#: rows read per device and per poll (catching up on a long file is spread over polls)
MAX_READ_ROWS = 1 << 22
#: rows per HDF5 read
READ_BLOCK = 1 << 20


def _utc() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def _wall_since(started_utc: str) -> float | None:
    try:
        t0 = _dt.datetime.fromisoformat(started_utc)
    except (TypeError, ValueError):
        return None
    return (_dt.datetime.now(_dt.UTC) - t0).total_seconds()


@dataclass
class _Series:
    """A growing temperature series: times (s) and degC, as lists of numpy blocks."""

    t: list[np.ndarray] = field(default_factory=list)
    c: list[np.ndarray] = field(default_factory=list)
    pos: int = 0  # rows of the file consumed

    def add(self, t_s: np.ndarray, c: np.ndarray) -> None:
        if len(t_s):
            self.t.append(np.asarray(t_s, dtype=np.float64))
            self.c.append(np.asarray(c, dtype=np.float64))
            if len(self.t) > 64:  # keep few blocks: concatenation is then cheap
                self.t, self.c = [np.concatenate(self.t)], [np.concatenate(self.c)]

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.t:
            return np.zeros(0), np.zeros(0)
        return np.concatenate(self.t), np.concatenate(self.c)


@dataclass
class _Device:
    name: str
    rate_hz: float
    rows: int = 0
    grew_wall: float = field(default_factory=time.monotonic)
    temp: _Series | None = None
    gyro: GyroBuffer | None = None
    loss_events: list[Event] = field(default_factory=list)
    breaks_checked: int = 0


def warmup_summary(t_s: np.ndarray, c: np.ndarray) -> dict[str, Any]:
    """Warm-up state of one temperature series (s, degC).

    ``warmup_end_s``: end of the warm-up found by the analysis's
    :func:`fit_warmup` (``None`` while fewer than ``WARMUP_WINDOW_S`` of
    readings exist, too few to tell or while still warming; 0 when there is
    no warm-up transient); ``warming``: a warm-up transient has not settled for
    ``WARMUP_WINDOW_S`` yet (``None`` while too short to tell); ``slope_c_per_h``: least-squares
    slope of the last ``WARMUP_WINDOW_S`` (degC/h); ``steady``: its magnitude
    is within the limit.
    """
    out: dict[str, Any] = {"warmup_end_s": None, "warming": None, "slope_c_per_h": None, "steady": None}
    if len(t_s) < 3:
        return out
    last = t_s >= t_s[-1] - WARMUP_WINDOW_S
    if np.count_nonzero(last) >= 3 and np.ptp(t_s[last]) > 0:
        slope = float(np.polyfit(t_s[last] - t_s[-1], c[last], 1)[0]) * 3600.0
        out["slope_c_per_h"] = slope
        out["steady"] = abs(slope) <= STEADY_C_PER_H
    if t_s[-1] - t_s[0] < WARMUP_WINDOW_S:
        return out
    wfit = fit_warmup(t_s, c, window_s=WARMUP_WINDOW_S, max_rate_c_per_h=STEADY_C_PER_H)
    if wfit.state == "unknown":
        return out
    out["warming"] = wfit.state == "unsettled"
    out["warmup_end_s"] = None if out["warming"] else wfit.cut_s
    return out


def decimate(t_s: np.ndarray, c: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_points`` points: block means of equal runs of readings (the last block may be shorter)."""
    n = len(t_s)
    if n <= max_points or max_points < 1:
        return t_s, c
    k = math.ceil(n / max_points)
    edges = np.arange(0, n, k)
    counts = np.diff(np.append(edges, n))
    return np.add.reduceat(t_s, edges) / counts, np.add.reduceat(c, edges) / counts


class Monitor:
    """Watches one run file; see the module docstring.

    path : the run file (must exist and be an imustation run file), or the base name of a
        rotated capture (its newest part is watched, then each next part).
    poll_s : wall seconds between polls of the file.
    allan_every_s, fit_every_s : wall seconds between Allan / model recomputations.
    model_after_s : station seconds of data a device needs before the model is fitted.
    max_rows : gyro rows kept per device (see :class:`GyroBuffer`).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        poll_s: float = 2.0,
        allan_every_s: float = 30.0,
        fit_every_s: float = 120.0,
        model_after_s: float = 600.0,
        max_rows: int = MAX_ROWS,
        max_read_rows: int = MAX_READ_ROWS,
    ):
        self.path = latest_part(os.fspath(path))  # a rotated capture's base name: the part being written
        self.poll_s = float(poll_s)
        self.allan_every_s = float(allan_every_s)
        self.fit_every_s = float(fit_every_s)
        self.model_after_s = float(model_after_s)
        self.max_rows = int(max_rows)
        self.max_read_rows = int(max_read_rows)
        with open_run(self.path, live=True) as run:  # fails early, with one line, on a bad file
            self._check(run)
        self._reset()
        self._stop = threading.Event()
        self._kick = threading.Event()
        self._threads: list[threading.Thread] = []
        self._status: dict[str, Any] = {"state": "starting", "file": os.path.basename(self.path), "devices": {}}
        self._temps: dict[str, Any] = {"series": {}, "warmup": {}}
        self._allan: dict[str, Any] = {"devices": {}, "model_after_s": self.model_after_s}
        self.error: str | None = None

    @staticmethod
    def _check(run: RunFile) -> None:
        if not run.devices and not run.thermometers:
            raise ImustationError(f"{run.path}: run file holds no devices and no thermometers")

    def _reset(self) -> None:
        self._devices: dict[str, _Device] = {}
        self._thermo: dict[str, _Series] = {}
        self._events_pos = 0
        self._tally = EventTally()
        self._events: collections.deque[dict[str, Any]] = collections.deque(maxlen=EVENTS_KEPT)
        self._station_events = 0
        self._polls = 0

    # -- threads ------------------------------------------------------------
    def start(self) -> None:
        """Start the poller and the analyser (daemon threads)."""
        try:  # the analysis kernels are numba-parallel: one core is plenty beside a capture
            import numba

            numba.set_num_threads(1)
        except (ImportError, ValueError):
            pass
        for target, name in ((self._poll_loop, "monitor-poll"), (self._analysis_loop, "monitor-allan")):
            th = threading.Thread(target=target, name=name, daemon=True)
            th.start()
            self._threads.append(th)

    def stop(self) -> None:
        self._stop.set()
        self._kick.set()
        for th in self._threads:
            th.join(timeout=5.0)

    def _poll_loop(self) -> None:
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                self.poll()
                self.error = None
            except Exception as exc:  # noqa: BLE001 - whatever it is, the page says it and the poller lives on
                self._report(exc)
            self._stop.wait(max(0.05, self.poll_s - (time.monotonic() - t0)))

    def _report(self, exc: Exception) -> None:
        """Keep serving the last snapshot, with the error on the page (and a bug's traceback on stderr once)."""
        error = str(exc) if isinstance(exc, ImustationError) else f"{exc.__class__.__name__}: {exc}"
        if not isinstance(exc, (ImustationError, OSError)) and error != self.error:
            traceback.print_exception(exc, file=sys.stderr)
        self.error = error
        state = "error" if self._status.get("state") in ("starting", "error") else self._status.get("state")
        self._status = {**self._status, "state": state, "monitor_error": error}

    def _analysis_loop(self) -> None:
        last_allan = last_fit = -math.inf
        while not self._stop.is_set():
            now = time.monotonic()
            if now - last_allan >= self.allan_every_s:
                fit_due = now - last_fit >= self.fit_every_s
                try:
                    did, fitted = self.analyse(fit=fit_due)
                except Exception as exc:  # noqa: BLE001 - the curves stay as they were, the page says why
                    self._report(exc)
                    did = fitted = False
                    last_allan = now
                if did:
                    last_allan = now
                    # the refit clock starts at a fit, not at a due time with too little data
                    last_fit = now if fitted else last_fit
            self._kick.wait(1.0)
            self._kick.clear()

    # -- polling (file access only here) ------------------------------------
    def poll(self) -> None:
        """Read what the writer added since the last poll and rebuild the status snapshot."""
        run = open_run(self.path, live=True)
        try:
            run.refresh()
            nxt = run.attrs.get("next_part")
            if nxt:
                nxt_path = os.path.join(os.path.dirname(self.path), str(nxt))
                if os.path.exists(nxt_path):  # a rotated capture moved on: follow it
                    self.path = nxt_path
                    self._reset()
                    return
            self._poll(run)
        finally:
            run.close()
        self._polls += 1
        if self._polls == 1:
            self._kick.set()

    def _poll(self, run: RunFile) -> None:
        infos = run.devices
        now = time.monotonic()
        for name, info in infos.items():
            dev = self._devices.get(name)
            if dev is None:
                dev = self._devices[name] = _Device(name, info.rate_hz)
                if "temp" in info.channels:
                    dev.temp = _Series()
                gyro = info.channels.get("gyro")
                if gyro is not None and gyro.axes:
                    dev.gyro = GyroBuffer(info.rate_hz, gyro.scale, gyro.dtype, gyro.axes, self.max_rows)
            if info.n > dev.rows:
                dev.rows, dev.grew_wall = info.n, now
        for name in run.thermometers:
            self._thermo.setdefault(name, _Series())
        self._read_events(run)
        for dev in self._devices.values():
            if dev.temp is not None:
                self._read_device_temp(run, dev, infos[dev.name])
            if dev.gyro is not None:
                self._read_gyro(run, dev)
        for name, series in self._thermo.items():
            t, c = run.temperatures(name)
            if len(t) > series.pos:
                series.add(np.asarray(t[series.pos :], dtype=np.int64) * 1e-9, c[series.pos :])
                series.pos = len(t)
        self._status = self._build_status(run, infos, now)
        self._temps = self._build_temps()

    def _read_events(self, run: RunFile) -> None:
        ds = run.h5.get("events")
        if ds is None or ds.shape[0] <= self._events_pos:
            return
        with damaged_file(run.path, "events", ds):
            rows = ds[self._events_pos :]
        self._events_pos += len(rows)
        events = parse_events(run.path, rows)  # events are rare (one per gap or fault), not per sample
        self._tally.add(events)
        for ev in events:
            self._events.append(
                {"t_s": ev.t_ns * 1e-9, "source": ev.source, "kind": ev.kind, "lost": ev.lost, "detail": ev.detail}
            )
            dev = self._devices.get(ev.source)
            if dev is None:
                self._station_events += 1
            elif ev.kind in LOSS_KINDS:
                dev.loss_events.append(ev)

    def _read_device_temp(self, run: RunFile, dev: _Device, info) -> None:
        """Block means of the device's temperature channel, about TEMP_READ_HZ readings per s."""
        ch = info.channels["temp"]
        m = max(1, int(round(info.rate_hz / TEMP_READ_HZ)))
        series = dev.temp
        stop = min(dev.rows, series.pos + self.max_read_rows)
        stop -= (stop - series.pos) % m
        while series.pos < stop:
            b = min(stop, series.pos + READ_BLOCK - READ_BLOCK % m)
            raw = run.read(dev.name, "temp", series.pos, b).astype(np.float64)
            t = run.read(dev.name, "t", series.pos, b)
            k = len(raw) // m
            if k == 0:
                break
            raw = raw[: k * m].reshape(k, m, -1).mean(axis=(1, 2))
            series.add(t[: k * m].reshape(k, m)[:, m // 2] * 1e-9, raw * ch.scale + ch.offset)
            series.pos += k * m

    def _read_gyro(self, run: RunFile, dev: _Device) -> None:
        buf = dev.gyro
        budget = self.max_read_rows
        while budget > 0:
            k = buf.wanted(dev.rows)
            d = buf.decimation
            step = min(k, budget, READ_BLOCK)
            step -= step % d
            if step <= 0:
                break
            start = buf.consumed
            buf.append(run.read(dev.name, "gyro", start, start + step))
            budget -= step
        if len(dev.loss_events) > dev.breaks_checked:
            dev.breaks_checked = len(dev.loss_events)
            t_ds = run.dataset(dev.name, "t")
            buf.breaks = [b for b in locate_breaks(t_ds, dev.loss_events, dev.rate_hz) if b < dev.rows]

    def _build_status(self, run: RunFile, infos, now: float) -> dict[str, Any]:
        started = str(run.attrs.get("started_utc", ""))
        complete = "ended_utc" in run.attrs
        devices: dict[str, Any] = {}
        models = {}
        for name, dev in self._devices.items():
            info = infos[name]
            d = models[name] = device_status_from_run(run, info, self._tally, rows=dev.rows)
            stalled_s = now - dev.grew_wall
            devices[name] = {
                "driver": info.driver,
                "model": info.model,
                "rate_cfg_hz": d.rate_cfg_hz,
                "samples": d.samples,
                "rate_hz": d.rate_hz,
                "rate_recent_hz": d.rate_recent_hz,
                "gaps": d.gaps,
                "lost": d.lost,
                "faults": d.faults,
                "events": d.events,
                "temp_c": d.temp_c,
                "last_t_s": d.last_t_s,
                "stalled_s": stalled_s,
                "state": "done" if complete else ("stalled" if stalled_s > max(STALL_S, 3 * self.poll_s) else "ok"),
            }
        thermos = {name: thermometer_status(name, *s.arrays(), self._tally) for name, s in self._thermo.items()}
        thermometers = {
            name: {"readings": th.readings, "celsius": th.celsius, "last_t_s": th.last_t_s}
            for name, th in thermos.items()
        }
        try:
            size = os.path.getsize(self.path)
        except OSError:
            size = None
        return {
            "format": "imustation-monitor-status",
            "version": 1,
            "file": os.path.basename(self.path),
            "state": "complete" if complete else "recording",
            "station": run.attrs.get("station", ""),
            "simulated": bool(run.attrs.get("simulated", False)),
            "started_utc": started,
            "ended_utc": run.attrs.get("ended_utc"),
            "stopped": run.attrs.get("stopped"),
            "part": run.attrs.get("part"),
            "elapsed_s": elapsed_from_run(models.values(), thermos.values()),
            "wall_elapsed_s": _wall_since(started),
            "file_bytes": size,
            "devices": devices,
            "thermometers": thermometers,
            "station_events": self._station_events,
            "events": list(self._events),
            "updated_utc": _utc(),
            "poll_s": self.poll_s,
        }

    def _temperature_arrays(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        out = {}
        for name, dev in self._devices.items():
            if dev.temp is not None:
                out[name] = dev.temp.arrays()
        for name, series in self._thermo.items():
            out[name] = series.arrays()
        return out

    def _build_temps(self) -> dict[str, Any]:
        arrays = self._temperature_arrays()
        return {
            "arrays": arrays,
            "warmup": {name: warmup_summary(t, c) for name, (t, c) in arrays.items()},
            "kinds": {name: ("device" if name in self._devices else "thermometer") for name in arrays},
        }

    # -- analysis (no file access) ------------------------------------------
    def analyse(self, fit: bool) -> tuple[bool, bool]:
        """Recompute the Allan curves (and the model overlay when ``fit``).

        Returns (some device had data, a model was fitted).
        """
        out: dict[str, Any] = {}
        previous = self._allan.get("devices", {})
        did = fitted = False
        for name, dev in list(self._devices.items()):
            snap = dev.gyro.snapshot() if dev.gyro is not None else None
            if snap is None:
                continue
            did = True
            prev = previous.get(name)
            if prev is not None and prev.get("samples") == snap.raw_rows and "error" not in prev:
                duration = snap.raw_rows / (snap.fs_hz * snap.decimation)
                if prev.get("model") is not None or duration < self.model_after_s:
                    out[name] = prev  # nothing new on disk (e.g. a finished run): keep the curves
                    continue
            try:
                curves = allan_curves(snap)
            except ImustationError as exc:
                out[name] = {"error": str(exc)}
                continue
            duration = snap.raw_rows / (snap.fs_hz * snap.decimation)
            entry: dict[str, Any] = {
                "fs_hz": snap.fs_hz * snap.decimation,
                "decimation": snap.decimation,
                "samples": snap.raw_rows,
                "duration_s": duration,
                "segments": len(snap.segments),
                "units": "rad/s",
                "computed_utc": _utc(),
                **curves,
                "model": None,
            }
            old = previous.get(name, {}).get("model")
            if fit and duration >= self.model_after_s and len(curves["tau"]):
                entry["model"] = model_curves(snap, np.asarray(curves["tau"]))
                entry["model"]["fitted_utc"] = _utc()
                fitted = True
            elif old is not None and len(curves["tau"]):
                # keep the last fit, its curve evaluated at the new taus
                entry["model"] = {**old, "axes": dict(old["axes"])}
                entry["model"]["stale"] = True
                entry["model"]["axes"] = _reevaluate(old, np.asarray(curves["tau"]))
            out[name] = entry
        if did:
            self._allan = {"devices": out, "model_after_s": self.model_after_s, "model": "wn+gm", "updated_utc": _utc()}
        return did, fitted

    # -- snapshots for the server -------------------------------------------
    def status(self) -> dict[str, Any]:
        return self._status

    def allan(self) -> dict[str, Any]:
        return self._allan

    def temperatures(self, max_points: int = 1500) -> dict[str, Any]:
        temps = self._temps
        series = {}
        for name, (t, c) in temps.get("arrays", {}).items():
            td, cd = decimate(t, c, max_points)
            series[name] = {"kind": temps["kinds"][name], "t_s": td, "celsius": cd, "readings": len(t)}
        return {
            "series": series,
            "warmup": temps.get("warmup", {}),
            "window_s": WARMUP_WINDOW_S,
            "limit_c_per_h": STEADY_C_PER_H,
        }


def _reevaluate(model: dict[str, Any], tau: np.ndarray) -> dict[str, Any]:
    """The standard model's Allan deviation at new taus from a previous fit's parameters."""
    axes = {}
    for axis, p in model["axes"].items():
        if "error" in p:
            axes[axis] = p
            continue
        tau_b = p["tau_b"] if p["tau_b"] is not None else math.inf
        axes[axis] = {**p, "adev": StandardModel(p["sigma_w"], p["sigma_b"], tau_b).adev(tau)}
    return axes
