"""The chunks of a closed ROS 1 bag found from its index, and read together with numpy.

A closed bag's index holds a chunk-info record per chunk: where the chunk starts, and how many
messages of each connection it holds (http://wiki.ros.org/Bags/Format/2.0). From those positions
every chunk's header and data lengths are gathered at once over the mapped file, instead of walking
the data section record by record (a bag written a chunk per message is two records per message;
lz4 and bz2 chunks, and chunks of interleaved topics, differ in length and make no run of constant
stride for the walk to find). The table is used only when it tiles the data section exactly: the
first chunk right after the bag header, each chunk followed by its index-data records (one per
connection, 12 bytes per message) and then by the next chunk or the index. Anything else (a
message or connection record outside a chunk, an index that does not match the data) and the bag
is walked as before (:class:`.rosbag1.Ros1Bag`).
"""

from __future__ import annotations

import mmap
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from imustation.acquisition.importers.messages import gather_u32
from imustation.acquisition.importers.ros1records import (
    OP_CHUNK,
    OP_IDXDATA,
    BagFormatError,
    ChunkMessages,
    Connection,
    decompress,
    op_code,
    parse_fields,
    split_chunk,
)
from imustation.acquisition.importers.ros1records import (
    layout as header_layout,
)

#: decompressed chunk bytes split and handed out together
BATCH_BYTES = 1 << 20


@dataclass(frozen=True)
class ChunkTable:
    """Every chunk of a bag from its index: start offset, connections and messages (int64 arrays)."""

    pos: np.ndarray
    conns: np.ndarray
    messages: np.ndarray


def _u64(b: np.ndarray, at: np.ndarray) -> np.ndarray:
    return b[np.asarray(at, np.int64)[:, None] + np.arange(8)].view("<u8")[:, 0].astype(np.int64)


def chunk_positions(fh, at: np.ndarray, value_offset: int) -> np.ndarray:
    """The ``chunk_pos`` of the chunk-info records at offsets ``at`` of the open file ``fh`` whose value
    sits ``value_offset`` bytes into their header (the same field layout in each)."""
    with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        b = np.frombuffer(mm, np.uint8)
        out = _u64(b, np.asarray(at, np.int64) + 4 + value_offset)
        del b
    return out


@dataclass(frozen=True)
class Layout:
    """Where each chunk's data is (start, length) and how it is stored (compression, decompressed size)."""

    start: np.ndarray
    length: np.ndarray
    kind: list[str]  # per distinct header
    which: np.ndarray  # header index of each chunk
    size: np.ndarray


def layout(b: np.ndarray, table: ChunkTable, first_record: int, index_pos: int) -> Layout | None:
    """The chunks' data from the mapped bag ``b``; None when the table does not tile the data section."""
    pos = table.pos
    n = len(pos)
    if n == 0 or pos[0] != first_record or (np.diff(pos) <= 0).any() or pos[-1] + 8 >= index_pos:
        return None
    hn = gather_u32(b, pos)
    if (hn > 1 << 20).any() or (pos + 8 + hn > index_pos).any():
        return None
    dn = gather_u32(b, pos + 4 + hn)
    start = pos + 8 + hn
    end = start + dn
    nxt = np.append(pos[1:], index_pos)
    if (end > nxt).any():
        return None
    # the index-data records after each chunk: one per connection, 12 bytes per message; their header
    # length is read from the first (the same fields in each)
    h = int(gather_u32(b, end[:1])[0])
    if h > 1 << 10 or end[0] + 4 + h > index_pos:
        return None
    try:
        if op_code(parse_fields(b[end[0] + 4 : end[0] + 4 + h].tobytes(), 0, h)) != OP_IDXDATA:
            return None
    except BagFormatError:
        return None
    if ((nxt - end) != table.conns * (8 + h) + 12 * table.messages).any():
        return None
    which = np.zeros(n, np.int64)
    kinds: list[str] = []
    size = np.zeros(n, np.int64)
    for k in np.unique(hn).tolist():
        g = np.flatnonzero(hn == k)
        rows = b[pos[g, None] + 4 + np.arange(k)]
        # chunk headers differ in their size value only (same compression, same fields): the others are
        # compared with the first's at once, and a header unlike it is parsed on its own
        left = g
        while len(left):
            r0 = rows[np.searchsorted(g, left[0])]
            try:
                f = parse_fields(r0.tobytes(), 0, k)
                if op_code(f) != OP_CHUNK:
                    return None
                kind = f.get("compression", b"none").decode()
                vo, vl = header_layout(r0.tobytes(), 0, k)["size"]
            except (BagFormatError, UnicodeDecodeError, KeyError):
                return None
            sub = rows[np.searchsorted(g, left)]
            fixed = np.ones(k, bool)
            fixed[vo : vo + vl] = False
            same = (sub[:, fixed] == r0[fixed]).all(axis=1)
            mine = left[same]
            val = sub[same][:, vo : vo + vl]
            size[mine] = (val.astype(np.int64) << (8 * np.arange(vl))).sum(axis=1)
            which[mine] = len(kinds)
            kinds.append(kind)
            left = left[~same]
    return Layout(start, dn, kinds, which, size)


