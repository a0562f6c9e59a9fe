"""Resume a capture after a crash, a power cut or a stop (``capture --resume``): the same run, its next part.

A rotated capture is already a series of parts ``run.001.h5``, ``run.002.h5``, ...
sharing ``run_id`` and ``started_utc`` (docs/runfile.md, "Rotation"); a resumed
capture is one more part of that series:

1. under the output lock, every part cut off by a kill or power cut is recovered
   first (:func:`~imustation.runfile.recover.recover_run`: the torn last block
   left out, ``recovered`` stated); a run written as one file (no ``--rotate``)
   becomes part 1 of its series (``run.h5`` -> ``run.001.h5`` with ``part``,
   ``run_id``, ``part_started_utc``), so ``run.h5`` still names the whole run;
2. the new part continues the run's time: sample times are ns since the run's
   ``started_utc``; the monotonic clock did not survive the reboot, so the new
   part's origin is the last sample plus the outage, measured on the wall clock
   (now minus the last sample's UTC time). A simulation's time is virtual: the wall time
   between two runs is not on its clock. A simulated run that ended cleanly (every part
   complete: stopped, or its duration extended) goes on right after its last sample, with
   no outage and no hole; one that was killed lost its unwritten tail, which the virtual
   clock cannot date, and stands for a station that lost power while its sensors ran: its
   outage is the wall time since the killed part's last write (docs/capture.md, "Resume");
3. each device's and thermometer's first sample in the new part carries a ``gap``
   event for the outage, dated at the first missing sample with the count the
   file's hole finder gives (:mod:`imustation.runfile.holes`), so ``inspect``,
   ``analyze`` and ``report`` read the night as one run with one hole.

The run ends when its planned duration (from ``started_utc``) is over: a capture
resumed after that records nothing and says so.
"""

from __future__ import annotations

import datetime as _dt
import os
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import h5py
import numpy as np

from imustation.acquisition.config import StationConfig
from imustation.acquisition.station import CaptureSummary
from imustation.errors import RunFileError
from imustation.runfile import TIME, open_run, part_path, parts_of
from imustation.runfile.holes import find_holes
from imustation.runfile.recover import needs_recovery, recover_run
from imustation.runfile.schema import COUNTER, DeviceSpec


def wall_now() -> _dt.datetime:
    """The host's wall clock, UTC (tests inject another)."""
    return _dt.datetime.now(_dt.UTC)


@dataclass
class Edge:
    """The last sample of a device or thermometer before the outage: time (ns), counter, period (ns), modulus."""

    t_ns: int
    period_ns: float
    counter: int | None = None
    modulus: int = 0

    def hole(self, t_first: int, counter_first: int | None, *, late_polls: bool = False) -> int:
        """Samples the hole finder counts missing between this sample and the first after the outage."""
        counter = None
        if self.counter is not None and counter_first is not None:
            counter = np.array([self.counter, counter_first], dtype=np.int64)
        holes = find_holes(
            np.array([self.t_ns, t_first], dtype=np.int64), self.period_ns, counter, self.modulus, late_polls=late_polls
        )
        return holes.samples


@dataclass
class ResumePoint:
    """Where a resumed capture continues its run."""

    output: str
    run_id: str
    started_utc: str
    #: the part the resumed capture writes first
    next_part: int
    #: the run's time at the resumed capture's station-time origin, ns
    offset_ns: int
    outage_s: float
    devices: dict[str, Edge] = field(default_factory=dict)
    thermometers: dict[str, Edge] = field(default_factory=dict)
    #: one line per thing done before the capture (recovered parts, a single file made part 1)
    done: list[str] = field(default_factory=list)
    #: the last part's device layout (name -> (driver, rate, channels)), checked against the new part
    layout: dict[str, tuple] = field(default_factory=dict)
    note: str = ""
    #: the run's last file as found (a single-file run keeps its name until a part follows it)
    last_path: str = ""
    #: the run is one file (no parts): it becomes part 1 when the resumed capture starts
    single: bool = False

    def commit(self) -> None:
        """The resumed capture starts (its devices opened and checked): a single-file run becomes part 1."""
        if self.single:
            self.run_id = _make_part_one(self.output, self.previous)
            self.single = False
            self.done.append(
                f"{os.path.basename(self.output)} became part 1 of its run: {os.path.basename(self.previous)}"
            )

    @property
    def previous(self) -> str:
        return part_path(self.output, self.next_part - 1)

    def remaining_s(self, duration_s: float) -> float:
        """Of a run planned for ``duration_s`` from its start, what is left at the resumed capture's start, s."""
        return duration_s - self.offset_ns * 1e-9


