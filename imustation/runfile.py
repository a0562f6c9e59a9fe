"""Run-file format, version 1: names, schema, writer and reader in one place.

One HDF5 file per capture (see ``docs/runfile.md`` for the full description).
Raw integer counts are stored, never only converted floats: the conversion is
kept as attributes (``value = raw * scale + offset``, SI units), so nothing is
lost and files stay small.

The recorder (``imustation.acquisition``) writes through :class:`RunWriter`;
the analysis and ``imustation inspect`` read through :func:`open_run`. Nothing
else touches the HDF5 layout.

Crash safety: the file is written in HDF5 SWMR mode (``libver="latest"``):
every dataset exists before recording starts, data are appended in blocks and
flushed at least every ``flush_interval_s`` seconds of host time, so a file cut
off by a crash opens and reads up to the last flush, and readers may open it
while it is being written. ``ended_utc`` is set only by a clean close.
"""

from __future__ import annotations

import datetime as _dt
import errno
import os
import socket
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import h5py
import numpy as np

from imustation import __version__
from imustation.errors import DiskFullError, ImustationError, RunFileError
from imustation.h5swmr import open_swmr_reader

FORMAT = "imustation-run"
FORMAT_VERSION = 1

DEVICES = "devices"
THERMOMETERS = "thermometers"
EVENTS = "events"
TIME = "t"  # int64 ns since started_utc, host monotonic clock
COUNTER = "counter"  # int64 device sample counter, where the device has one
CELSIUS = "celsius"

#: kinds of event a run file may hold (design.md, run-file format)
EVENT_KINDS = ("gap", "resync", "reconnect", "overrun", "checksum", "config", "note", "fault")
EVENT_DTYPE = np.dtype(
    [
        ("t", "<i8"),  # ns since started_utc
        ("source", "S64"),  # device or thermometer name, or "station"
        ("kind", "S16"),  # one of EVENT_KINDS
        ("lost", "<i8"),  # samples lost (gaps, overruns); 0 when not applicable
        ("detail", "S256"),  # free text, truncated to 256 bytes
    ]
)

#: HDF5 storage options for every appendable dataset; gzip-1 + shuffle packs
#: int16 sensor counts about 2-3x at a small CPU cost.
H5_OPTS: dict[str, Any] = {"compression": "gzip", "compression_opts": 1, "shuffle": True}
CHUNK_ROWS = 8192
#: free space a flush leaves on the filesystem (room to close the file cleanly)
DEFAULT_MIN_FREE_BYTES = 16 * 2**20
#: suffix of a run file while it is being created (renamed when valid)
CREATING_SUFFIX = ".creating"
#: room kept beside a run file to finish it when the disk fills up anyway
BALLAST_SUFFIX = ".ballast"
DEFAULT_BALLAST_BYTES = 4 * 2**20


@dataclass(frozen=True)
class ChannelSpec:
    """One recorded quantity of a device: ``gyro``, ``accel`` or ``temp``.

    ``value [units] = raw * scale + offset``; ``axes`` is ``("x", "y", "z")``
    for vector channels and ``()`` for scalars.
    """

    name: str
    dtype: str
    units: str
    scale: float
    offset: float = 0.0
    axes: tuple[str, ...] = ()


@dataclass(frozen=True)
class DeviceSpec:
    """What the recorder knows about a device before the first sample."""

    name: str
    driver: str
    model: str
    bus: str
    identity: str
    rate_hz: float
    settings: Mapping[str, Any]
    channels: tuple[ChannelSpec, ...]
    has_counter: bool = False


def utc_now_iso() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


def _attr_value(value: Any) -> Any:
    """Map a setting value to something HDF5 stores as an attribute."""
    if value is None:
        return "none"
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, float, str, np.integer, np.floating)):
        return value
    return str(value)


