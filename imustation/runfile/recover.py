"""Make a run file cut off by a crash a plain, complete HDF5 file (``imustation recover``).

After a kill or a power cut the file keeps HDF5's "open for SWMR writing" flags
in its superblock: only SWMR-aware readers open it (other tools say "already
open for write, use h5clear"), it has no ``ended_utc``, and its last block may
be torn (docs/runfile.md). :func:`recover_run` copies what the file holds into a
new file - every dataset of a device or thermometer up to their common length
(a torn block is left out), the events, every attribute - marks it recovered
(root attributes ``recovered_utc``, ``recovered`` stating what was lost,
``ended_utc`` at the last sample, a ``note`` event) and puts it under the
original name; the original is kept beside it as ``<name>.before-recover``.
"""

from __future__ import annotations

import datetime as _dt
import os
from dataclasses import dataclass, field

import h5py
import numpy as np

from imustation.errors import RunFileError
from imustation.runfile import (
    DEVICES,
    EVENT_DTYPE,
    EVENTS,
    THERMOMETERS,
    TIME,
    RunFile,
    open_run,
    utc_now_iso,
)
from imustation.runfile.checks import damaged_file
from imustation.runfile.disk import release_tail

#: suffixes of the new file while it is written, and of the original kept after a recovery
RECOVERING_SUFFIX = ".recovering"
ORIGINAL_SUFFIX = ".before-recover"
#: rows copied per read
COPY_ROWS = 1 << 20


@dataclass
class Recovery:
    """What :func:`recover_run` did: the files, the last sample time (s), rows dropped per dataset."""

    path: str
    original: str
    last_t_s: float
    dropped: dict[str, int] = field(default_factory=dict)

    def statement(self) -> str:
        torn = ", ".join(f"{k} {v}" for k, v in sorted(self.dropped.items()))
        torn = f"; torn last block left out (rows): {torn}" if torn else "; no torn block"
        return (
            f"cut off by a crash: recovered up to t = {self.last_t_s:.3f} s (the last sample on disk); samples "
            f"the capture read after its last flush before the crash were never written{torn}"
        )


def needs_recovery(path: str | os.PathLike) -> bool:
    """True when the file opens only as a SWMR reader (HDF5's write flags set: a capture writes it
    now, or was cut off). An unreadable file raises RunFileError."""
    try:
        with h5py.File(os.fspath(path), "r", locking=False):
            return False
    except OSError as exc:
        if "already open for write" in str(exc):
            return True
        raise RunFileError(f"{path}: not a readable HDF5 file ({exc.__class__.__name__})") from None


def recover_run(path: str | os.PathLike) -> Recovery | None:
    """Recover ``path`` in place (see the module docstring); None when it is complete already.

    The caller makes sure no capture writes the file (the capture's output lock).
    """
    p = os.fspath(path)
    original = p + ORIGINAL_SUFFIX
    flagged = needs_recovery(p)  # before open_run: HDF5 refuses one file open twice with other flags
    with open_run(p) as run:
        if run.complete and not flagged:
            return None
        if os.path.exists(original):
            raise RunFileError(f"{original} exists (an earlier recovery?); move it away first")
        new = p + RECOVERING_SUFFIX
        try:
            rec = _copy(run, new, original)
        except BaseException:
            if os.path.exists(new):
                os.unlink(new)
            raise
    with open_run(new):  # the copy passes every check before it replaces anything
        pass
    os.link(p, original)
    os.replace(new, p)
    release_tail(original)  # the room the killed capture kept past the file's end
    fd = os.open(os.path.dirname(os.path.abspath(p)), os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    rec.path = p
    return rec


def _copy_dataset(run: RunFile, src: h5py.Dataset, dst_group: h5py.Group, name: str, n: int) -> None:
    dst = dst_group.create_dataset(
        name, shape=(n, *src.shape[1:]), maxshape=(None, *src.shape[1:]), dtype=src.dtype, chunks=src.chunks,
        compression=src.compression, compression_opts=src.compression_opts, shuffle=src.shuffle,
        fletcher32=src.fletcher32,
    )  # fmt: skip
    for key, value in src.attrs.items():
        dst.attrs[key] = value
    for i in range(0, n, COPY_ROWS):
        with damaged_file(run.path, f"{src.name} rows {i}:{min(i + COPY_ROWS, n)}", src):
            dst[i : min(i + COPY_ROWS, n)] = src[i : min(i + COPY_ROWS, n)]


def _copy(run: RunFile, new: str, original: str) -> Recovery:
    h5 = run.h5
    rec = Recovery(path=new, original=original, last_t_s=0.0)
    last_t = 0
    with h5py.File(new, "w", libver="latest") as out:
        for key, value in h5.attrs.items():
            out.attrs[key] = value
        for gname in (DEVICES, THERMOMETERS):
            out_g = out.create_group(gname)
            for name, g in h5[gname].items():
                sub = out_g.create_group(name)
                for key, value in g.attrs.items():
                    sub.attrs[key] = value
                n = min((ds.shape[0] for ds in g.values()), default=0)
                for dname, ds in g.items():
                    if ds.shape[0] > n:
                        rec.dropped[f"{gname}/{name}/{dname}"] = ds.shape[0] - n
                    _copy_dataset(run, ds, sub, dname, n)
                if n:
                    with damaged_file(run.path, f"{gname}/{name}/t", g[TIME]):
                        last_t = max(last_t, int(np.max(g[TIME][max(0, n - COPY_ROWS) : n])))
        rec.last_t_s = last_t * 1e-9
        with damaged_file(run.path, "events", h5[EVENTS]):
            rows = h5[EVENTS][()]
        note = np.array([(last_t, b"station", b"note", 0, rec.statement().encode()[:256])], dtype=EVENT_DTYPE)
        events = np.concatenate([rows.astype(EVENT_DTYPE), note])
        out.create_dataset(EVENTS, data=events, maxshape=(None,), chunks=(256,), fletcher32=h5[EVENTS].fletcher32)
        started = _dt.datetime.fromisoformat(str(run.attrs["started_utc"]))
        ended = started + _dt.timedelta(microseconds=last_t / 1e3)
        out.attrs["ended_utc"] = ended.isoformat(timespec="milliseconds")
        out.attrs["recovered_utc"] = utc_now_iso()
        out.attrs["recovered"] = rec.statement()
        if "stopped" not in out.attrs:
            out.attrs["stopped"] = "cut off by a crash (recovered)"
        out.flush()
        os.fsync(out.id.get_vfd_handle())
    return rec
