"""Outputs of the commands that write: checked before any work, never replaced without ``--overwrite``.

Every command that writes a file or a folder (``capture``, ``import``, ``demo``,
``export``, ``study``, ``report``, ``fleet``) checks its outputs first, so a
missing folder, a file where a folder is needed, an unwritable place or an
existing output is one :class:`~imustation.errors.InputError` line (exit status
2) before minutes of capture or fitting, not a traceback after them.
:func:`fresh_folder` removes the folders a failed command created.
Only the standard library: the CLI calls these before loading anything heavy.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterable, Iterator

from imustation.errors import InputError


def _nearest_existing(path: str) -> str:
    p = os.path.abspath(path)
    while not os.path.exists(p):
        p = os.path.dirname(p)
    return p


def check_file(path: str | os.PathLike, *, overwrite: bool, option: str = "-o") -> str:
    """``path`` can be written as a new file (or replace one with ``overwrite``); returns it.

    Refused, naming ``option``: an existing folder, a folder that does not exist or is a
    file, a folder that is not writable, an existing file without ``overwrite``, an
    existing file that cannot be written.
    """
    p = os.fspath(path)
    if not p:
        raise InputError(f"{option}: empty file name")
    if os.path.isdir(p):
        raise InputError(f"{option} {p}: is a folder; give a file name")
    folder = os.path.dirname(p) or "."
    if not os.path.isdir(folder):
        what = "is a file, not a folder" if os.path.exists(folder) else "does not exist"
        raise InputError(f"{option} {p}: folder {folder} {what}")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"{option} {p}: folder {folder} is not writable")
    if os.path.lexists(p):
        if not overwrite:
            raise InputError(f"{option} {p}: file exists; choose another name or --overwrite")
        if not os.access(p, os.W_OK):
            raise InputError(f"{option} {p}: file exists and is not writable")
    return p


def check_folder(path: str | os.PathLike, *, overwrite: bool, writes: Iterable[str] = (), option: str = "-o") -> str:
    """``path`` is, or can be made, a writable folder, and none of ``writes`` (names the command
    writes inside it: files or sub-folders) exists unless ``overwrite``; returns it.

    Missing folders are fine (they are created, parents too); refused, naming ``option``:
    ``path`` or a parent being a file, an unwritable place, an existing output (an empty
    sub-folder does not count).
    """
    p = os.fspath(path)
    if not p:
        raise InputError(f"{option}: empty folder name")
    if os.path.exists(p) and not os.path.isdir(p):
        raise InputError(f"{option} {p}: is a file; give a folder (this command writes several files)")
    base = _nearest_existing(p)
    if not os.path.isdir(base):
        raise InputError(f"{option} {p}: {base} is a file, not a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise InputError(f"{option} {p}: {base} is not writable")
    if not overwrite:
        taken = [w for w in writes if _occupied(os.path.join(p, w))]
        if taken:
            more = f" (and {len(taken) - 1} more)" if len(taken) > 1 else ""
            raise InputError(f"{option} {p}: {taken[0]} exists{more}; choose another folder or --overwrite")
    return p


def _occupied(path: str) -> bool:
    if os.path.isdir(path):
        return bool(os.listdir(path))
    return os.path.lexists(path)


@contextlib.contextmanager
def fresh_folder(path: str | os.PathLike, *, discard: bool = True) -> Iterator[str]:
    """Create folder ``path`` (and missing parents) for the block; if the block fails, remove what
    it created: with ``discard`` whatever the block wrote into it, else only the folders left empty."""
    p = os.fspath(path)
    created = []
    q = os.path.abspath(p)
    while not os.path.exists(q):
        created.append(q)
        q = os.path.dirname(q)
    os.makedirs(p, exist_ok=True)
    try:
        yield p
    except BaseException:
        if created and discard:
            shutil.rmtree(created[-1], ignore_errors=True)
        else:
            for d in created:  # deepest first
                try:
                    os.rmdir(d)
                except OSError:
                    break
        raise