class RunWriter:
    """Append-only writer of one run file.

    Parameters
    ----------
    path : file to create; an existing file is refused unless ``overwrite``.
    devices, thermometers : everything that will be recorded (SWMR forbids
        creating datasets once recording has started).
    flush_interval_s : host seconds between flushes (data older than this is on disk).
    part, previous_part, run_id, part_started_utc : set when the capture is
        rotated into several files (root attributes, see docs/runfile.md).
    fsync : after each flush, ask the OS to put the file on the disk (power loss).
    min_free_bytes : a flush that would leave less free space than this on the
        file's filesystem is refused with :class:`DiskFullError` *before*
        writing, so the file stays complete and can still be closed cleanly.
    ballast_bytes : size of ``<path>.ballast``, a file allocated beside the run
        file and deleted when a write fails with ENOSPC anyway (another program
        filled the disk): the freed room lets HDF5 finish its flush and close
        the file cleanly (a file HDF5 cannot flush stays half-open in the
        process, and the library crashes at exit). 0 disables it.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        station: str,
        config_text: str,
        simulated: bool,
        devices: Sequence[DeviceSpec],
        thermometers: Sequence[str] = (),
        flush_interval_s: float = 1.0,
        overwrite: bool = False,
        started_utc: str | None = None,
        max_buffer_rows: int = 1 << 20,
        part: int | None = None,
        previous_part: str = "",
        run_id: str = "",
        part_started_utc: str | None = None,
        fsync: bool = True,
        min_free_bytes: int = DEFAULT_MIN_FREE_BYTES,
        ballast_bytes: int = DEFAULT_BALLAST_BYTES,
    ):
        self.path = os.fspath(path)
        self.flush_interval_s = float(flush_interval_s)
        self.max_buffer_rows = int(max_buffer_rows)
        self.fsync = bool(fsync)
        self.min_free_bytes = int(min_free_bytes)
        self.closed = True
        if not overwrite and os.path.exists(self.path):
            raise RunFileError(f"{self.path}: file exists; choose another name or --overwrite")
        # built under a temporary name and renamed once it is a valid SWMR file, so
        # a crash while creating it never leaves an unreadable file at ``path``
        creating = self.path + CREATING_SUFFIX
        self._ballast = self.path + BALLAST_SUFFIX if ballast_bytes > 0 else None
        if self._ballast is not None:
            _make_ballast(self._ballast, ballast_bytes)
        try:
            self._f = h5py.File(creating, "w", libver="latest")
        except OSError as exc:
            raise RunFileError(f"{self.path}: cannot create run file: {exc}") from exc
        self.closed = False
        #: set once a write failed half-way (disk full): nothing more is written
        self.broken = False
        f = self._f
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["station"] = station
        f.attrs["started_utc"] = started_utc or utc_now_iso()
        f.attrs["config"] = config_text
        f.attrs["software_version"] = __version__
        f.attrs["host"] = socket.gethostname()
        f.attrs["simulated"] = bool(simulated)
        if part is not None:
            f.attrs["part"] = int(part)
            f.attrs["previous_part"] = previous_part
            f.attrs["run_id"] = run_id
            f.attrs["part_started_utc"] = part_started_utc or utc_now_iso()

        self.devices = {d.name: d for d in devices}
        self._buffers: dict[tuple[str, str], list[np.ndarray]] = {}
        self._datasets: dict[tuple[str, str], h5py.Dataset] = {}
        self._pending_rows = 0
        self._pending_bytes = 0
        self.samples_written: dict[str, int] = {d.name: 0 for d in devices}
        #: rows of each device on disk (after the last successful flush)
        self.samples_flushed: dict[str, int] = {d.name: 0 for d in devices}
        self._queued: dict[str, int] = {d.name: 0 for d in devices}
        self._last_t: dict[str, int] = {}
        dgrp = f.create_group(DEVICES)
        for dev in devices:
            g = dgrp.create_group(dev.name)
            g.attrs["driver"] = dev.driver
            g.attrs["model"] = dev.model
            g.attrs["bus"] = dev.bus
            g.attrs["identity"] = dev.identity
            g.attrs["rate_hz"] = float(dev.rate_hz)
            for key, value in dev.settings.items():
                if key != "rate_hz":
                    g.attrs[key] = _attr_value(value)
            # data channels before t: a block torn by a crash mid-flush then
            # tends to lack its times rather than its data (readers use the
            # shortest dataset of a device either way)
            for ch in dev.channels:
                ds = self._create(g, dev.name, ch.name, ch.dtype, (len(ch.axes),) if ch.axes else ())
                ds.attrs["scale"] = float(ch.scale)
                ds.attrs["offset"] = float(ch.offset)
                ds.attrs["units"] = ch.units
                ds.attrs["axes"] = ",".join(ch.axes)
            if dev.has_counter:
                self._create(g, dev.name, COUNTER, "<i8", ())
            self._create(g, dev.name, TIME, "<i8", ())
        tgrp = f.create_group(THERMOMETERS)
        self.thermometers = tuple(thermometers)
        for name in self.thermometers:
            g = tgrp.create_group(name)
            ds = self._create(g, THERMOMETERS + "/" + name, CELSIUS, "<f8", ())
            ds.attrs["units"] = "degC"
            self._create(g, THERMOMETERS + "/" + name, TIME, "<i8", ())
        self._events = f.create_dataset(EVENTS, shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE, chunks=(256,))
        self._event_buffer: list[tuple] = []
        f.swmr_mode = True
        f.flush()
        if self.fsync:
            os.fsync(f.id.get_vfd_handle())
        os.replace(creating, self.path)
        _fsync_dir(self.path)
        self._last_flush = time.monotonic()

    # -- creation -----------------------------------------------------------
    def _create(self, group: h5py.Group, owner: str, name: str, dtype: str, tail: tuple[int, ...]):
        ds = group.create_dataset(
            name,
            shape=(0, *tail),
            maxshape=(None, *tail),
            dtype=dtype,
            chunks=(CHUNK_ROWS, *tail),
            **H5_OPTS,
        )
        key = (owner, name)
        self._buffers[key] = []
        self._datasets[key] = ds
        return ds

    # -- appending ----------------------------------------------------------
    def append(
        self,
        device: str,
        t_ns: np.ndarray,
        channels: Mapping[str, np.ndarray],
        counter: np.ndarray | None = None,
    ) -> None:
        """Queue one block of samples of ``device``: ``t_ns`` (k,), each channel (k, ...)."""
        dev = self.devices[device]
        k = len(t_ns)
        if k == 0:
            return
        buffers = self._buffers
        nbytes = 8 * k
        for ch in dev.channels:
            data = channels[ch.name]
            if len(data) != k:
                raise ValueError(f"{device}/{ch.name}: {len(data)} rows for {k} timestamps")
            data = np.asarray(data, dtype=ch.dtype)
            buffers[(device, ch.name)].append(data)
            nbytes += data.nbytes
        if dev.has_counter:
            if counter is None or len(counter) != k:
                raise ValueError(f"{device}: counter missing or of wrong length")
            buffers[(device, COUNTER)].append(np.asarray(counter, dtype="<i8"))
            nbytes += 8 * k
        buffers[(device, TIME)].append(np.asarray(t_ns, dtype="<i8"))
        self._last_t[device] = int(t_ns[-1])
        self._queued[device] += k
        self._pending_rows += k
        self._pending_bytes += nbytes
        self.samples_written[device] += k
        self._maybe_flush()

    def append_temperature(self, name: str, t_ns: np.ndarray, celsius: np.ndarray) -> None:
        """Queue thermometer readings: times ``t_ns`` (k,) and ``celsius`` (k,), degC."""
        owner = THERMOMETERS + "/" + name
        if len(t_ns) != len(celsius):
            raise ValueError(f"thermometer {name}: {len(celsius)} readings for {len(t_ns)} timestamps")
        self._buffers[(owner, CELSIUS)].append(np.asarray(celsius, dtype="<f8"))
        self._buffers[(owner, TIME)].append(np.asarray(t_ns, dtype="<i8"))
        self._pending_rows += len(t_ns)
        self._pending_bytes += 16 * len(t_ns)
        self._maybe_flush()

    def event(self, t_ns: int, source: str, kind: str, detail: str = "", lost: int = 0) -> None:
        if kind not in EVENT_KINDS:
            raise ValueError(f"event kind {kind!r} not in {EVENT_KINDS}")
        self._event_buffer.append((int(t_ns), source.encode()[:64], kind.encode(), int(lost), detail.encode()[:256]))
        self._pending_bytes += EVENT_DTYPE.itemsize

    def _maybe_flush(self) -> None:
        if self._pending_rows >= self.max_buffer_rows or self.flush_due():
            self.flush()

    def flush_due(self) -> bool:
        """True when ``flush_interval_s`` of host time has passed since the last flush.

        The one place the writer reads the host clock: tests replace it with an
        explicit trigger so that what they check does not depend on machine speed.
        """
        return time.monotonic() - self._last_flush >= self.flush_interval_s

    def flush_if_due(self) -> None:
        """Flush when ``flush_interval_s`` has passed (call it when no data arrive)."""
        if self.flush_due():
            self.flush()

    def free_bytes(self) -> int:
        """Free bytes (for unprivileged users) on the filesystem holding the file."""
        st = os.statvfs(os.path.dirname(os.path.abspath(self.path)))
        return st.f_bavail * st.f_frsize

    def flush(self, *, reserve: bool = True) -> None:
        """Write every queued block and flush the file to disk.

        Raises :class:`DiskFullError` when the filesystem is (nearly) full: either
        before writing (free space below ``min_free_bytes``; the file is intact and
        can be closed cleanly) or when a write failed with ENOSPC (the file keeps
        what the previous flush wrote; the writer is then ``broken``).
        ``reserve=False`` (the final flush of :meth:`close`) may use the reserve.
        """
        if self.broken:
            raise DiskFullError(f"{self.path}: the run file can no longer be written (disk full)")
        if reserve and self._pending_bytes and self.min_free_bytes > 0:
            free = self.free_bytes()
            if free < self.min_free_bytes + self._pending_bytes:
                raise DiskFullError(
                    f"{self.path}: disk full ({free / 2**20:.1f} MiB free, keeping {self.min_free_bytes / 2**20:.1f} "
                    "MiB in reserve); capture stopped"
                )
        extents = {key: ds.shape[0] for key, ds in self._datasets.items()}
        extents[(EVENTS, "")] = self._events.shape[0]
        events = list(self._event_buffer)
        try:
            self._write_pending()
            self._f.flush()
            if self.fsync:
                os.fsync(self._f.id.get_vfd_handle())
        except (OSError, RuntimeError) as exc:  # h5py raises RuntimeError for a failed H5Fflush
            if not _is_enospc(exc):
                raise
            if self._drop_ballast() and self._roll_back(extents, events):
                raise DiskFullError(
                    f"{self.path}: disk full while writing (no space left on device); capture stopped, "
                    "the last block is logged as lost"
                ) from exc
            self.broken = True
            raise DiskFullError(
                f"{self.path}: disk full while writing (no space left on device); capture stopped, "
                "the file holds the data up to the previous flush"
            ) from exc
        for name, k in self._queued.items():
            self.samples_flushed[name] += k
            self._queued[name] = 0
        self._last_flush = time.monotonic()

    def _write_pending(self) -> None:
        for key, parts in self._buffers.items():
            if not parts:
                continue
            data = np.concatenate(parts) if len(parts) > 1 else parts[0]
            parts.clear()
            ds = self._datasets[key]
            n0 = ds.shape[0]
            ds.resize(n0 + len(data), axis=0)
            ds[n0:] = data
        self._pending_rows = 0
        self._pending_bytes = 0
        if self._event_buffer:
            rows = np.array(self._event_buffer, dtype=EVENT_DTYPE)
            self._event_buffer.clear()
            n0 = self._events.shape[0]
            self._events.resize(n0 + len(rows), axis=0)
            self._events[n0:] = rows

    def _roll_back(self, extents: Mapping[tuple[str, str], int], events: list[tuple]) -> bool:
        """After ENOSPC, with room again: cut every dataset back to its extent before
        the failed flush (HDF5 may have extended a dataset whose chunks it could not
        write), log the dropped rows as lost, and flush. False if that fails too."""
        try:
            for key, ds in self._datasets.items():
                if ds.shape[0] > extents[key]:
                    ds.resize(extents[key], axis=0)
            if self._events.shape[0] > extents[(EVENTS, "")]:
                self._events.resize(extents[(EVENTS, "")], axis=0)
            self._event_buffer[:0] = events
            self.discard_pending()
            self._write_pending()
            self._f.flush()
            if self.fsync:
                os.fsync(self._f.id.get_vfd_handle())
        except (OSError, RuntimeError):
            return False
        return True

    def _drop_ballast(self) -> bool:
        if self._ballast is None:
            return False
        try:
            os.unlink(self._ballast)
        except OSError:
            pass
        self._ballast = None
        return True

    def discard_pending(self) -> None:
        """Drop the queued blocks (the disk is full), logging them as lost samples.

        Events stay queued; one ``gap`` event per device tells how many samples
        were dropped, so written + logged losses still add up.
        """
        for parts in self._buffers.values():
            parts.clear()
        for name, k in self._queued.items():
            if k:
                self.samples_written[name] -= k
                detail = b"disk full: samples not written"
                self._event_buffer.append((self._last_t.get(name, 0), name.encode()[:64], b"gap", k, detail))
            self._queued[name] = 0
        self._pending_rows = 0
        self._pending_bytes = len(self._event_buffer) * EVENT_DTYPE.itemsize

    def file_bytes(self) -> int:
        try:
            return os.path.getsize(self.path)
        except OSError:
            return 0

    def close(self, ended_utc: str | None = None, attrs: Mapping[str, Any] | None = None) -> None:
        """Flush, close, and mark the file complete with ``ended_utc`` (plus ``attrs``)."""
        if self.closed:
            return
        try:
            self.flush(reserve=False)
        finally:
            self._f.close()
            self.closed = True
            self._drop_ballast()
        # SWMR writers may not add attributes; reopen once to mark the run complete.
        # Without HDF5's file lock: a SWMR reader (open_run, h5py with swmr=True) holds
        # a shared lock for as long as it has the file open, and the capture must finish
        # its file whatever readers do (the OutputLock keeps other writers out).
        with h5py.File(self.path, "r+", libver="latest", locking=False) as f:
            for key, value in (attrs or {}).items():
                f.attrs[key] = _attr_value(value)
            f.attrs["ended_utc"] = ended_utc or utc_now_iso()

    def abort(self) -> None:
        """Close without marking the run complete (used when the capture failed).

        Queued blocks are written when the file is still writable; a write error
        here is swallowed, since the capture is already failing for another reason.
        """
        if self.closed:
            return
        try:
            if not self.broken:
                self.flush()
        except (OSError, ImustationError):
            pass
        finally:
            try:
                self._f.close()
            except Exception:  # noqa: BLE001 - HDF5 may refuse to close a file it could not write
                pass
            self.closed = True
            self._drop_ballast()

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _make_ballast(path: str, size: int) -> None:
    try:
        fd = os.open(path, os.O_CREAT | os.O_WRONLY | os.O_TRUNC, 0o644)
        try:
            os.posix_fallocate(fd, 0, size)
        finally:
            os.close(fd)
    except OSError as exc:
        try:
            os.unlink(path)
        except OSError:
            pass
        if exc.errno == errno.ENOSPC:
            raise DiskFullError(f"{path}: disk full before the capture started") from None
        raise RunFileError(f"{path}: cannot create: {exc.strerror}") from None


def _fsync_dir(path: str) -> None:
    """Make a rename durable (the directory entry is on disk after power loss)."""
    fd = os.open(os.path.dirname(os.path.abspath(path)), os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _is_enospc(exc: Exception) -> bool:
    """HDF5 reports write failures as OSError/RuntimeError with the errno only in the message."""
    return getattr(exc, "errno", None) == errno.ENOSPC or "No space left" in str(exc) or "errno = 28" in str(exc)


# ---------------------------------------------------------------------------
# reading


@dataclass(frozen=True)
class ChannelInfo:
    name: str
    dtype: np.dtype
    units: str
    scale: float
    offset: float
    axes: tuple[str, ...]
    n: int


@dataclass(frozen=True)
class DeviceInfo:
    name: str
    driver: str
    model: str
    bus: str
    identity: str
    rate_hz: float
    settings: dict[str, Any]
    channels: dict[str, ChannelInfo]
    #: rows every dataset of the device holds (the shortest one: see ``rows``)
    n: int
    has_counter: bool
    #: rows per dataset; they differ only in a file cut off while a flush was
    #: being written (a torn last block), and readers use the first ``n`` rows
    rows: dict[str, int] = field(default_factory=dict)

    @property
    def torn(self) -> bool:
        return any(r != self.n for r in self.rows.values())


@dataclass(frozen=True)
class Event:
    t_ns: int
    source: str
    kind: str
    lost: int
    detail: str


_DEVICE_CORE_ATTRS = {"driver", "model", "bus", "identity"}


def _plain(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    return value


@dataclass
class RunFile:
    """An open run file (read-only). Use :func:`open_run`; close or use ``with``."""

    path: str
    h5: h5py.File
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        """True when the capture closed cleanly (``ended_utc`` present)."""
        return "ended_utc" in self.attrs

    @property
    def devices(self) -> dict[str, DeviceInfo]:
        out = {}
        for name, g in self.h5.get(DEVICES, {}).items():
            attrs = {k: _plain(v) for k, v in g.attrs.items()}
            channels = {}
            for cname, ds in g.items():
                if cname in (TIME, COUNTER):
                    continue
                axes = _plain(ds.attrs.get("axes", ""))
                channels[cname] = ChannelInfo(
                    name=cname,
                    dtype=ds.dtype,
                    units=_plain(ds.attrs.get("units", "")),
                    scale=float(ds.attrs.get("scale", 1.0)),
                    offset=float(ds.attrs.get("offset", 0.0)),
                    axes=tuple(axes.split(",")) if axes else (),
                    n=ds.shape[0],
                )
            settings = {k: v for k, v in attrs.items() if k not in _DEVICE_CORE_ATTRS}
            out[name] = DeviceInfo(
                name=name,
                driver=attrs.get("driver", ""),
                model=attrs.get("model", ""),
                bus=attrs.get("bus", ""),
                identity=str(attrs.get("identity", "")),
                rate_hz=float(attrs.get("rate_hz", float("nan"))),
                settings=settings,
                channels=channels,
                n=min((ds.shape[0] for ds in g.values()), default=0),
                has_counter=COUNTER in g,
                rows={k: ds.shape[0] for k, ds in g.items()},
            )
        return out

    @property
    def thermometers(self) -> list[str]:
        return list(self.h5.get(THERMOMETERS, {}).keys())

    def events(self) -> list[Event]:
        from imustation.runfile_checks import read_events

        return read_events(self.path, self.h5)

    def dataset(self, device: str, name: str) -> h5py.Dataset:
        from imustation.runfile_checks import CheckedDataset

        try:
            return CheckedDataset(self.h5[f"{DEVICES}/{device}/{name}"], self.path, f"{device}/{name}")
        except KeyError:
            raise RunFileError(f"{self.path}: no dataset {device}/{name}") from None

    def rows(self, device: str) -> int:
        """Rows every dataset of ``device`` holds (a torn last block is left out)."""
        g = self.h5.get(f"{DEVICES}/{device}")
        if g is None:
            raise RunFileError(f"{self.path}: no device {device}")
        return min((ds.shape[0] for ds in g.values()), default=0)

    def read(self, device: str, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Raw rows ``start:stop`` of ``devices/<device>/<name>`` (at most :meth:`rows`)."""
        n = self.rows(device)
        return self.dataset(device, name)[start : n if stop is None else min(stop, n)]

    def iter_chunks(self, device: str, name: str, rows: int = 1 << 22, stop: int | None = None) -> Iterator[np.ndarray]:
        """Read a dataset in blocks of ``rows`` so memory stays bounded."""
        ds = self.dataset(device, name)
        n = self.rows(device) if stop is None else min(stop, self.rows(device))
        for i in range(0, n, rows):
            yield ds[i : min(i + rows, n)]

    def temperatures(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Thermometer ``name``: times (ns) and readings (degC), equal lengths."""
        from imustation.runfile_checks import damaged_file

        g = self.h5[f"{THERMOMETERS}/{name}"]
        n = min(g[TIME].shape[0], g[CELSIUS].shape[0])
        with damaged_file(self.path, f"thermometer {name}"):
            return g[TIME][:n], g[CELSIUS][:n]

    def refresh(self) -> None:
        """SWMR reader: see what the writer flushed since the file was opened (or last refreshed).

        Refreshes every dataset's extent (devices, thermometers, events); a file
        opened without SWMR is left as it is.
        """
        if not self.h5.swmr_mode:
            return
        for gname in (DEVICES, THERMOMETERS):
            for g in self.h5.get(gname, {}).values():
                for ds in g.values():
                    ds.refresh()
        if EVENTS in self.h5:
            self.h5[EVENTS].refresh()

    def close(self) -> None:
        self.h5.close()

    def __enter__(self) -> RunFile:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_run(path: str | os.PathLike, *, live: bool = False) -> RunFile:
    """Open a run file read-only (also while it is being written).

    ``live=True`` (a reader kept beside a running capture, e.g. the monitor):
    SWMR read only, never the plain read-only fallback, which holds a shared
    file lock that would keep the capture from marking the file complete.

    Raises :class:`RunFileError` with a one-line reason for a missing file,
    a file that is not HDF5, not an imustation run, or of an unknown version.
    """
    p = os.fspath(path)
    if not os.path.exists(p):
        raise RunFileError(f"{p}: no such file")
    try:
        # a live reader takes no file lock at all: even the short one HDF5 holds while
        # opening could make the capture's final reopen (to set ended_utc) fail
        h5 = open_swmr_reader(p, locking=False if live else None)
    except OSError as first:
        if live:
            raise RunFileError(f"{p}: not a readable SWMR run file ({first.__class__.__name__})") from None
        try:  # a file written without SWMR (e.g. by another tool) still opens
            h5 = h5py.File(p, "r")
        except OSError as exc:
            raise RunFileError(f"{p}: not a readable HDF5 file ({exc.__class__.__name__})") from None
    from imustation.runfile_checks import check_run  # it reads this module's schema names

    try:
        attrs = check_run(h5, p)
    except RunFileError:
        h5.close()
        raise
    return RunFile(path=p, h5=h5, attrs=attrs)
