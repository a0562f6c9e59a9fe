"""The capture's side of the run file: one writer at a time, rotation, output lock.

:class:`Recorder` owns the :class:`~imustation.runfile.RunWriter` of the part
being written. With ``rotate_s`` the capture is cut into parts of that much
station time (``run.001.h5``, ``run.002.h5``, ...): each part is a complete
run file (format v1) sharing ``started_utc`` and ``run_id`` with the others, so
sample times continue from one part to the next (docs/runfile.md, "Rotation").

:class:`OutputLock` keeps two captures from writing the same output: an
exclusive ``flock`` on ``<output>.lock``, released by the kernel when the
process dies, so a crash never leaves a stale lock behind.
"""

from __future__ import annotations

import datetime as _dt
import errno
import fcntl
import math
import os
import re
import shutil
import uuid
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from imustation.acquisition.clocksync import ClockWatch
from imustation.acquisition.config import StationConfig
from imustation.acquisition.resume import ResumePoint, check_layout, link_next_part, prepare_resume, wall_now
from imustation.acquisition.station import OpenedDevice
from imustation.errors import DiskFullError, InputError, RunFileError
from imustation.runfile import (
    DEFAULT_BALLAST_BYTES,
    DEFAULT_MIN_FREE_BYTES,
    DeviceSpec,
    RunWriter,
    part_path,
    utc_now_iso,
)

#: shortest part of a rotated capture, s: every part is a new HDF5 file (created, fsynced,
#: renamed, reopened to be marked complete), so parts of milliseconds only make files
MIN_ROTATE_S = 1.0
#: most parts a capture may plan (their names are checked and kept up front)
MAX_PARTS = 10_000
#: free space a capture needs at its start beyond the reserve and the ballast: a disk
#: without it would end the capture at its first flush with nothing written
START_ROOM_BYTES = 2**20


_PART_NAME = re.compile(r"^(?P<stem>.+)\.\d{3,}(?P<ext>\.[^./]*)?$")


def run_of_part(path: str) -> str | None:
    """The output whose rotated parts include ``path`` (``run.002.h5`` -> ``run.h5``), or None."""
    m = _PART_NAME.match(path)
    return m.group("stem") + (m.group("ext") or ".h5") if m else None