def prepare_resume(
    output: str,
    config: StationConfig,
    duration_s: float,
    *,
    simulated: bool,
    now: Callable[[], _dt.datetime] = wall_now,
) -> ResumePoint | None:
    """Recover and take stock of the run at ``output`` (the caller holds its output lock).

    ``duration_s``: the run's planned duration from its start, s. None when there is
    nothing to resume (no such run: a new capture starts). A run whose duration is
    over is left as it is (:meth:`ResumePoint.remaining_s` <= 0). Raises
    :class:`RunFileError` when the run was recorded by another station.
    """
    parts = parts_of(output)
    done = []
    single = not parts
    if single:
        if not os.path.exists(output):
            return None
        first = part_path(output, 1)
        if os.path.exists(first):
            raise RunFileError(f"{output}: {first} exists too; move one of them away before resuming")
        parts = [output]
    last = parts[-1]
    # its last write, before a recovery rewrites it (a simulation's outage is measured from there)
    last_write = _dt.datetime.fromtimestamp(os.path.getmtime(last), _dt.UTC)
    for path in parts:
        done += _recover(path)
    killed = bool(done)  # a part cut off by a kill or a power cut needed recovering
    with open_run(last) as run:
        attrs = run.attrs
        if str(attrs.get("station", "")) != config.name:
            raise RunFileError(
                f"{last}: recorded by station {attrs.get('station')!r}, not {config.name!r}; "
                "resume with the same config"
            )
        number = int(attrs.get("part", 1))
        layout = {
            name: _layout(info.driver, info.rate_hz, {c: (ch.scale, ch.offset) for c, ch in info.channels.items()})
            for name, info in run.devices.items()
        }
        layout.update({f"thermometer {n}": ("thermometer", run.thermometer_rate_hz(n)) for n in run.thermometers})
        started_utc = str(attrs["started_utc"])
        run_id = str(attrs.get("run_id", ""))
    devices, thermometers = _edges(parts)
    last_t = max([e.t_ns for e in (*devices.values(), *thermometers.values())], default=0)
    started = _dt.datetime.fromisoformat(started_utc)
    note = ""
    if simulated and not killed:
        # virtual time ended cleanly: the run goes on at its last sample, the wall time between the runs is
        # not on its clock (each device's first new sample follows its last one; nothing is lost)
        outage_ns = 0
        note = "simulated run continued on its virtual clock: the wall time between the runs is not an outage"
    elif simulated:  # killed: the outage stands for the wall time since the killed part's last write
        outage_ns = int((now() - last_write).total_seconds() * 1e9)
    else:
        outage_ns = int((now() - started).total_seconds() * 1e9) - last_t
    if outage_ns <= 0 and not (simulated and not killed):
        note = (
            f"the host clock reads {-outage_ns * 1e-9:.3f} s before the last sample (set back, or not yet "
            "synchronised after the reboot): the outage's length is unknown, the run goes on 1 s after its last sample"
        )
        outage_ns = 1_000_000_000
    point = ResumePoint(
        output=output,
        run_id=run_id,
        started_utc=started_utc,
        next_part=number + 1,
        offset_ns=last_t + outage_ns,
        outage_s=outage_ns * 1e-9,
        devices=devices,
        thermometers=thermometers,
        done=done,
        layout=layout,
        note=note,
        last_path=last,
    )
    point.single = single
    return point


