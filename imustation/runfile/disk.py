"""File-system helpers of the writer: durable renames and room to finish a file on a full disk."""

from __future__ import annotations

import ctypes
import errno
import functools
import os

from imustation.errors import DiskFullError, RunFileError


def make_ballast(path: str, size: int) -> None:
    """Allocate ``size`` bytes at ``path``: room the writer frees when the disk fills up anyway."""
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


def fsync_dir(path: str) -> None:
    """Make a rename durable (the directory entry is on disk after power loss)."""
    fd = os.open(os.path.dirname(os.path.abspath(path)), os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def is_enospc(exc: Exception) -> bool:
    """HDF5 reports write failures as OSError/RuntimeError with the errno only in the message."""
    return getattr(exc, "errno", None) == errno.ENOSPC or "No space left" in str(exc) or "errno = 28" in str(exc)


# -- room allocated to the run file itself, past its end -----------------------------------
_FALLOC_FL_KEEP_SIZE = 0x01  # <linux/falloc.h>: allocate without changing the file's size
_FALLOC_FL_PUNCH_HOLE = 0x02  # free the blocks of a range (with KEEP_SIZE)
#: errors of fallocate() that mean "this filesystem cannot" rather than "no room"
_UNSUPPORTED = {errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL, errno.ENODEV}


@functools.cache
def _fallocate():
    """libc's Linux ``fallocate(2)`` (Python offers only ``posix_fallocate``, which grows the
    file's size: HDF5 would take the zeros past its end of allocation for a truncated file)."""
    try:
        func = ctypes.CDLL(None, use_errno=True).fallocate
    except (AttributeError, OSError):
        return None
    func.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    func.restype = ctypes.c_int
    return func


def reserve_tail(fd: int, nbytes: int) -> bool:
    """Allocate ``nbytes`` of disk past the end of the open file ``fd``, its size unchanged.

    Why: blocks allocated to the run file belong to it: whatever another program
    writes meanwhile, HDF5's next writes past the end land there, so the file can always
    be finished (a ballast file deleted to make room gives the room to whoever writes
    first). Blocks already allocated stay; only the missing ones are taken.
    Returns False when the filesystem cannot do it (the caller keeps a ballast file
    instead); raises :class:`DiskFullError` when the room is not there.
    """
    func = _fallocate()
    if func is None:
        return False
    if func(fd, _FALLOC_FL_KEEP_SIZE, os.fstat(fd).st_size, int(nbytes)) == 0:
        return True
    err = ctypes.get_errno()
    if err in _UNSUPPORTED:
        return False
    if err == errno.ENOSPC or err == errno.EDQUOT:
        raise DiskFullError(f"disk full: no room for {nbytes / 2**20:.1f} MiB past the end of the run file")
    raise OSError(err, os.strerror(err))


def release_tail(path: str) -> None:
    """Give back the blocks allocated past the end of the file at ``path`` (its size unchanged)."""
    try:
        fd = os.open(path, os.O_WRONLY)
    except OSError:
        return
    try:
        size = os.fstat(fd).st_size
        func = _fallocate()
        # the whole range past the end: fallocate takes off_t lengths, 2^62 stays clear of overflow
        if func is None or func(fd, _FALLOC_FL_PUNCH_HOLE | _FALLOC_FL_KEEP_SIZE, size, 2**62 - size) != 0:
            os.ftruncate(fd, size)  # frees blocks past the end on Linux filesystems
    finally:
        os.close(fd)
