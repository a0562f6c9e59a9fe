"""The chunks of a closed ROS 1 bag found from its index, and read together with numpy.

A closed bag's index holds a chunk-info record per chunk: where the chunk starts, and how many
messages of each connection it holds (http://wiki.ros.org/Bags/Format/2.0). From those positions
the headers and data lengths of every chunk in a block of the file (4 MB read at once) are gathered
together, instead of walking the data section record by record (a bag written a chunk per message
is two records per message; lz4 and bz2 chunks, and chunks of interleaved topics, differ in length
and make no run of constant stride for the walk to find). A block is used only where the table
tiles it exactly: the first chunk right after the bag header, each chunk followed by its index-data
records (one per connection, 12 bytes per message) and then by the next chunk or the index. Where
it does not (a message or connection record outside a chunk, an index that does not match the
data), reading stops at the first chunk of that block, and :class:`.rosbag1.Ros1Bag` walks the bag
from there, record by record as before. The lz4 chunks of a bag of LZ4_KERNEL_CHUNKS chunks or more
are decoded a batch at a time by :mod:`.lz4frames` (compiled), fewer by ``lz4.frame`` one call each.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass, replace

import numpy as np

from imustation.acquisition.importers.bytegather import gather_u32, rows_match
from imustation.acquisition.importers.chunked import file_span
from imustation.acquisition.importers.ros1records import (
    OP_CHUNK,
    OP_IDXDATA,
    BagFormatError,
    ChunkMessages,
    Connection,
    codec,
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
#: file bytes read at once (chunks and their index data); a larger chunk is read alone
BLOCK_BYTES = 1 << 22
#: threads decompressing the batches ahead of the one being split (1: none, in the reading thread)
WORKERS = min(len(os.sched_getaffinity(0)), 4) if hasattr(os, "sched_getaffinity") else min(os.cpu_count() or 1, 4)
#: the codecs decompressed in those threads: bz2 spends 8-15 us in libbz2 per one-message chunk with the
#: GIL released (threads: 1.3x one-message chunks, up to 1.8x large ones, on a free second core); an lz4
#: call is ~1 us, mostly Python's, and threads made it slower (0.160 -> 0.181-0.232 s per 100k messages)
THREADED = frozenset({"bz2"})
#: batches decompressed ahead of the one handed out
AHEAD = 2
#: chunks in a bag from which its lz4 chunks are decoded by the compiled decoder (:mod:`.lz4frames`), not
#: one ``lz4.frame.decompress`` call each: importing numba and loading the kernels costs ~0.75 s of CPU
#: once per process (numba's first use imports scipy.linalg), the kernel saves ~0.5 us per one-message
#: chunk (docs/import.md, "Large bags")
LZ4_KERNEL_CHUNKS = 1_500_000
#: None: by LZ4_KERNEL_CHUNKS; True / False: always / never (benchmarks and tests)
LZ4_KERNEL: bool | None = None
#: chunks whose layout is gathered at once, at the most (bounds the temporaries: ~50 bytes a chunk)
WINDOW = 1 << 16


@dataclass(frozen=True)
class ChunkTable:
    """Every chunk of a bag from its index: start offset (int64), connections (int32) and messages (int32)."""

    pos: np.ndarray
    conns: np.ndarray
    messages: np.ndarray


@dataclass(frozen=True)
class Layout:
    """Where the data of the chunks of a block is (start, length; from the block's start), how it is
    stored (``kind[which[k]]``) and its decompressed size."""

    start: np.ndarray
    length: np.ndarray
    kind: list[str]
    which: np.ndarray
    size: np.ndarray
    #: the chunks' records (from the block's start), and the block's offset in the file
    pos: np.ndarray
    base: int = 0


def layout(b: np.ndarray, pos: np.ndarray, nxt: np.ndarray, conns: np.ndarray, messages: np.ndarray) -> Layout | None:
    """The chunks starting at ``pos`` in the block ``b`` (offsets in it), each followed by its index-data
    records up to ``nxt`` (the next chunk or the index); None when they do not tile the block so."""
    if (nxt <= pos).any() or nxt[-1] > len(b):
        return None
    hn = gather_u32(b, pos)
    if (hn > 1 << 20).any() or (pos + 8 + hn > nxt).any():
        return None
    dn = gather_u32(b, pos + 4 + hn)
    start = pos + 8 + hn
    end = start + dn
    if (end + 4 > nxt).any():
        return None
    # the index-data records after each chunk: one per connection, 12 bytes per message, all with the
    # header of the first (the same fields)
    h = _idx_header(b, int(end[0]), int(nxt[0]))
    if h is None or ((nxt - end) != conns.astype(np.int64) * (8 + h) + 12 * messages.astype(np.int64)).any():
        return None
    which = np.zeros(len(pos), np.int8)
    kinds: list[str] = []
    size = np.zeros(len(pos), np.int64)
    for k in [int(hn[0])] if (hn == hn[0]).all() else np.unique(hn).tolist():
        g = np.flatnonzero(hn == k)
        # chunk headers differ in their size value only (same compression, same fields): all compared with
        # the first's at once, a few 8-byte words per header, and a header unlike it looked at on its own
        left = np.arange(len(g))
        while len(left):
            at = int(pos[g[left[0]]]) + 4
            key = b[at : at + k].tobytes()
            try:
                f = parse_fields(key, 0, k)
                if op_code(f) != OP_CHUNK or len(kinds) >= 64:
                    return None
                kind = f.get("compression", b"none").decode()
                vo, vl = header_layout(key, 0, k)["size"]
            except (BagFormatError, UnicodeDecodeError, KeyError):
                return None
            if vl != 4:
                return None  # a u32 in every bag written (the walk reads any other)
            free = np.zeros(k, bool)
            free[vo : vo + 4] = True
            heads = pos[g[left]] + 4
            same = rows_match(b, heads, key, free)
            mine = left[same]
            size[g[mine]] = gather_u32(b, heads[same] + vo)
            which[g[mine]] = len(kinds)
            kinds.append(kind)
            left = left[~same]
    return Layout(start, dn, kinds, which, size, pos)


def _idx_header(b: np.ndarray, at: int, stop: int) -> int | None:
    """The header length of the index-data record at ``at`` (None if it is not one)."""
    if at + 4 > stop:
        return None
    h = int(gather_u32(b, [at])[0])
    if h > 1 << 10 or at + 4 + h > stop:
        return None
    try:
        return h if op_code(parse_fields(b[at + 4 : at + 4 + h].tobytes(), 0, h)) == OP_IDXDATA else None
    except BagFormatError:
        return None


def read_chunks(fh, table: ChunkTable, first_record: int, index_pos: int, conns: dict[int, Connection],
                counts: list[int]) -> Iterator[ChunkMessages]:  # fmt: skip
    """The messages of the chunks of ``table`` in file order, a batch of chunks at a time (``counts``: chunks
    and messages read so far, updated). Stops at the first block the table does not tile: ``counts[2]`` is
    then the file offset to walk on from (None when every chunk was read)."""
    pos = table.pos
    n = len(pos)
    counts[2] = first_record
    if n == 0 or pos[0] != first_record:
        return
    nxt = np.append(pos[1:], index_pos)
    with ThreadPoolExecutor(WORKERS) if WORKERS > 1 else nullcontext() as pool:
        yield from _blocks(fh, table, nxt, conns, counts, pool)


def _blocks(fh, table: ChunkTable, nxt: np.ndarray, conns, counts, pool) -> Iterator[ChunkMessages]:
    pos = table.pos
    n = len(pos)
    kernel = LZ4_KERNEL if LZ4_KERNEL is not None else n >= LZ4_KERNEL_CHUNKS
    i = 0
    while i < n:
        base = int(pos[i])
        j = max(int(np.searchsorted(nxt, base + BLOCK_BYTES, side="right")), i + 1)
        j = min(j, n, i + WINDOW)
        data, base = _block(fh, base, int(nxt[j - 1]))
        if data is None:
            return  # shorter than its index says: walked (and found cut)
        buf = np.frombuffer(data, np.uint8)
        lay = layout(buf, pos[i:j] - base, nxt[i:j] - base, table.conns[i:j], table.messages[i:j])
        if lay is None:
            return
        lay = replace(lay, base=base)
        yield from _batches(data, lay, conns, counts, pool, kernel)
        del data, buf, lay  # not held while the next block is read
        i = j
        counts[2] = int(nxt[i - 1])
    counts[2] = None


def _block(fh, start: int, stop: int) -> tuple[object, int]:
    """The file's bytes from ``start`` (or a page before it) to ``stop`` (:func:`.chunked.file_span`) and
    where they start; None when the file ends before ``stop``."""
    data, at = file_span(fh, start, stop)
    return (data if at + len(data) == stop else None), at


def _batches(
    data, lay: Layout, conns, counts, pool: ThreadPoolExecutor | None, kernel: bool
) -> Iterator[ChunkMessages]:
    """The chunks of a block in batches of about BATCH_BYTES decompressed (the messages of a batch are
    split and decoded together: bounded temporaries); lz4 chunks with :mod:`.lz4frames` if ``kernel``."""
    n = len(lay.start)
    cum = np.cumsum(lay.size)
    spans = []
    i = 0
    while i < n:
        j = int(np.searchsorted(cum, (cum[i - 1] if i else 0) + BATCH_BYTES, side="left")) + 1
        spans.append((i, min(max(j, i + 1), n)))
        i = spans[-1][1]
    if all(k == "none" for k in lay.kind):
        # uncompressed chunks are split where they lie in the block read (no copy)
        if (lay.length != lay.size).any():
            k = int(np.argmax(lay.length != lay.size))
            at = lay.base + int(lay.pos[k])
            raise BagFormatError(f"chunk at byte {at} holds {lay.length[k]} bytes, its header says {lay.size[k]}")
        for i, j in spans:
            start = lay.start[i:j]
            msgs = split_chunk(data, conns, starts=start, ends=start + lay.length[i:j])
            counts[0] += j - i
            counts[1] += len(msgs.conn)
            yield msgs
        return
    if kernel and all(k == "lz4" for k in lay.kind):
        src = np.frombuffer(data, np.uint8)
        for i, j in spans:
            raw = _lz4_frames(src, lay, i, j)
            bounds = np.concatenate([[0], np.cumsum(lay.size[i:j])[:-1]])
            msgs = split_chunk(raw, conns, starts=bounds)
            counts[0] += j - i
            counts[1] += len(msgs.conn)
            yield msgs
        return
    view = memoryview(data)
    if not THREADED.intersection(lay.kind):
        pool = None
    for (i, j), parts in _in_order(pool, spans, lambda i, j: _decompress_all(view, lay, i, j)):
        raw = b"".join(parts)
        bounds = np.concatenate([[0], np.cumsum(lay.size[i:j])[:-1]])
        msgs = split_chunk(raw, conns, starts=bounds)
        counts[0] += j - i
        counts[1] += len(msgs.conn)
        yield msgs


def _in_order(pool: ThreadPoolExecutor | None, spans: list[tuple[int, int]], work) -> Iterator:
    """``(span, work(*span))`` for each span in order; with a ``pool``, the next AHEAD spans' work runs in
    its threads meanwhile (the codecs release the GIL while they decompress), so at most AHEAD + 1
    batches of BATCH_BYTES are held at once."""
    if pool is None:
        for sp in spans:
            yield sp, work(*sp)
        return
    pending: deque = deque()
    todo = iter(spans)
    try:
        for sp in todo:
            pending.append((sp, pool.submit(work, *sp)))
            if len(pending) > AHEAD:
                break
        while pending:
            sp, fut = pending.popleft()
            yield sp, fut.result()
            nxt = next(todo, None)  # once the batch handed out is done with
            if nxt is not None:
                pending.append((nxt, pool.submit(work, *nxt)))
    finally:
        for _, fut in pending:
            fut.cancel()


def _lz4_frames(src: np.ndarray, lay: Layout, i: int, j: int) -> np.ndarray:
    """The lz4 chunks ``i:j`` of a block decoded together (:func:`.lz4frames.decode_frames`); a chunk that
    fails is named by its offset in the file, as :func:`_decompress_all` names it."""
    from imustation.acquisition.importers.lz4frames import PROBLEMS, decode_frames

    start, length, size = lay.start[i:j], lay.length[i:j], lay.size[i:j]
    # no frame of L bytes holds more than 255 L (a length byte of 255 per 255 bytes of match): a size beyond
    # that is not believed, and not allocated
    over = np.flatnonzero(size > 255 * length + 64)
    if len(over):
        k = int(over[0])
        raise BagFormatError(f"chunk at byte {lay.base + int(lay.pos[i + k])}: its header says {size[k]} bytes, "
                             f"more than an lz4 frame of {length[k]} bytes holds")  # fmt: skip
    out, status, got = decode_frames(src, start, start + length, size)
    bad = np.flatnonzero((status != 0) | (got != size))
    if len(bad):
        k = int(bad[0])
        at, st = lay.base + int(lay.pos[i + k]), int(status[k])
        if st == 0:
            raise BagFormatError(f"chunk at byte {at} holds {got[k]} bytes, its header says {size[k]}")
        if st == 10:
            raise BagFormatError(f"chunk at byte {at} holds more than the {size[k]} bytes its header says")
        raise BagFormatError(f"chunk at byte {at}: lz4 chunk does not decompress ({PROBLEMS[st]})")
    return out


def _decompress_all(mm: memoryview, lay: Layout, i: int, j: int) -> list[bytes]:
    """Chunks ``i:j`` decompressed, one codec call each (no per-chunk checks in Python: their sizes are
    compared at once after); a chunk that fails is named by its offset in the file."""
    start, length = lay.start[i:j].tolist(), lay.length[i:j].tolist()
    which = lay.which[i:j]
    codecs = {w: codec(lay.kind[w]) for w in np.unique(which).tolist()}
    try:
        if len(codecs) == 1:  # one codec call per chunk, iterated in C (lz4: ~1 us a chunk)
            ends = (lay.start[i:j] + lay.length[i:j]).tolist()
            parts = list(map(next(iter(codecs.values())), map(mm.__getitem__, map(slice, start, ends))))
        else:
            parts = [codecs[w](mm[a : a + k]) for w, a, k in zip(which.tolist(), start, length, strict=True)]
    except (OSError, ValueError, RuntimeError, EOFError) as exc:
        # the chunk that fails, named as the walk names it
        for k, (w, a, m, s) in enumerate(zip(which.tolist(), start, length, lay.size[i:j].tolist(), strict=True)):
            try:
                decompress(lay.kind[w], mm[a : a + m], s)
            except BagFormatError as err:
                raise BagFormatError(f"chunk at byte {lay.base + int(lay.pos[i + k])}: {err}") from None
        raise BagFormatError(f"chunks at bytes {lay.base + int(lay.pos[i])}-{lay.base + int(lay.pos[j - 1])} "
                             f"do not decompress ({exc})") from None  # fmt: skip
    got = np.fromiter(map(len, parts), np.int64, len(parts))
    bad = np.flatnonzero(got != lay.size[i:j])
    if len(bad):
        k = int(bad[0])
        raise BagFormatError(
            f"chunk at byte {lay.base + int(lay.pos[i + k])} holds {got[k]} bytes, its header says {lay.size[i + k]}"
        )
    return parts
