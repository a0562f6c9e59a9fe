"""File-system helpers of the writer: durable renames and room to finish a file on a full disk."""

from __future__ import annotations

import errno
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
