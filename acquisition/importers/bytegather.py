"""Little-endian integers and byte rows at arbitrary offsets of a uint8 array, gathered with numpy.

A bag written a chunk per message holds a record header every few hundred bytes: their lengths and
fields are read at every offset at once. An unaligned strided view (one element per byte offset)
makes each such read one fancy index of the offsets, ~3x faster than gathering the bytes of each
value and joining them, and a row of header bytes is compared as a few 8-byte words, not byte by byte.
"""

from __future__ import annotations

import numpy as np


def words(b: np.ndarray, width: int) -> np.ndarray:
    """A read-only view of ``b`` (uint8) whose element ``i`` is the little-endian unsigned integer of
    ``width`` (4 or 8) bytes starting at byte ``i`` (``len(b) - width + 1`` elements, none past the end)."""
    if not b.flags.c_contiguous:
        b = np.ascontiguousarray(b)
    n = max(len(b) - width + 1, 0)
    if n == 0:
        return np.empty(0, f"<u{width}")
    v = np.ndarray((n,), f"<u{width}", buffer=b, strides=(1,))
    v.flags.writeable = False
    return v


def gather_u32(b: np.ndarray, at) -> np.ndarray:
    """Little-endian uint32 at byte offsets ``at`` of the uint8 array ``b``, as int64 (IndexError for an
    offset whose 4 bytes are not all in ``b``)."""
    return words(b, 4)[np.asarray(at, np.int64)].astype(np.int64)


def rows_match(b: np.ndarray, starts, template: bytes, free: np.ndarray | None = None) -> np.ndarray:
    """Which of the rows ``b[s : s + len(template)]`` (``s`` in ``starts``: an array of offsets, or a
    ``range`` for rows at a constant stride, read as a strided view, no gather) equal ``template`` at every
    byte not marked in ``free`` (bool, one per template byte). Every row must lie inside ``b``."""
    k = len(template)
    keep = np.ones(k, bool) if free is None else ~np.asarray(free, bool)
    if isinstance(starts, range):
        n = len(starts)
        if not b.flags.c_contiguous:
            b = np.ascontiguousarray(b)

        def column(at: int, width: int) -> np.ndarray:
            if n == 0:
                return np.empty(0, f"<u{width}")
            return np.ndarray((n,), f"<u{width}", buffer=b, offset=starts.start + at, strides=(starts.step,))
    else:
        starts = np.asarray(starts, np.int64)
        n = len(starts)

        def column(at: int, width: int) -> np.ndarray:
            return words(b, width)[starts + at]

    good = np.ones(n, bool)
    if k < 8:  # too short for a word: bytes
        t = np.frombuffer(template, np.uint8)
        for j in np.flatnonzero(keep).tolist():
            good &= column(j, 1) == t[j]
        return good
    # words at 0, 8, 16, ... and one ending at the last byte (overlapping the one before it)
    for at in sorted({*range(0, k - 7, 8), k - 8}):
        m = keep[at : at + 8]
        if not m.any():
            continue
        mask = sum(0xFF << (8 * i) for i in np.flatnonzero(m).tolist())
        want = int.from_bytes(template[at : at + 8], "little") & mask
        col = column(at, 8)
        good &= (col == want) if mask == (1 << 64) - 1 else ((col & np.uint64(mask)) == want)
    return good