class OutputLock:
    """Exclusive lock on ``<path>.lock`` for the life of a capture.

    A name that is also a part name of a rotated run (``run.001.h5`` of ``run.h5``)
    locks that run's name as well, so the whole name set of a rotated capture is
    locked: nobody writes ``run.001.h5`` (even with --overwrite) or a later part while
    ``run.h5 --rotate`` records, and that capture never finds its next part taken.
    """

    def __init__(self, path: str):
        self.path = path + ".lock"
        self._fd: int | None = None
        run = run_of_part(path)
        self._run = OutputLock(run) if run is not None else None

    def acquire(self) -> None:
        if self._run is not None:
            try:
                self._run.acquire()
            except RunFileError as exc:
                raise RunFileError(f"{self.path[:-5]} is a part name of {self._run.path[:-5]}: {exc}") from None
            try:
                self._acquire()
            except BaseException:
                self._run.release()
                raise
        else:
            self._acquire()

    def _acquire(self) -> None:
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise RunFileError(f"{self.path}: cannot create the output lock: {exc.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EACCES):
                raise RunFileError(
                    f"{self.path[:-5]}: another capture (pid {holder}) is writing this output; choose another name"
                ) from None
            raise RunFileError(f"{self.path}: cannot lock: {exc.strerror}") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            try:
                os.unlink(self.path)
            except OSError:
                pass
            os.close(self._fd)
            self._fd = None
        if self._run is not None:
            self._run.release()


def run_file_device(dev: OpenedDevice) -> DeviceSpec:
    """The run file's description of an opened device: its config name, driver and bus, and what
    its driver reported (model, identity, rate, settings, channels, counter). Made here only."""
    cfg, info = dev.config, dev.info
    return DeviceSpec(
        name=cfg.name,
        driver=cfg.driver,
        model=info.model,
        bus=cfg.bus + (f"@0x{cfg.address:02X}" if cfg.address is not None else ""),
        identity=info.identity,
        rate_hz=info.rate_hz,
        settings=info.settings,
        channels=info.channels,
        has_counter=info.has_counter,
    )


def rotation_parts(duration_s: float, rotate_s: float | None) -> int:
    """Parts a capture of ``duration_s`` seconds rotated every ``rotate_s`` seconds makes (1 without rotation).

    Raises :class:`InputError` for a part shorter than MIN_ROTATE_S or more than MAX_PARTS parts.
    """
    if rotate_s is None:
        return 1
    if not rotate_s >= MIN_ROTATE_S:  # also NaN
        raise InputError(f"--rotate {rotate_s:g}s: parts must last at least {MIN_ROTATE_S:g} s")
    n = math.ceil(duration_s / rotate_s)
    if n > MAX_PARTS:
        raise InputError(
            f"--rotate {rotate_s:g}s over --duration {duration_s:g}s makes {n:.3g} parts; at most {MAX_PARTS}"
            " (choose a longer --rotate)"
        )
    return n


class Recorder:
    """Writes a capture into one run file, or into parts of ``rotate_s`` station seconds.

    Parameters
    ----------
    output : the run file (without rotation) or the name the parts derive from.
    duration_s : planned capture duration (to check every part name up front).
    rotate_s : station seconds per part, or None for one file.
    note : an event note opening every part (e.g. the simulation level), or "".
    clock_watch : the host clock: its synchronisation state is stored in every part's
        root attributes, a step of the wall clock is logged as a ``note``
        (:mod:`~imustation.acquisition.clocksync`).
    resume : continue this run as its next part (``capture --resume``,
        :mod:`~imustation.acquisition.resume`): its run id and start, part numbers
        from ``resume.next_part``, times shifted by ``resume.offset_ns``, the outage
        logged as a gap at each device's first sample. Its output lock is held already.
    writer_options : passed to every :class:`RunWriter` (station, config_text,
        simulated, flush_interval_s, fsync, min_free_bytes, ...).
    """

    def __init__(
        self,
        output: str | os.PathLike,
        *,
        duration_s: float,
        rotate_s: float | None = None,
        overwrite: bool = False,
        note: str = "",
        resume: ResumePoint | None = None,
        lock: OutputLock | None = None,
        clock_watch: ClockWatch | None = None,
        **writer_options: Any,
    ):
        self.output = os.fspath(output)
        self.note = note
        self.rotate_s = rotate_s
        self.overwrite = overwrite
        self.writer_options = writer_options
        self.writer: RunWriter | None = None
        self.paths: list[str] = []
        self.resume = resume
        self.clock_watch = clock_watch
        #: the run's time at the station's time origin, ns (a resumed capture continues its run)
        self.offset_ns = resume.offset_ns if resume is not None else 0
        #: devices and thermometers whose first sample after the outage is still to come
        self._outage = {**resume.devices, **resume.thermometers} if resume is not None else {}
        self.part = resume.next_part - 1 if resume is not None else 0
        self._closed_bytes = 0
        #: samples per device in parts already closed (on disk)
        self._closed_flushed: dict[str, int] = {}
        self._next_rotation_ns: int | None = None
        self.lock = lock or OutputLock(self.output)
        self._locked = lock is not None  # held already (a resumed capture's stock was taken under it)
        #: station time the capture ends, ns: no part starts there (nothing would follow)
        self._end_ns = int(round(duration_s * 1e9))
        n_parts = rotation_parts(duration_s, rotate_s)
        first = self.part + 1
        if rotate_s or resume is not None:
            self.planned = [part_path(self.output, k) for k in range(first, first + n_parts)]
        else:
            self.planned = [self.output]

    # -- life cycle ---------------------------------------------------------------
    def reserve(self) -> None:
        """Lock the output and refuse existing files, before any device is touched."""
        if not self._locked:
            self.lock.acquire()
            self._locked = True
        if not self.overwrite:
            for p in self.planned:
                if os.path.exists(p):
                    self.lock.release()
                    raise RunFileError(f"{p}: file exists; choose another name or --overwrite")
        try:
            self._check_room()
        except DiskFullError:
            self.lock.release()
            raise

    def _check_room(self) -> None:
        """Refuse a disk that holds no data beyond the reserve and the ballast (a capture that
        would stop at once, its file empty)."""
        reserve = int(self.writer_options.get("min_free_bytes", DEFAULT_MIN_FREE_BYTES))
        ballast = int(self.writer_options.get("ballast_bytes", DEFAULT_BALLAST_BYTES))
        if reserve <= 0:
            return
        st = os.statvfs(os.path.dirname(os.path.abspath(self.output)))
        free = st.f_bavail * st.f_frsize
        if free < reserve + ballast + START_ROOM_BYTES:
            mib = 2**20
            raise DiskFullError(
                f"{self.output}: {free / mib:.1f} MiB free; a capture keeps {reserve / mib:g} MiB in reserve and "
                f"{ballast / mib:g} MiB of ballast and needs {START_ROOM_BYTES / mib:g} MiB more for data; free space"
            )

    def start(self, devices: Sequence[OpenedDevice], thermometers: Mapping[str, float]) -> None:
        """Create the first part for the opened ``devices`` and the ``thermometers`` (name: configured poll
        rate, Hz; every part stores it, see :class:`~imustation.runfile.RunWriter`)."""
        self.devices = [run_file_device(d) for d in devices]
        self.thermometers = dict(thermometers)
        if self.resume is not None:
            check_layout(self.resume, self.devices, self.thermometers)
            self.resume.commit()
            self.started_utc, self.run_id = self.resume.started_utc, self.resume.run_id
        else:
            self.started_utc = utc_now_iso()
            self.run_id = uuid.uuid4().hex if self.rotate_s else ""
        self._open_part(0)
        if self.resume is not None:
            self._open_resumed()

    def _open_resumed(self) -> None:
        """The first part of a resumed capture: linked to the part it continues, the outage noted."""
        point = self.resume
        assert point is not None and self.writer is not None
        link_next_part(point.previous, self.writer.path)
        for line in point.done:
            self.writer.event(self.offset_ns, "station", "note", line)
        outage = (
            f"capture resumed after an outage of {point.outage_s:.3f} s (crash, power cut or stop)"
            if point.outage_s > 0
            else "capture resumed"
        )
        self.writer.event(self.offset_ns, "station", "note", f"{outage}; continues {os.path.basename(point.previous)}")
        if point.note:
            self.writer.event(self.offset_ns, "station", "note", point.note)

    def _open_part(self, local_ns: int) -> None:
        t_ns = local_ns + self.offset_ns
        self.part += 1
        rotating = self.rotate_s is not None or self.resume is not None
        path = part_path(self.output, self.part) if rotating else self.output
        previous = os.path.basename(self.paths[-1] if self.paths else self.resume.previous if self.resume else "")
        started = _dt.datetime.fromisoformat(self.started_utc) + _dt.timedelta(microseconds=t_ns / 1e3)
        self.writer = RunWriter(
            path,
            devices=self.devices,
            thermometers=self.thermometers,
            overwrite=self.overwrite,
            started_utc=self.started_utc,
            part=self.part if rotating else None,
            previous_part=previous,
            run_id=self.run_id,
            part_started_utc=started.isoformat(timespec="milliseconds"),
            attrs=self.clock_watch.sync().attrs() if self.clock_watch is not None else None,
            **self.writer_options,
        )
        self.paths.append(path)
        if self.note:
            self.writer.event(t_ns, "station", "note", self.note)
        if self.rotate_s is not None:
            self._next_rotation_ns = local_ns + int(round(self.rotate_s * 1e9))
        if rotating:
            if self.part > 1:
                self.writer.event(t_ns, "station", "note", f"part {self.part} continues {previous}")

    def _close_part(self, attrs: Mapping[str, Any] | None = None) -> None:
        assert self.writer is not None
        self.writer.close(attrs=attrs)
        self._closed_bytes += self.writer.file_bytes()
        for name, n in self.writer.samples_flushed.items():
            self._closed_flushed[name] = self._closed_flushed.get(name, 0) + n
        self.writer = None  # its bytes and samples are counted above

    def tick(self, t_ns: int) -> None:
        """Between polls: flush when due, start the next part when its time has come, note a clock step."""
        assert self.writer is not None
        if self.clock_watch is not None:
            step = self.clock_watch.check(t_ns)
            if step is not None:
                self.writer.event(t_ns + self.offset_ns, "station", "note", step)
        if self._next_rotation_ns is not None and self._end_ns > t_ns >= self._next_rotation_ns:
            following = os.path.basename(part_path(self.output, self.part + 1))
            self.writer.event(t_ns + self.offset_ns, "station", "note", f"continued in {following}")
            self._close_part({"next_part": following})
            self._open_part(t_ns)
        else:
            self.writer.flush_if_due()

    def finish(self, attrs: Mapping[str, Any] | None = None) -> None:
        """Flush and close the current part cleanly (``ended_utc`` set)."""
        try:
            if self.writer is not None and not self.writer.closed:
                self._close_part(attrs)
        finally:
            self.lock.release()

    def abort(self) -> None:
        """Close without marking the file complete (the capture failed)."""
        try:
            if self.writer is not None:
                self.writer.abort()
        finally:
            self.lock.release()

    # -- the sink the station writes into ------------------------------------------------
    # (times arrive in station time, ns since this capture's origin; the file's are the run's)
    def append(self, device: str, t_ns: np.ndarray, channels, counter=None) -> None:
        if self.offset_ns:
            t_ns = np.asarray(t_ns, dtype=np.int64) + self.offset_ns
        if device in self._outage and len(t_ns):
            self._log_outage(device, int(t_ns[0]), None if counter is None else int(counter[0]))
        self.writer.append(device, t_ns, channels, counter)  # type: ignore[union-attr]

    def append_temperature(self, name: str, t_ns: np.ndarray, celsius: np.ndarray) -> None:
        if self.offset_ns:
            t_ns = np.asarray(t_ns, dtype=np.int64) + self.offset_ns
        if name in self._outage and len(t_ns):
            self._log_outage(name, int(t_ns[0]), None, late_polls=True)
        self.writer.append_temperature(name, t_ns, celsius)  # type: ignore[union-attr]

    def event(self, t_ns: int, source: str, kind: str, detail: str = "", lost: int = 0) -> None:
        self.writer.event(t_ns + self.offset_ns, source, kind, detail, lost)  # type: ignore[union-attr]

    def _log_outage(self, name: str, t_first: int, counter: int | None, *, late_polls: bool = False) -> None:
        """The outage's gap, at the first sample it misses, counted as the file's hole finder counts it."""
        edge = self._outage.pop(name)
        lost = edge.hole(t_first, counter, late_polls=late_polls)
        if lost <= 0:  # a simulated run continued on its virtual clock: no hole, nothing to log
            return
        span = (t_first - edge.t_ns) * 1e-9
        t_missing = edge.t_ns + int(round(edge.period_ns))
        detail = f"outage: no samples for {span:.3f} s before the capture resumed"
        self.writer.event(min(t_missing, t_first - 1), name, "gap", detail, lost)  # type: ignore[union-attr]

    def status(self) -> dict[str, Any]:
        """The file part of the status document (docs/capture.md): current file and part, bytes of
        all parts, samples per device on disk, free space on the output's filesystem (bytes)."""
        w = self.writer
        path = w.path if w else (self.paths[-1] if self.paths else self.output)
        try:
            free = shutil.disk_usage(os.path.dirname(os.path.abspath(path))).free
        except OSError:
            free = None
        return {
            "file": path,
            "part": self.part if self.rotate_s or self.resume else None,
            "file_bytes": self._closed_bytes + (w.file_bytes() if w else 0),
            # samples per device known to be on disk (after the last completed flush)
            "on_disk": {
                name: self._closed_flushed.get(name, 0) + (w.samples_flushed.get(name, 0) if w else 0)
                for name in (w.samples_flushed if w else self._closed_flushed)
            },
            "disk_free_bytes": free,
            **({"clock": self.clock_watch.status()} if self.clock_watch is not None else {}),
        }


def reserve_resumed(
    output: str | os.PathLike,
    config: StationConfig,
    duration_s: float,
    *,
    simulated: bool,
    now: Callable[[], Any] | None = None,
) -> tuple[OutputLock | None, ResumePoint | None]:
    """Lock ``output`` and take stock of its run for ``capture --resume`` (recovering cut-off parts).

    Returns (the held lock, the resume point), or (None, None) when there is no run to
    resume (the lock is released: a new capture starts as usual).
    """
    lock = OutputLock(os.fspath(output))
    lock.acquire()
    try:
        point = prepare_resume(os.fspath(output), config, duration_s, simulated=simulated, now=now or wall_now)
    except BaseException:
        lock.release()
        raise
    if point is None:
        lock.release()
        return None, None
    return lock, point
