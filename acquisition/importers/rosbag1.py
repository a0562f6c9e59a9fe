"""A streaming ROS 1 bag (format 2.0) reader: one chunk in memory at a time, no per-message index.

rosbags' ``rosbag1.Reader`` builds an index entry (a Python object) for every
message when it opens a bag (~150-180 bytes per message: 2.6 GB for 12 h at
400 Hz). This reader instead takes a closed bag's chunks from its index's chunk
table, a block of the file at a time (:mod:`.ros1chunks`), or walks the file
record by record (http://wiki.ros.org/Bags/Format/2.0) where the table is missing
or does not match; it decompresses one chunk at a time (none / bz2 / lz4) and hands
out its messages in file order, so memory is O(chunk) plus 16 bytes a chunk for
the table, whatever the bag's length. ``sensor_msgs/Imu`` messages are decoded
with numpy, a chunk at a time (:func:`.messages.decode_imu_ros1`).

The records and a chunk's contents are parsed by :mod:`.ros1records`.
Messages inside a chunk are in the order they were recorded (receive time);
they are returned in that order, never sorted.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import numpy as np

from imustation.acquisition.importers.chunked import ChunkedFile, file_span
from imustation.acquisition.importers.ros1chunks import ChunkTable, read_chunks
from imustation.acquisition.importers.ros1records import (
    MAGIC,
    OP_BAGHEADER,
    OP_CHUNK,
    OP_CHUNK_INFO,
    OP_CONNECTION,
    OP_MSGDATA,
    BagCutError,
    BagFormatError,
    ChunkMessages,
    Connection,
    Run,
    Shape,
    connection,
    decompress,
    decompress_prefix,
    int_field,
    layout,
    op_code,
    op_of,
    parse_fields,
    periodic_run,
    split_chunk,
    stamp,
    u32,
)

__all__ = ["BagCutError", "BagFormatError", "ChunkMessages", "Connection", "Ros1Bag"]

#: decompressed chunk bytes split and handed out together (small chunks are batched up to it)
BATCH_BYTES = 1 << 20
#: file bytes read at a time while walking the records of the data section
WALK_BYTES = 1 << 22
#: records found in runs by the walk (:func:`.ros1records.periodic_run`); others are handed out one by one
RUN_OPS = (OP_CHUNK, OP_CHUNK_INFO)


class Ros1Bag(ChunkedFile):
    """Sequential reader of a ROS 1 bag: :meth:`index` (topics, counts) and :meth:`chunks` (messages)."""

    def __init__(self, path: str):
        self._parsed: dict[bytes, dict[str, bytes]] = {}
        self._walk_at = 0
        #: the messages of the last :meth:`chunks` that came from a chunk cut short
        self.salvaged = 0
        #: every chunk's position from the index (:meth:`index`; None: not read, or not usable)
        self.table: ChunkTable | None = None
        super().__init__(path)

    def _start(self) -> None:
        if self.fh.read(len(MAGIC)) != MAGIC:
            raise BagFormatError("not a ROS 1 bag (v2.0 magic missing)")
        hdr = self._header()
        if op_code(hdr) != OP_BAGHEADER:
            raise BagFormatError("first record is not the bag header")
        self.index_pos = int_field(hdr, "index_pos")
        self.conn_count = int_field(hdr, "conn_count")
        self.chunk_count = int_field(hdr, "chunk_count")
        if hdr.get("encryptor"):
            raise BagFormatError(f"encrypted bag ({hdr['encryptor'].decode()}) not supported")
        self._skip(self._u32())
        self.first_record = self.fh.tell()
        #: the bag is indexed but cut short: its index (at ``index_pos``) is missing or
        #: incomplete, so the chunks are read one after the other up to the cut
        self.cut = self.index_pos > self.size

    # -- low level
    def _u32(self) -> int:
        b = self.fh.read(4)
        if len(b) != 4:
            raise BagCutError("truncated record")
        return u32(b, 0)[0]

    def _read(self, n: int) -> bytes:
        b = self.fh.read(n)
        if len(b) != n:
            raise BagCutError(f"truncated record ({len(b)} of {n} bytes)")
        return b

    def _skip(self, n: int) -> None:
        self.fh.seek(n, os.SEEK_CUR)

    def _header(self) -> dict[str, bytes]:
        n = self._u32()
        if n > 1 << 20:
            raise BagFormatError(f"record header of {n} bytes")
        b = self._read(n)
        # the headers of a bag's chunks and index-data records repeat (same compression and size, same
        # connection and count): parsed once (read-only dicts; callers only look fields up)
        hit = self._parsed.get(b)
        if hit is None:
            hit = parse_fields(b, 0, n)
            if len(self._parsed) >= 1024:
                self._parsed.clear()
            self._parsed[b] = hit
        return hit

    # -- index
    def index(self) -> tuple[dict[int, Connection], dict[int, int]]:
        """Connections and message counts per connection id.

        From the index section at the end of the bag (connection and chunk-info
        records: O(chunks)); an unindexed bag (a recording that was not closed) and
        a bag cut short (:attr:`cut`) are scanned instead.
        """
        if self.index_pos == 0 or self.cut:
            return self.scan()
        try:
            return self._read_index()
        except BagCutError:
            self.cut = True  # cut inside the index: every chunk is there
            return self.scan()

    def _read_index(self) -> tuple[dict[int, Connection], dict[int, int]]:
        self.fh.seek(self.index_pos)
        conns: dict[int, Connection] = {}
        totals: dict[int, int] = {}  # messages per connection id, summed run by run (bounded temporaries)
        table: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # chunk positions, connections, messages
        for item in self._walk(self.size, (OP_CONNECTION, OP_CHUNK_INFO)):
            if isinstance(item, Run):  # chunk infos of one connection and length
                if item.shape.data_len % 8:
                    raise BagFormatError("chunk info record of a length that is not pairs of u32")
                k, m = len(item.at), item.shape.data_len // 8
                pairs = item.data.reshape(k, -1).copy().view("<u4").reshape(k, m, 2)
                _add_counts(totals, pairs.reshape(-1, 2))
                vo = layout(item.shape.key, 0, len(item.shape.key)).get("chunk_pos", (0, 0))
                # each chunk's position, from the headers (the index is not read a second time for them)
                pos = item.head[:, vo[0] : vo[0] + 8].copy().view("<u8")[:, 0].astype(np.int64) if vo[1] == 8 else None
                per = pairs[:, :, 1].sum(axis=1)
                table.append((pos, np.full(k, m, np.int32), per.astype(np.int32)))
                continue
            _at, op, hdr, data = item
            if op == OP_CONNECTION:
                c = connection(hdr, data)
                conns[c.id] = c
            elif op == OP_CHUNK_INFO:
                # (connection id u32, message count u32) pairs; the header's count is their number
                if len(data) % 8:
                    raise BagFormatError("chunk info record of a length that is not pairs of u32")
                _add_counts(totals, np.frombuffer(data, "<u4").reshape(-1, 2))
                cp = hdr.get("chunk_pos")
                pos = np.array([int.from_bytes(cp, "little")], np.int64) if cp is not None and len(cp) == 8 else None
                per = np.frombuffer(data, "<u4").reshape(-1, 2)[:, 1].sum()
                table.append((pos, np.array([len(data) // 8], np.int32), np.array([per], np.int32)))
        self.table = None
        if table and all(p is not None for p, _, _ in table):
            self.table = ChunkTable(*(np.concatenate(x) for x in zip(*table, strict=True)))
        return conns, dict(sorted(totals.items()))

    # -- messages
    def chunks(self, conns: dict[int, Connection] | None = None) -> Iterator[ChunkMessages]:
        """The messages of each chunk in file order; ``conns`` is filled with the connection records met.

        An unindexed bag (a recording that was not closed) or a bag cut short may end in a
        record that was being written: reading stops there, :attr:`unread_from` tells where (else
        it is None), and the complete messages of a chunk cut there are handed out too.
        """
        conns = {} if conns is None else conns
        self.unread_from = None
        self.chunks_read = self.messages_read = self.salvaged = 0
        scan = self.index_pos == 0 or self.cut
        at: int | None = self.first_record
        if not scan:
            at = yield from self._indexed_chunks(conns)
            if at is None:
                return
        self.fh.seek(at)
        end = self.index_pos if 0 < self.index_pos <= self.size else self.size
        # small chunks (a recorder that flushes every message) are split and decoded together: per chunk
        # the cost is then a record read, not a numpy pass (one message per chunk: 0.6k -> tens of k msg/s)
        batch: list[tuple[int | np.ndarray, bytes, int | None]] = []  # (offset(s), raw, size of each or None)
        held = 0
        failed: list[tuple[int, BagFormatError]] = []
        walk = self._walk(end)
        while True:
            try:
                item = next(walk, None)
                if item is None:
                    break
                if isinstance(item, Run):
                    held += self._take_run(item, batch)
                    if held < BATCH_BYTES:
                        continue
                else:
                    at, op, hdr, data = item
                    if op == OP_CHUNK:
                        raw = decompress(hdr.get("compression", b"none").decode(), data, int_field(hdr, "size"))
            except BagFormatError as err:
                problem = err
                at = self._walk_at
                yield from self._flush(batch, conns, failed)
                if failed:
                    at, problem = failed[0]
                if not scan:
                    if not isinstance(problem, BagCutError):
                        raise problem from None
                    self.cut = True  # the index says more than the file holds
                yield from self._stop(at, conns)
                return
            if isinstance(item, Run):
                pass  # the batch is full: handed out below
            elif op == OP_CHUNK:
                batch.append((at, raw, None))
                held += len(raw)
                if held < BATCH_BYTES:
                    continue
            elif op not in (OP_CONNECTION, OP_MSGDATA):
                continue  # index data after each chunk: nothing to hand out, the batch goes on
            yield from self._flush(batch, conns, failed)
            held = 0
            if failed:
                at, exc = failed[0]
                if not scan:
                    raise exc
                yield from self._stop(at, conns)
                return
            if isinstance(item, Run):
                continue
            if op == OP_CONNECTION:
                c = connection(hdr, data)
                conns[c.id] = c
            elif op == OP_MSGDATA:  # a message outside any chunk (not written by rosbag, but allowed)
                one = np.ones(1, np.int64)
                yield ChunkMessages(
                    data, one * int_field(hdr, "conn"), one * stamp(hdr), np.zeros(1, np.int64), one * len(data)
                )
        yield from self._flush(batch, conns, failed)
        if failed:
            at, exc = failed[0]
            if not scan:
                raise exc
            yield from self._stop(at, conns)

    def _indexed_chunks(self, conns: dict[int, Connection]) -> Iterator[ChunkMessages]:
        """The chunks of a closed bag from its index's chunk table (:mod:`.ros1chunks`), as far as the table
        tiles the bag; returns the offset to walk on from (None: every chunk read)."""
        if self.table is None:
            try:
                self._read_index()
            except BagFormatError:
                return self.first_record  # an index cut short or damaged: the walk finds out
        if self.table is None:
            return self.first_record
        counts: list = [0, 0, None]
        for msgs in read_chunks(self.fh, self.table, self.first_record, self.index_pos, conns, counts):
            self.chunks_read, self.messages_read = counts[0], counts[1]
            yield msgs
        self.chunks_read, self.messages_read = counts[0], counts[1]
        return counts[2]

    def _walk(
        self, end: int, keep: tuple[int, ...] = (OP_CHUNK, OP_CONNECTION, OP_MSGDATA)
    ) -> Iterator[tuple[int, int, dict[str, bytes], bytes] | Run]:
        """``(offset, op, header fields, data)`` of the top-level records from the file position up to
        ``end``, read WALK_BYTES at a time (data ``b""`` and header fields ``{}`` for records whose op is
        not in ``keep``, skipped): a chunk per message costs two small records, which read one by one
        from the file cost more than the messages. The fields of a header seen before are not parsed
        again. Records that repeat the last one or two at a constant stride (a chunk per message) come as
        a :class:`.ros1records.Run` instead. :attr:`_walk_at` is the offset of the record being read
        (where a BagFormatError stops)."""
        pos = self.fh.tell()
        base, buf = pos, b""
        arr = np.empty(0, np.uint8)
        last = before = None  # (op, header bytes, fields, data length) of the last two records walked one by one
        calm = 0  # records to walk one by one before looking for a run again
        wait = 16  # calm after a failed look, doubled while they keep failing (a walk that is not periodic)

        def fill(need: int) -> tuple[object, int]:
            got, at = file_span(self.fh, pos, pos + max(WALK_BYTES, need))
            if at + len(got) < pos + need:
                raise BagCutError(f"truncated record ({at + len(got) - pos} of {need} bytes)")
            return got, at

        while pos < end:
            self._walk_at = pos
            off = pos - base
            if before is not None and not calm:
                if off + WALK_BYTES // 4 > len(buf) and end - pos > WALK_BYTES // 4:
                    buf, base = file_span(self.fh, pos, pos + WALK_BYTES)  # room for a long run
                    off = pos - base
                    arr = np.frombuffer(buf, np.uint8)
                found = 0
                recent = [Shape(*r, r[0] in keep) for r in (before, last)]
                for cycle in (recent[1:], recent):
                    if sum(s.kept for s in cycle) > 1 or any(s.kept and s.op not in RUN_OPS for s in cycle):
                        continue
                    found, run = periodic_run(arr, off, min(end - base, len(buf)), cycle)
                    if found:
                        wait = 16
                        if run is not None:
                            run.at += pos
                            yield run
                        pos += found * sum(s.total for s in cycle)
                        break
                if found:
                    continue
                calm, wait = wait, min(wait * 2, 4096)
            calm = max(calm - 1, 0)
            if off + 4 > len(buf):
                buf, base = fill(4)
                off = pos - base
                arr = np.frombuffer(buf, np.uint8)
            (hn,) = u32(buf, off)
            if hn > 1 << 20:
                raise BagFormatError(f"record header of {hn} bytes")
            if off + 8 + hn > len(buf):
                buf, base = fill(8 + hn)
                off = pos - base
                arr = np.frombuffer(buf, np.uint8)
            key = buf[off + 4 : off + 4 + hn]
            hdr = self._parsed.get(key)
            if hdr is not None:
                op = op_code(hdr)
            else:
                op = op_of(key)
                if op in keep and op != OP_CHUNK_INFO:
                    hdr = parse_fields(key, 0, hn)
                    if len(self._parsed) >= 1024:
                        self._parsed.clear()
                    self._parsed[key] = hdr
                elif op in keep:  # a chunk info walked alone: its chunk's position (values differ: not kept)
                    hdr = parse_fields(key, 0, hn)
                else:
                    hdr = {}
            (dn,) = u32(buf, off + 4 + hn)
            total = 8 + hn + dn
            data = b""
            if op in keep:
                if off + total > len(buf):
                    buf, base = fill(total)
                    off = pos - base
                    arr = np.frombuffer(buf, np.uint8)
                data = buf[off + 8 + hn : off + total]
            elif pos + total > self.size:
                raise BagCutError("truncated record")
            # a chunk info's values differ from record to record: its run is found by its layout
            before, last = last, (op, key, hdr if op != OP_CHUNK_INFO else {}, dn)
            yield pos, op, hdr, data
            pos += total
        self.fh.seek(pos)

    def _flush(
        self, batch: list[tuple[int, bytes]], conns: dict[int, Connection], failed: list
    ) -> Iterator[ChunkMessages]:
        """The messages of the held chunks, split together; a chunk that does not split stops there
        (``failed`` gets its offset and error, the chunks before it are handed out)."""
        if not batch:
            return
        count = sum(1 if size is None else len(at) for at, _, size in batch)
        try:
            msgs = split_chunk(b"".join(raw for _, raw, _ in batch), conns) if count > 1 else None
        except BagFormatError:
            msgs = None
        if msgs is not None:
            self.chunks_read += count
            self.messages_read += len(msgs.conn)
            batch.clear()
            yield msgs
            return
        for at, raw in _each_chunk(batch):
            try:
                one = split_chunk(raw, conns)
            except BagFormatError as exc:
                failed.append((at, exc))
                break
            self.chunks_read += 1
            self.messages_read += len(one.conn)
            yield one
        batch.clear()

    def _take_run(self, run: Run, batch: list) -> int:
        """Adds a run of chunks to ``batch`` (uncompressed: as one group); the bytes added. A chunk that
        does not decompress raises with :attr:`_walk_at` at it, the chunks before it already added."""
        fields = run.shape.fields
        kind, size = fields.get("compression", b"none").decode(), int_field(fields, "size")
        if kind == "none" and size == run.shape.data_len:
            raw = run.data.tobytes()
            batch.append((run.at, raw, size))
            return len(raw)
        held = 0
        for at, row in zip(run.at.tolist(), run.data, strict=True):
            self._walk_at = at
            raw = decompress(kind, row.tobytes(), size)
            batch.append((at, raw, None))
            held += len(raw)
        return held

    def _stop(self, at: int, conns: dict[int, Connection]) -> Iterator[ChunkMessages]:
        """Reading ends at the record at ``at``: the complete messages of a chunk cut there."""
        self.unread_from = at
        part = self._salvage(at, conns)
        if part is not None:
            self.salvaged = len(part.conn)
            self.messages_read += self.salvaged
            yield part

    def _salvage(self, at: int, conns: dict[int, Connection]) -> ChunkMessages | None:
        """The complete messages at the start of the chunk record at ``at``, cut short (None if none)."""
        try:
            self.fh.seek(at)
            hdr = self._header()
            if op_code(hdr) != OP_CHUNK:
                return None
            self._u32()
            raw = decompress_prefix(hdr.get("compression", b"none").decode(), self.fh.read())
            msgs = split_chunk(raw, conns, partial=True)
        except BagFormatError:
            return None
        return msgs if len(msgs.conn) else None

    def _record(self) -> tuple[int, dict[str, bytes], bytes]:
        """The next top-level record: op, header fields and data (b"" for index records, skipped)."""
        hdr = self._header()
        op = op_code(hdr)
        n = self._u32()
        if op in (OP_CHUNK, OP_CONNECTION, OP_MSGDATA):
            return op, hdr, self._read(n)
        if self.fh.tell() + n > self.size:
            raise BagCutError("truncated record")
        self._skip(n)
        return op, hdr, b""

    def messages(self, topics=None) -> Iterator[tuple[str, str, int, bytes]]:
        """``(topic, msgtype, record time ns, raw bytes)`` of every message (of ``topics``) in file order."""
        conns: dict[int, Connection] = {}
        for ch in self.chunks(conns):
            for cid, t, s, n in zip(ch.conn.tolist(), ch.time.tolist(), ch.start.tolist(), ch.length.tolist(),
                                    strict=True):  # fmt: skip
                c = conns.get(cid)
                if c is None:
                    raise BagFormatError(f"message of unknown connection {cid}")
                if topics is None or c.topic in topics:
                    yield c.topic, c.msgtype, t, bytes(ch.buf[s : s + n])


def _add_counts(totals: dict[int, int], pairs: np.ndarray) -> None:
    """Adds the (connection id, message count) ``pairs`` (uint32, (n, 2)) of chunk infos to ``totals``."""
    if not len(pairs):
        return
    ids, n = pairs[:, 0], pairs[:, 1].astype(np.int64)
    if (ids == ids[0]).all():  # a run of chunk infos of one connection
        totals[int(ids[0])] = totals.get(int(ids[0]), 0) + int(n.sum())
        return
    u, where = np.unique(ids, return_inverse=True)
    for i, k in zip(u.tolist(), np.bincount(where, n, len(u)).tolist(), strict=True):
        totals[i] = totals.get(i, 0) + int(k)


def _each_chunk(batch: list[tuple[int | np.ndarray, bytes, int | None]]) -> Iterator[tuple[int, bytes]]:
    """``(offset, raw)`` of every chunk of a batch, the groups of a run split into their chunks."""
    for at, raw, size in batch:
        if size is None:
            yield at, raw
        else:
            for i, a in enumerate(at.tolist()):
                yield a, raw[i * size : (i + 1) * size]
