"""Validation of a run file on read: every reader gets a sound file or one line saying why not.

:func:`check_run` runs once when :func:`imustation.runfile.open_run` opens a
file. It visits every object the readers use (root, ``/devices/*``,
``/thermometers/*``, ``/events`` and their attributes), so damaged metadata
fails here, as one :class:`~imustation.errors.RunFileError`, instead of as an
h5py traceback somewhere in a reader. Data chunks are not read (a 12 h file
holds hundreds of MB); a damaged chunk fails when it is read, through
:class:`CheckedDataset`, with the same kind of one-line error.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import Any

import h5py
import numpy as np

from imustation.errors import RunFileError
from imustation.runfile import FORMAT, FORMAT_VERSION

#: what h5py raises for damaged files: OSError (I/O, decompression, checksum),
#: KeyError (an object that cannot be opened), RuntimeError (library state),
#: ValueError/TypeError (a stored type or shape h5py cannot map to numpy)
H5_ERRORS = (OSError, KeyError, RuntimeError, ValueError, TypeError)


def _reason(exc: BaseException) -> str:
    text = str(exc).strip().strip("'\"").splitlines()
    return (text[0] if text else exc.__class__.__name__)[:200]


@contextlib.contextmanager
def damaged_file(path: str, what: str = "") -> Iterator[None]:
    """Turn an h5py error raised inside the block into one :class:`RunFileError` line."""
    try:
        yield
    except RunFileError:
        raise
    except H5_ERRORS as exc:
        where = f" ({what})" if what else ""
        raise RunFileError(f"{path}: damaged run file{where}: {_reason(exc)}") from None


class CheckedDataset:
    """An h5py dataset whose reads raise :class:`RunFileError` on a damaged chunk.

    Offers what the readers use: slicing, ``len``, ``shape``, ``dtype``,
    ``ndim``, ``attrs``, ``refresh()``.
    """

    __slots__ = ("_ds", "_path", "_what")

    def __init__(self, ds: h5py.Dataset, path: str, what: str):
        self._ds, self._path, self._what = ds, path, what

    def __getitem__(self, key: Any):
        with damaged_file(self._path, f"{self._what} rows {_rows(key)}"):
            return self._ds[key]

    def __len__(self) -> int:
        return self._ds.shape[0]

    @property
    def shape(self) -> tuple[int, ...]:
        return self._ds.shape

    @property
    def dtype(self):
        return self._ds.dtype

    @property
    def ndim(self) -> int:
        return self._ds.ndim

    @property
    def attrs(self):
        return self._ds.attrs

    def refresh(self) -> None:
        with damaged_file(self._path, self._what):
            self._ds.refresh()


def _rows(key: Any) -> str:
    k = key[0] if isinstance(key, tuple) and key else key
    if isinstance(k, slice):
        return f"{k.start or 0}:{'' if k.stop is None else k.stop}"
    return str(k) if isinstance(k, (int, np.integer)) else "..."


def _visit(path: str, obj: h5py.HLObject, name: str) -> None:
    """Read every attribute of ``obj`` (loads its object header and attribute messages)."""
    with damaged_file(path, name):
        for key in obj.attrs:
            obj.attrs[key]


def _members(path: str, group: h5py.Group, name: str) -> dict[str, h5py.HLObject]:
    """The members of ``group``, each opened, refusing links that lead out of the file."""
    out = {}
    with damaged_file(path, name):
        for key in group:
            link = group.get(key, getlink=True)
            if not isinstance(link, h5py.HardLink):
                kind = "external link" if isinstance(link, h5py.ExternalLink) else "soft link"
                raise RunFileError(f"{path}: {name}/{key} is a {kind}; a run file holds its data itself")
            out[key] = group[key]
    return out


def _plain(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    return value


def check_run(h5: h5py.File, path: str) -> dict[str, Any]:
    """Refuse a damaged run file with one line (see the module docstring); returns the root attributes."""
    with damaged_file(path, "root attributes"):
        attrs = {k: _plain(v) for k, v in h5.attrs.items()}
    fmt = attrs.get("format")
    if not isinstance(fmt, str) or fmt != FORMAT:
        raise RunFileError(f"{path}: not an imustation run file (format attribute is {fmt!r})")
    version = attrs.get("format_version")
    if type(version) is not int or version != FORMAT_VERSION:
        raise RunFileError(f"{path}: run-file format version {version!r} is not supported (this is v1)")
    if "ended_utc" in attrs:
        # a finished file was cut to its end of allocation when it was closed; a SWMR
        # reader does not compare the two (the file grows while written), so check here
        with damaged_file(path, "superblock"):
            eoa = h5.id.get_filesize()
        size = os.path.getsize(path)
        if size < eoa:
            raise RunFileError(f"{path}: truncated: {size} of its {eoa} bytes are left (the capture had finished it)")
    root = _members(path, h5, "")
    for gname in ("devices", "thermometers"):
        grp = root.get(gname)
        if not isinstance(grp, h5py.Group):
            continue
        _visit(path, grp, gname)
        for name, sub in _members(path, grp, gname).items():
            where = f"{gname}/{name}"
            _visit(path, sub, where)
            if isinstance(sub, h5py.Group):
                for dname, ds in _members(path, sub, where).items():
                    _visit(path, ds, f"{where}/{dname}")
    events = root.get("events")
    if events is not None:
        _visit(path, events, "events")
    return attrs