def _edges(parts: list[str]) -> tuple[dict[str, Edge], dict[str, Edge]]:
    """Each device's and thermometer's last sample in the run (a part killed right after a hand-over may
    hold none of a device's: its last sample is then in a part before)."""
    devices: dict[str, Edge] = {}
    thermometers: dict[str, Edge] = {}
    for path in reversed(parts):
        with open_run(path) as run:
            for name, info in run.devices.items():
                if name not in devices and info.n:
                    t = int(run.read(name, TIME, info.n - 1)[0])
                    c = int(run.read(name, COUNTER, info.n - 1)[0]) if info.has_counter else None
                    modulus = int(info.settings.get("counter_modulus", 0) or 0)
                    devices[name] = Edge(t, 1e9 / info.rate_hz, c, modulus)
            for name in run.thermometers:
                rate = run.thermometer_rate_hz(name)
                if name not in thermometers and rate:
                    t, _ = run.temperatures(name)
                    if len(t):
                        thermometers[name] = Edge(int(t[-1]), 1e9 / rate)
            if all(n in devices for n in run.devices) and all(n in thermometers for n in run.thermometers):
                break
    return devices, thermometers


def _layout(driver: str, rate_hz: float, channels: Mapping[str, tuple[float, float]]) -> tuple:
    return driver, float(rate_hz), tuple(sorted((c, float(s), float(o)) for c, (s, o) in channels.items()))


def check_layout(point: ResumePoint, devices: list[DeviceSpec], thermometers: Mapping[str, float]) -> None:
    """The resumed capture records what the run recorded: the same devices, rates and channel scales, and
    the same thermometers at the same poll rates."""
    new = {d.name: _layout(d.driver, d.rate_hz, {c.name: (c.scale, c.offset) for c in d.channels}) for d in devices}
    new.update({f"thermometer {n}": ("thermometer", float(rate)) for n, rate in thermometers.items()})
    if new == point.layout:
        return
    differ = sorted(n for n in set(new) | set(point.layout) if new.get(n) != point.layout.get(n))
    raise RunFileError(
        f"{point.output}: cannot resume: {', '.join(differ)} now differ(s) from the run's "
        f"{os.path.basename(point.previous)} (devices, rates or ranges changed); start a new run instead"
    )


def _recover(path: str) -> list[str]:
    """Recover ``path`` when a crash cut it off; what was done, as lines."""
    with open_run(path) as run:
        complete = run.complete
    if complete and not needs_recovery(path):
        return []
    rec = recover_run(path)
    return [f"{os.path.basename(path)}: {rec.statement()}"] if rec is not None else []


def _make_part_one(path: str, first: str) -> str:
    """A run written as one file becomes part 1 of its series (it is complete: not open anywhere); its run id."""
    run_id = uuid.uuid4().hex
    with h5py.File(path, "r+", locking=False) as f:
        f.attrs["part"] = 1
        f.attrs["previous_part"] = ""
        f.attrs["run_id"] = run_id
        f.attrs["part_started_utc"] = f.attrs["started_utc"]
    os.rename(path, first)
    _fsync_dir(first)
    return run_id


def link_next_part(previous: str, following: str) -> None:
    """Set ``next_part`` on the part the resumed capture continues (it is complete: closed and recovered)."""
    with h5py.File(previous, "r+", locking=False) as f:
        f.attrs["next_part"] = os.path.basename(following)


def _fsync_dir(path: str) -> None:
    fd = os.open(os.path.dirname(os.path.abspath(path)), os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def resumed_nothing(point: ResumePoint, remaining_s: float) -> CaptureSummary:
    """The summary of a resume that found its run's planned duration over: nothing recorded."""
    return CaptureSummary(
        duration_s=0.0,
        samples={},
        lost={},
        gaps={},
        wall_s=0.0,
        stopped_early=True,
        stop_reason=(
            f"the run's planned duration ended {-remaining_s:.0f} s ago: nothing to resume "
            f"(its last file is {os.path.basename(point.last_path)})"
        ),
        paths=[],
    )
