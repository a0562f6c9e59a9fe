"""Open an HDF5 file as a SWMR reader without waiting forever on damaged metadata.

Why this exists: a SWMR reader cannot tell a metadata block the writer is
rewriting from a damaged one, so HDF5 re-reads a block whose checksum fails,
sleeping 1 ns, 2 ns, 4 ns ... between tries (``H5C__load_entry``), up to the
file's *metadata read attempts* - 100 by default for SWMR readers
(``H5F_SWMR_METADATA_READ_ATTEMPTS``). 100 doublings are 2^100 ns: a truncated
or byte-flipped run file made ``inspect``, ``analyze`` and the monitor sleep
forever at 0 % CPU inside the library. :data:`SWMR_READ_ATTEMPTS` bounds the
total sleep per damaged block to about one second, ample for a block the
writer is rewriting (one ``pwrite`` of a few kB).

h5py exposes no setter for that property (``H5Pset_metadata_read_attempts``),
so it is set through ctypes on the HDF5 library h5py itself loaded, and the
file is opened with h5py's low-level ``h5f.open``.

The library h5py ships is not built thread-safe (``H5is_library_threadsafe``
says false): h5py serialises every call into it with one lock, ``phil``. A
ctypes call releases the GIL and takes no such lock, so it ran inside HDF5 at
the same time as another thread's h5py call: two analysis threads of an
in-process dask cluster opening run files crashed the process (segmentation
fault in CI; reproduced with four threads opening one file, 4 of 6 runs). The
ctypes call is therefore made holding ``phil``.
"""

from __future__ import annotations

import ctypes
import os
from functools import cache

import h5py
from h5py import h5f, h5p
from h5py._objects import phil  # h5py's lock around every HDF5 call (see the module docstring)

#: metadata read attempts of a SWMR reader: the retries sleep 2^k ns, k = 0..n-1,
#: so 30 attempts wait at most 2^30 ns (about 1.07 s) for one damaged block
SWMR_READ_ATTEMPTS = 30


@cache
def _set_read_attempts():
    """``H5Pset_metadata_read_attempts`` of the HDF5 library h5py uses.

    Looked up through h5py's own extension module: ``dlsym`` on its handle
    searches the libraries it links, so this is the very library h5py calls
    (never a second copy found elsewhere on the system).
    """
    func = ctypes.CDLL(h5p.__file__).H5Pset_metadata_read_attempts
    func.argtypes = [ctypes.c_int64, ctypes.c_uint]  # hid_t is int64 since HDF5 1.10
    func.restype = ctypes.c_int
    return func


def open_swmr_reader(path: str | os.PathLike, *, locking: bool | None = None) -> h5py.File:
    """Open ``path`` read-only as an HDF5 SWMR reader (``libver="latest"``).

    ``locking``: HDF5 file locking on/off; ``None`` keeps HDF5's default
    (``HDF5_USE_FILE_LOCKING``). Damaged metadata raises ``OSError`` or
    ``KeyError`` from h5py after at most about a second per damaged block
    instead of hanging (see the module docstring).
    """
    fapl = h5p.create(h5p.FILE_ACCESS)
    fapl.set_libver_bounds(h5f.LIBVER_LATEST, h5f.LIBVER_LATEST)
    if locking is not None:
        fapl.set_file_locking(bool(locking), False)  # as h5py's locking=True/False
    with phil:
        refused = _set_read_attempts()(fapl.id, SWMR_READ_ATTEMPTS) < 0
    if refused:
        raise RuntimeError("HDF5 refused H5Pset_metadata_read_attempts")
    fid = h5f.open(os.fsencode(path), h5f.ACC_RDONLY | h5f.ACC_SWMR_READ, fapl=fapl)
    return h5py.File(fid)
