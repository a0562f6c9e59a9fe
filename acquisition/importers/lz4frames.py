"""LZ4 frames decoded many at once, compiled with numba: the lz4 chunks of a ROS 1 bag.

ROS 1 writes each chunk of a bag as one LZ4 frame (roslz4; rosbags the same with lz4.frame). A bag
written a chunk per message is a frame of a few hundred bytes per message, and one call of
``lz4.frame.decompress`` per frame (~1 us, mostly the call's own overhead) cost more than the
rest of the import. :func:`decode_frames` decodes a batch of frames in one compiled call.

Every field is read as the LZ4 frame format says (docs/reference/lz4-frame.md): magic number,
FLG and BD bytes (version 01, reserved bits 0, block maximum size), the optional content size,
the header checksum; then each block (compressed or stored, its size within the maximum and
within the frame, its optional checksum), the end mark, and the optional content checksum
(xxHash32 of the decoded bytes). Every read and every write is bounds-checked; a frame that
breaks any rule gets a status code (:data:`PROBLEMS` says what it means), never a wrong result.
A dictionary (FLG bit 0) and skippable frames are not used by ROS and are refused.

Importing this module imports numba (~0.2 s of CPU) and loads the kernels from numba's cache
(``cache=True``; compiled on the first use on a machine): the bag reader imports it only when it
meets lz4 chunks (:mod:`.ros1chunks`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: LZ4 frame format (docs/reference/lz4-frame.md): the frame's magic number (little endian)
MAGIC = 0x184D2204
#: FLG bits: version (bits 7-6, must be 01), block independence, block checksum, content size,
#: content checksum, reserved (must be 0), dictionary id
FLG_VERSION, FLG_INDEP, FLG_BLOCK_SUM, FLG_SIZE = 0xC0, 0x20, 0x10, 0x08
FLG_CONTENT_SUM, FLG_RESERVED, FLG_DICT = 0x04, 0x02, 0x01
#: a block size word's high bit: the block is stored as is (not compressed)
STORED = 0x80000000
#: the largest distance a match may reach back (64 KB - 1; a linked block reaches into earlier ones)
MAX_DISTANCE = 65535

#: status codes of :func:`decode_frames` -> what is wrong with the frame
PROBLEMS = {
    1: "LZ4 frame cut short (a field or block runs past the chunk's data)",
    2: "not an LZ4 frame (magic number)",
    3: "LZ4 frame of an unknown version",
    4: "LZ4 frame descriptor with reserved bits set",
    5: "LZ4 frame with a dictionary (not used by ROS, not supported)",
    6: "LZ4 frame header checksum does not match",
    7: "LZ4 block larger than the frame's block maximum size",
    8: "LZ4 block checksum does not match",
    9: "LZ4 block damaged (a match or literal run outside the data)",
    10: "LZ4 frame holds more bytes than its chunk header says",
    11: "LZ4 frame's content size field differs from its content",
    12: "LZ4 content checksum does not match",
    13: "bytes after the LZ4 frame's end mark",
}

_P1, _P2, _P3, _P4, _P5 = 2654435761, 2246822519, 3266489917, 668265263, 374761393
_M32 = 0xFFFFFFFF


@nb.njit(cache=True)
def _rotl(x, r):
    return ((x << np.uint64(r)) | (x >> np.uint64(32 - r))) & np.uint64(_M32)


@nb.njit(cache=True)
def _u32(b, i):
    return (
        np.uint64(b[i])
        | (np.uint64(b[i + 1]) << np.uint64(8))
        | (np.uint64(b[i + 2]) << np.uint64(16))
        | (np.uint64(b[i + 3]) << np.uint64(24))
    )


@nb.njit(cache=True)
def _xxh32(b, start, end):
    """xxHash32 (seed 0) of ``b[start:end]``, as uint64."""
    m = np.uint64(_M32)
    p1, p2, p3, p4, p5 = np.uint64(_P1), np.uint64(_P2), np.uint64(_P3), np.uint64(_P4), np.uint64(_P5)
    n = end - start
    i = start
    if n >= 16:
        v1 = (p1 + p2) & m
        v2 = p2
        v3 = np.uint64(0)
        v4 = (np.uint64(1 << 32) - p1) & m
        while i + 16 <= end:
            v1 = (_rotl((v1 + _u32(b, i) * p2) & m, 13) * p1) & m
            v2 = (_rotl((v2 + _u32(b, i + 4) * p2) & m, 13) * p1) & m
            v3 = (_rotl((v3 + _u32(b, i + 8) * p2) & m, 13) * p1) & m
            v4 = (_rotl((v4 + _u32(b, i + 12) * p2) & m, 13) * p1) & m
            i += 16
        h = (_rotl(v1, 1) + _rotl(v2, 7) + _rotl(v3, 12) + _rotl(v4, 18)) & m
    else:
        h = p5
    h = (h + np.uint64(n)) & m
    while i + 4 <= end:
        h = (_rotl((h + _u32(b, i) * p3) & m, 17) * p4) & m
        i += 4
    while i < end:
        h = (_rotl((h + np.uint64(b[i]) * p5) & m, 11) * p1) & m
        i += 1
    h ^= h >> np.uint64(15)
    h = (h * p2) & m
    h ^= h >> np.uint64(13)
    h = (h * p3) & m
    h ^= h >> np.uint64(16)
    return h


@nb.njit(cache=True)
def _length(src, s, e, n):
    """A literal or match length from its token nibble ``n``: 15 continues in bytes from ``src[s]`` that
    add up while they are 255 (LZ4 block format). Returns (length, position after it), length -1 where
    the block ends first."""
    if n == 15:
        while True:
            if s >= e:
                return np.int64(-1), s
            x = src[s]
            s += 1
            n += x
            if x != 255:
                break
    return n, s


@nb.njit(cache=True)
def _block(src, s, e, out, o, lo, hi):
    """Decodes the compressed LZ4 block ``src[s:e]`` into ``out`` from ``o``; matches may reach back to
    ``lo``, output must stay below ``hi``. Returns the end of the output, or -9 (damaged block) /
    -10 (more output than room)."""
    while True:
        if s >= e:
            return -9
        token = src[s]
        s += 1
        n, s = _length(src, s, e, np.int64(token >> 4))
        if n < 0 or n > e - s:
            return -9
        if n > hi - o:
            return -10
        out[o : o + n] = src[s : s + n]
        s += n
        o += n
        if s == e:  # the last sequence: literals only
            return o
        if s + 2 > e:
            return -9
        dist = np.int64(src[s]) | (np.int64(src[s + 1]) << 8)
        s += 2
        if dist == 0 or dist > o - lo:
            return -9
        n, s = _length(src, s, e, np.int64(token & 15))
        if n < 0:
            return -9
        n += 4
        if n > hi - o:
            return -10
        # a match closer than its length repeats what it has just written: copied in pieces no longer than
        # the distance (none overlaps its source), each piece doubling the run the next can copy
        f = o - dist
        if dist >= n:
            out[o : o + n] = out[f : f + n]
            o += n
            continue
        end = o + n
        while o < end:
            c = min(o - f, end - o)
            out[o : o + c] = out[f : f + c]
            o += c


@nb.njit(cache=True)
def _frame(src, s, e, out, o, hi):
    """One LZ4 frame ``src[s:e]`` decoded into ``out[o:hi]``: ``(status, end of output)``."""
    base = o
    if e - s < 7:
        return 1, o
    if _u32(src, s) != np.uint64(MAGIC):
        return 2, o
    flg = src[s + 4]
    bd = src[s + 5]
    if flg & FLG_VERSION != 0x40:
        return 3, o
    if flg & FLG_RESERVED or bd & 0x8F:
        return 4, o
    if flg & FLG_DICT:
        return 5, o
    bsize = (bd >> 4) & 7
    if bsize < 4:
        return 4, o
    bmax = np.int64(1) << (8 + 2 * bsize)  # 4: 64 KB, 5: 256 KB, 6: 1 MB, 7: 4 MB
    p = s + 6
    csize = np.int64(-1)
    if flg & FLG_SIZE:
        if p + 8 > e:
            return 1, o
        csize = np.int64(_u32(src, p)) | (np.int64(_u32(src, p + 4)) << 32)
        p += 8
    if p >= e:
        return 1, o
    if np.uint64(src[p]) != (_xxh32(src, s + 4, p) >> np.uint64(8)) & np.uint64(0xFF):
        return 6, o
    p += 1
    indep = flg & FLG_INDEP
    bsum = flg & FLG_BLOCK_SUM
    while True:
        if p + 4 > e:
            return 1, o
        w = _u32(src, p)
        p += 4
        if w == 0:  # end mark
            break
        n = np.int64(w & np.uint64(0x7FFFFFFF))
        if n > bmax:
            return 7, o
        if n > e - p:
            return 1, o
        if bsum:
            if p + n + 4 > e:
                return 1, o
            if _xxh32(src, p, p + n) != _u32(src, p + n):
                return 8, o
        if w & np.uint64(STORED):
            if n > hi - o:
                return 10, o
            out[o : o + n] = src[p : p + n]
            o += n
        else:
            lo = o if indep else max(base, o - MAX_DISTANCE)
            r = _block(src, p, p + n, out, o, lo, min(hi, o + bmax))
            if r < 0:
                return (10 if r == -10 and o + bmax > hi else 9), o
            o = r
        p += n + (4 if bsum else 0)
    if csize >= 0 and csize != o - base:
        return 11, o
    if flg & FLG_CONTENT_SUM:
        if p + 4 > e:
            return 1, o
        if _xxh32(out, base, o) != _u32(src, p):
            return 12, o
        p += 4
    if p != e:
        return 13, o
    return 0, o


@nb.njit(cache=True)
def _frames(src, starts, ends, out, out_starts, out_ends, status, got):
    for k in range(len(starts)):
        st, o = _frame(src, starts[k], ends[k], out, out_starts[k], out_ends[k])
        status[k] = st
        got[k] = o - out_starts[k]


def decode_frames(
    src: np.ndarray, starts: np.ndarray, ends: np.ndarray, sizes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The LZ4 frames ``src[starts[k]:ends[k]]`` (``src`` uint8), each expected to hold ``sizes[k]`` bytes,
    decoded one after the other into one buffer: ``(out uint8 (sum of sizes), status int32, got int64)``.
    ``status[k]`` is 0 for a good frame, else a key of :data:`PROBLEMS`; ``got[k]`` is the bytes it
    decoded (= ``sizes[k]`` when good). A frame holding more than its size stops there (status 10), so
    ``out`` never grows past the sizes given (the caller bounds those)."""
    starts = np.ascontiguousarray(starts, np.int64)
    ends = np.ascontiguousarray(ends, np.int64)
    sizes = np.ascontiguousarray(sizes, np.int64)
    bounds = np.zeros(len(sizes) + 1, np.int64)
    np.cumsum(sizes, out=bounds[1:])
    out = np.empty(int(bounds[-1]), np.uint8)
    status = np.zeros(len(starts), np.int32)
    got = np.zeros(len(starts), np.int64)
    if len(starts) and ((starts < 0).any() or (ends > len(src)).any() or (ends < starts).any() or (sizes < 0).any()):
        raise ValueError("frame bounds outside the source")
    _frames(np.ascontiguousarray(src, np.uint8), starts, ends, out, bounds[:-1], bounds[1:], status, got)
    return out, status, got


def xxh32(data: bytes) -> int:
    """xxHash32 (seed 0) of ``data`` (the LZ4 frame's checksums)."""
    b = np.frombuffer(data, np.uint8)
    return int(_xxh32(b, 0, len(b)))