def read_chunks(fh, table: ChunkTable, first_record: int, index_pos: int, conns: dict[int, Connection],
                counts: list[int]) -> Iterator[ChunkMessages] | None:  # fmt: skip
    """The messages of every chunk in file order, a batch of chunks at a time (``counts``: chunks and messages
    read so far, updated); None when the table does not tile the bag (walk it instead)."""
    mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    b = np.frombuffer(mm, np.uint8)
    lay = layout(b, table, first_record, index_pos)
    if lay is None:
        del b
        mm.close()
        return None
    return _batches(mm, b, lay, conns, counts)


def _batches(mm, b, lay: Layout, conns, counts) -> Iterator[ChunkMessages]:
    try:
        n = len(lay.start)
        cum = np.cumsum(lay.size)
        i = 0
        while i < n:
            j = int(np.searchsorted(cum, (cum[i - 1] if i else 0) + BATCH_BYTES, side="left")) + 1
            j = min(max(j, i + 1), n)
            start, length = lay.start[i:j], lay.length[i:j]
            raw = b"".join(_decompress_all(mm, lay, i, j, start, length))
            bounds = np.concatenate([[0], np.cumsum(lay.size[i:j])[:-1]])
            msgs = split_chunk(raw, conns, starts=bounds)
            counts[0] += j - i
            counts[1] += len(msgs.conn)
            yield msgs
            i = j
    finally:
        del b
        mm.close()


def _decompress_all(mm, lay: Layout, i: int, j: int, start: np.ndarray, length: np.ndarray) -> list[bytes]:
    """Chunks ``i:j`` decompressed, one codec call each (no per-chunk checks in Python: their sizes are
    compared at once after)."""
    which = lay.which[i:j]
    codecs = {w: _codec(lay.kind[w]) for w in np.unique(which).tolist()}
    try:
        if len(codecs) == 1:
            dec = next(iter(codecs.values()))
            parts = [dec(mm[a : a + k]) for a, k in zip(start.tolist(), length.tolist(), strict=True)]
        else:
            parts = [codecs[w](mm[a : a + k]) for w, a, k in zip(which.tolist(), start.tolist(), length.tolist(),
                                                                   strict=True)]  # fmt: skip
    except (OSError, ValueError, RuntimeError, EOFError) as exc:
        # the chunk that fails, named as the walk names it
        for w, a, k, s in zip(which.tolist(), start.tolist(), length.tolist(), lay.size[i:j].tolist(), strict=True):
            decompress(lay.kind[w], mm[a : a + k], s)
        raise BagFormatError(f"chunk does not decompress ({exc})") from None
    got = np.fromiter(map(len, parts), np.int64, len(parts))
    bad = np.flatnonzero(got != lay.size[i:j])
    if len(bad):
        k = int(bad[0])
        raise BagFormatError(f"chunk holds {got[k]} bytes, its header says {lay.size[i + k]}")
    return parts


def _codec(kind: str):
    """The decompressor of a chunk compression (``none``, ``bz2``, ``lz4``)."""
    if kind == "none":
        return _same
    if kind == "bz2":
        import bz2

        return bz2.decompress
    if kind == "lz4":
        import lz4.frame

        return lz4.frame.decompress
    raise BagFormatError(f"chunk compression {kind!r} is not supported")


def _same(data: bytes) -> bytes:
    return data
