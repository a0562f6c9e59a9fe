"""Writing run files: :class:`RunWriter`, the one writer of the format.

The recorder (``imustation.acquisition``) writes through it.

Crash safety: the file is written in HDF5 SWMR mode (``libver="latest"``):
every dataset exists before recording starts, data are appended in blocks and
flushed at least every ``flush_interval_s`` seconds of host time, so a file cut
off by a crash opens and reads up to the last flush, and readers may open it
while it is being written. ``ended_utc`` is set only by a clean close.

Over 500 lines on purpose: one class that alone knows how the layout is written (datasets
made before recording, appends, flushes, the clean close); reading and checking the format
live in their own modules.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Mapping, Sequence
from typing import Any

import h5py
import numpy as np

from imustation import __version__
from imustation.errors import DiskFullError, ImustationError, RunFileError
from imustation.runfile.disk import fsync_dir, is_enospc, make_ballast, release_tail, reserve_tail
from imustation.runfile.schema import (
    CELSIUS,
    COUNTER,
    DEVICES,
    EVENT_DTYPE,
    EVENT_KINDS,
    EVENTS,
    FORMAT,
    FORMAT_VERSION,
    THERMOMETERS,
    TIME,
    DeviceSpec,
    utc_now_iso,
)

#: HDF5 storage options for every appendable dataset; gzip-1 + shuffle packs
#: int16 sensor counts about 2-3x at a small CPU cost. fletcher32 stores a
#: checksum with every chunk: a flipped byte inside compressed data that still
#: decompresses would otherwise read as wrong numbers without a word (a storage
#: filter, invisible to readers: the format version stays 1).
H5_OPTS: dict[str, Any] = {"compression": "gzip", "compression_opts": 1, "shuffle": True, "fletcher32": True}
CHUNK_ROWS = 8192
#: free space a flush leaves on the filesystem (room to close the file cleanly)
DEFAULT_MIN_FREE_BYTES = 16 * 2**20
#: suffix of a run file while it is being created (renamed when valid)
CREATING_SUFFIX = ".creating"
#: room kept to finish a run file when the disk fills up anyway: allocated past the file's
#: end, or as ``<name>.ballast`` beside it where the filesystem cannot (see RunWriter)
BALLAST_SUFFIX = ".ballast"
DEFAULT_BALLAST_BYTES = 4 * 2**20
#: HDF5 metadata a flush may add beyond its data (chunk index, object headers, free-space
#: aggregators of 2 KiB each), counted generously
FLUSH_METADATA_BYTES = 2**16


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
        creating datasets once recording has started). ``thermometers``: names,
        or a mapping of each name to its configured poll rate, Hz, stored as the
        group's ``rate_hz`` (what the file alone checks its readings against;
        names alone store none: an imported log has no configured rate).
    flush_interval_s : host seconds between flushes (data older than this is on disk).
    part, previous_part, run_id, part_started_utc : set when the capture is
        rotated into several files (root attributes, see docs/runfile.md).
    fsync : after each flush, ask the OS to put the file on the disk (power loss).
    min_free_bytes : a flush that would leave less free space than this on the
        file's filesystem is refused with :class:`DiskFullError` *before*
        writing, so the file stays complete and can still be closed cleanly.
    ballast_bytes : room kept to finish the file however full the disk gets
        (another program may fill it at any moment): allocated to the run file
        itself past its end (``fallocate`` with ``FALLOC_FL_KEEP_SIZE``; the size
        HDF5 sees is unchanged). Before every flush the writer allocates the room
        that flush can take plus ``ballast_bytes``; when the disk cannot give it the
        flush is refused before writing, so the file always has ``ballast_bytes``
        allocated to close it, which no other program can take (the extra room
        is given back at close). On a filesystem without ``fallocate`` it is
        ``<path>.ballast`` beside the file, deleted when a write fails with
        ENOSPC (a file HDF5 cannot flush stays half-open in the process, and
        the library crashes at exit). 0 disables it.
    attrs : extra root attributes (additive: the host clock's synchronisation state, docs/runfile.md).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        station: str,
        config_text: str,
        simulated: bool,
        devices: Sequence[DeviceSpec],
        thermometers: Sequence[str] | Mapping[str, float] = (),
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
        attrs: Mapping[str, Any] | None = None,
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
        self.ballast_bytes = max(0, int(ballast_bytes))
        #: the room to finish the file is allocated past its end (else a ballast file)
        self._tail = False
        self._ballast: str | None = None
        try:
            self._f = h5py.File(creating, "w", libver="latest")
        except OSError as exc:
            raise RunFileError(f"{self.path}: cannot create run file: {exc}") from exc
        if self.ballast_bytes:
            try:
                self._tail = reserve_tail(self._f.id.get_vfd_handle(), self.ballast_bytes + FLUSH_METADATA_BYTES)
                if not self._tail:
                    self._ballast = self.path + BALLAST_SUFFIX
                    make_ballast(self._ballast, self.ballast_bytes)
            except BaseException as exc:
                self._f.close()
                os.unlink(creating)
                if isinstance(exc, DiskFullError):
                    raise DiskFullError(f"{self.path}: disk full before the capture started") from None
                raise
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
        for key, value in (attrs or {}).items():  # additive root attributes (the host clock's state)
            f.attrs[key] = _attr_value(value)

        self.devices = {d.name: d for d in devices}
        self._buffers: dict[tuple[str, str], list[np.ndarray]] = {}
        self._datasets: dict[tuple[str, str], h5py.Dataset] = {}
        #: bytes of one uncompressed chunk per dataset (a flush rewrites a dataset's last chunk)
        self._chunk_bytes: dict[tuple[str, str], int] = {}
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
        rates = thermometers if isinstance(thermometers, Mapping) else {}
        for name in self.thermometers:
            g = tgrp.create_group(name)
            if name in rates:
                g.attrs["rate_hz"] = float(rates[name])
            ds = self._create(g, THERMOMETERS + "/" + name, CELSIUS, "<f8", ())
            ds.attrs["units"] = "degC"
            self._create(g, THERMOMETERS + "/" + name, TIME, "<i8", ())
        self._events = f.create_dataset(
            EVENTS, shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE, chunks=(256,), fletcher32=True
        )
        self._event_buffer: list[tuple] = []
        f.swmr_mode = True
        f.flush()
        if self.fsync:
            os.fsync(f.id.get_vfd_handle())
        os.replace(creating, self.path)
        fsync_dir(self.path)
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
        self._chunk_bytes[key] = int(np.prod(ds.chunks)) * ds.dtype.itemsize
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
        if self._tail:
            try:
                reserve_tail(self._f.id.get_vfd_handle(), self.ballast_bytes + self._flush_room())
            except DiskFullError:
                if reserve:
                    raise DiskFullError(
                        f"{self.path}: disk full (no room for the next block beside the "
                        f"{self.ballast_bytes / 2**20:.1f} MiB kept to finish the file); capture stopped"
                    ) from None
                # closing: the room kept past the end since the last flush holds it
        extents = {key: ds.shape[0] for key, ds in self._datasets.items()}
        extents[(EVENTS, "")] = self._events.shape[0]
        events = list(self._event_buffer)
        try:
            self._write_pending()
            self._f.flush()
            if self.fsync:
                os.fsync(self._f.id.get_vfd_handle())
        except (OSError, RuntimeError) as exc:  # h5py raises RuntimeError for a failed H5Fflush
            if not is_enospc(exc):
                raise
            if (self._drop_ballast() or self._tail) and self._roll_back(extents, events):
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

    def _flush_room(self) -> int:
        """Bytes the next flush may add to the file, at most: its data (gzip never grows a
        chunk by more than 0.1 % + 12 bytes; HDF5 stores one it would grow unfiltered), one
        whole chunk per dataset written (its last chunk, rewritten elsewhere when its size
        changes), and the metadata."""
        room = self._pending_bytes + FLUSH_METADATA_BYTES
        for key, parts in self._buffers.items():
            if parts:
                room += self._chunk_bytes[key]
        if self._event_buffer:
            room += int(np.prod(self._events.chunks)) * EVENT_DTYPE.itemsize
        return room + room // 512

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
            if not self.broken:
                self._keep_tail()
        # SWMR writers may not add attributes; reopen once to mark the run complete.
        # Without HDF5's file lock: a SWMR reader (open_run, h5py with swmr=True) holds
        # a shared lock for as long as it has the file open, and the capture must finish
        # its file whatever readers do (the OutputLock keeps other writers out).
        try:
            with h5py.File(self.path, "r+", libver="latest", locking=False) as f:
                for key, value in (attrs or {}).items():
                    f.attrs[key] = _attr_value(value)
                f.attrs["ended_utc"] = ended_utc or utc_now_iso()
        finally:
            self._release_tail()

    def _keep_tail(self) -> None:
        """Between closing the SWMR file and reopening it to mark it complete: should HDF5 have
        cut the file to its end of allocation (which frees what lies past it), take the room
        again if the disk has it (what the reopen needs is small; best effort)."""
        if not self._tail:
            return
        try:
            fd = os.open(self.path, os.O_WRONLY)
        except OSError:
            return
        try:
            reserve_tail(fd, FLUSH_METADATA_BYTES)
        except (OSError, DiskFullError):
            pass
        finally:
            os.close(fd)

    def _release_tail(self) -> None:
        if self._tail:
            self._tail = False
            release_tail(self.path)

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
            self._release_tail()

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
