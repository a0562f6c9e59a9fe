"""ROS 1 bag format 2.0 (http://wiki.ros.org/Bags/Format/2.0): records, header fields, chunk contents.

Records: ``<header_len u32><header><data_len u32><data>``; the header is a list
of ``<field_len u32>name=value`` fields, ``op`` tells the record type. A chunk's
data (decompressed: none / bz2 / lz4) is a sequence of records again: message
data and connections. :func:`split_chunk` parses one with numpy (runs of records
of one size found at once); :class:`.rosbag1.Ros1Bag` walks a file of them.
"""

from __future__ import annotations

import bz2
import struct
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from imustation.acquisition.importers.bytegather import gather_u32, rows_match

OP_MSGDATA, OP_BAGHEADER, OP_IDXDATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
MAGIC = b"#ROSBAG V2.0\n"

u32 = struct.Struct("<I").unpack_from


class BagFormatError(ValueError):
    """Not a readable ROS 1 (v2.0) bag."""


class BagCutError(BagFormatError):
    """A record runs past the end of the file (the bag was cut short)."""


@dataclass(frozen=True)
class Connection:
    id: int
    topic: str
    msgtype: str  # as in the bag: "sensor_msgs/Imu"
    md5sum: str


@dataclass
class ChunkMessages:
    """The messages of one chunk, in file order: ``buf[start[i]:start[i] + length[i]]`` is message i."""

    buf: bytes
    conn: np.ndarray  # int64 connection ids
    time: np.ndarray  # int64 record (receive) time, ns
    start: np.ndarray  # int64 offset of the serialised message in buf
    length: np.ndarray  # int64


def normalize_topic(name: str) -> str:
    """As rosbags does: no doubled or trailing slashes."""
    return f"{'/' * (name[:1] == '/')}{'/'.join(x for x in name.split('/') if x)}"


def parse_fields(buf, pos: int, end: int) -> dict[str, bytes]:
    out = {}
    while pos < end:
        if end - pos < 4:
            raise BagFormatError("header field cut short")
        (n,) = u32(buf, pos)
        pos += 4
        if n > end - pos:
            raise BagFormatError("header field longer than its header")
        name, sep, value = bytes(buf[pos : pos + n]).partition(b"=")
        if not sep:
            raise BagFormatError("header field without '='")
        out[name.decode("latin-1")] = value
        pos += n
    return out


def layout(buf, pos: int, n: int) -> dict[str, tuple[int, int]]:
    """``name -> (value offset from the header start, value length)`` of the fields of a header."""
    out, p, end = {}, pos, pos + n
    while p < end:
        (k,) = u32(buf, p)
        p += 4
        name, _, value = bytes(buf[p : p + k]).partition(b"=")
        out[name.decode("latin-1")] = (p + len(name) + 1 - pos, len(value))
        p += k
    return out


def int_field(fields: dict[str, bytes], name: str) -> int:
    try:
        return int.from_bytes(fields[name], "little")
    except KeyError:
        raise BagFormatError(f"record without {name!r} field") from None


def op_code(fields: dict[str, bytes]) -> int:
    op = fields.get("op")
    if op is None or len(op) != 1:
        raise BagFormatError("record without op code")
    return op[0]


def connection(fields: dict[str, bytes], data: bytes) -> Connection:
    d = parse_fields(data, 0, len(data))
    topic = fields.get("topic") or d.get("topic") or b""
    return Connection(
        int_field(fields, "conn"),
        normalize_topic(topic.decode()),
        d.get("type", b"").decode(),
        d.get("md5sum", b"").decode(),
    )


def codec(kind: str):
    """The decompressor (bytes -> bytes) of a ROS 1 chunk compression (``none``, ``bz2``, ``lz4``); lz4 is
    imported only for a bag that has lz4 chunks."""
    if kind == "none":
        return _same
    if kind == "bz2":
        return bz2.decompress
    if kind == "lz4":
        import lz4.frame

        return lz4.frame.decompress
    raise BagFormatError(f"chunk compression {kind!r} is not supported")


def decompress_prefix(kind: str, data: bytes) -> bytes:
    """What the first bytes of a chunk cut short decompress to (b"" where nothing can be told).

    bz2 and lz4 frames decompress block by block: the blocks complete before the cut come out.
    """
    try:
        if kind == "none":
            return data
        if kind == "bz2":
            return bz2.BZ2Decompressor().decompress(data)
        if kind == "lz4":
            import lz4.frame

            return lz4.frame.LZ4FrameDecompressor().decompress(data)
    except (OSError, ValueError, RuntimeError, EOFError):
        pass
    return b""


def _same(data: bytes) -> bytes:
    return data  # an uncompressed chunk is split where it lies: no copy


def decompress(kind: str, data: bytes, size: int) -> bytes:
    decode = codec(kind)
    try:
        out = decode(data)
    except (OSError, ValueError, RuntimeError, EOFError) as exc:
        raise BagFormatError(f"{kind} chunk does not decompress ({exc})") from None
    if len(out) != size:
        raise BagFormatError(f"chunk holds {len(out)} bytes, its header says {size}")
    return out


def split_chunk(
    raw: bytes,
    conns: dict[int, Connection],
    partial: bool = False,
    starts: np.ndarray | None = None,
    ends: np.ndarray | None = None,
) -> ChunkMessages:
    """The records of a decompressed chunk: message data (vectorised header parse) and connection records.

    ``partial``: ``raw`` is the start of a chunk cut short; its complete records only. ``starts``: ``raw``
    is several chunks joined, each starting at these offsets (:func:`chunk_record_starts`); ``ends``: they
    lie apart in ``raw`` (uncompressed chunks in the file's bytes), each ending there.
    """
    b = np.frombuffer(raw, np.uint8)
    rec = record_starts(raw, b, partial) if starts is None else chunk_record_starts(raw, b, starts, ends)
    hl_a = gather_u32(b, rec)
    hs_a = rec + 4
    dl_a = gather_u32(b, hs_a + hl_a)
    ds_a = hs_a + hl_a + 4
    cid = np.full(len(hs_a), -1, np.int64)
    tim = np.zeros(len(hs_a), np.int64)
    is_msg = np.zeros(len(hs_a), bool)
    done = np.zeros(len(hs_a), bool)
    for n in np.unique(hl_a).tolist():
        idx = np.flatnonzero(hl_a == n)
        hdr = sliding_window_view(b, n)[hs_a[idx]]  # (k, n), gathered by row
        # the first message header of this length is the template; a connection record of the same length
        # (topic name and message header alike long) is passed over, left to the loop below
        is_op2 = _op_is(hdr, raw, int(hs_a[idx[0]]), n, OP_MSGDATA)
        if not is_op2.any():
            continue
        first = int(idx[np.argmax(is_op2)])
        f = parse_fields(raw, int(hs_a[first]), int(hs_a[first]) + n)
        if op_code(f) != OP_MSGDATA or len(f.get("conn", b"")) != 4 or len(f.get("time", b"")) != 8:
            continue
        # field layout of this header length: everything but the conn and time values must match
        lay = layout(raw, int(hs_a[first]), n)
        fixed = np.ones(n, bool)
        fixed[lay["conn"][0] : lay["conn"][0] + 4] = False
        fixed[lay["time"][0] : lay["time"][0] + 8] = False
        row = hdr[int(np.argmax(is_op2))]
        same = (hdr[:, fixed] == row[fixed]).all(axis=1)
        ok = idx[same]
        h = hdr[same]
        c0, t0 = lay["conn"][0], lay["time"][0]
        cid[ok] = h[:, c0 : c0 + 4].copy().view("<u4")[:, 0]
        sec = h[:, t0 : t0 + 4].copy().view("<u4")[:, 0].astype(np.int64)
        nsec = h[:, t0 + 4 : t0 + 8].copy().view("<u4")[:, 0].astype(np.int64)
        tim[ok] = sec * 1_000_000_000 + nsec
        is_msg[ok] = True
        done[ok] = True
    for i in np.flatnonzero(~done).tolist():  # connection records and unusual headers
        h0 = int(hs_a[i])
        hdr = parse_fields(raw, h0, h0 + int(hl_a[i]))
        op = op_code(hdr)
        if op == OP_MSGDATA:
            cid[i], tim[i], is_msg[i] = int_field(hdr, "conn"), stamp(hdr), True
        elif op == OP_CONNECTION:
            c = connection(hdr, raw[int(ds_a[i]) : int(ds_a[i] + dl_a[i])])
            conns[c.id] = c
    return ChunkMessages(raw, cid[is_msg], tim[is_msg], ds_a[is_msg], dl_a[is_msg])


def _op_is(hdr: np.ndarray, raw: bytes, first: int, n: int, op: int) -> np.ndarray:
    """Which rows of ``hdr`` (headers of length ``n``) hold ``op`` where the first's op value is (a cheap
    test: a row that passes it is compared field by field after)."""
    try:
        at = layout(raw, first, n)["op"][0]
    except KeyError:
        return np.zeros(len(hdr), bool)
    return hdr[:, at] == op


def op_of(header: bytes) -> int:
    """The op code of a record header, found without decoding its other fields (the fields of a chunk info
    record differ in every record: its position and times)."""
    pos, end = 0, len(header)
    while pos + 4 <= end:
        (n,) = u32(header, pos)
        if n == 4 and header[pos + 4 : pos + 7] == b"op=":
            return header[pos + 7]
        pos += 4 + n
    raise BagFormatError("record without op code")


def stamp(hdr: dict[str, bytes]) -> int:
    t = hdr.get("time")
    if t is None or len(t) != 8:
        raise BagFormatError("message record without time")
    sec, nsec = struct.unpack("<II", t)
    return sec * 1_000_000_000 + nsec


#: a chunk's records are looked at in cycles of up to this many (topics interleaved: one record of each)
MAX_CYCLE = 4


def record_starts(raw: bytes, b: np.ndarray, partial: bool = False) -> np.ndarray:
    """Offsets of the records of a chunk (``partial``: of its complete records, the chunk cut short).

    Records are walked one by one, but runs of records that repeat the last one to MAX_CYCLE walked (a
    topic's messages of constant length, or the messages of topics interleaved, one of each in turn: the
    common cases) are found with numpy, a window of cycles at a constant stride at once.
    """
    out: list = []
    pos, size = 0, len(raw)
    plain = 0  # records to walk one by one before trying a run again
    hist: list[tuple[int, int, int]] = []  # (offset, header length, data length) of the last records walked
    try:
        while pos < size:
            if partial and pos + 8 > size:
                break
            (hn,) = u32(raw, pos)
            if partial and pos + 8 + hn > size:
                break
            (dn,) = u32(raw, pos + 4 + hn)
            stride = 8 + hn + dn
            if pos + stride > size:
                if partial:
                    break
                raise BagFormatError("truncated record in chunk")
            if not plain:
                end = _cycles(b, [*hist[len(hist) - MAX_CYCLE + 1 :], (pos, hn, dn)], size, out)
                if end:
                    pos, hist = end, []
                    continue
                plain = 16
            out.append(np.array([pos], np.int64))
            hist = [*hist[1 - MAX_CYCLE :], (pos, hn, dn)]
            pos += stride
            plain = max(plain - 1, 0)
    except struct.error:
        raise BagFormatError("truncated record in chunk") from None
    return np.concatenate(out) if out else np.empty(0, np.int64)


def _cycles(b: np.ndarray, recent: list[tuple[int, int, int]], size: int, out: list) -> int:
    """Cycles of the last c of the ``recent`` records (c = 1 .. MAX_CYCLE, the last one not handed out yet)
    repeated at a constant stride from the first of them; when at least MIN_RUN, their offsets are added
    to ``out`` and the offset after them returned, else 0."""
    for c in range(1, len(recent) + 1):
        cyc = recent[len(recent) - c :]
        s0 = cyc[0][0]
        stride = sum(8 + h + d for _, h, d in cyc)
        m = min((size - s0) // stride, 4096)
        if m < MIN_RUN:
            continue
        base = s0 + stride * np.arange(m, dtype=np.int64)
        good = np.ones(m, bool)
        for off, h, d in cyc:
            at = base + (off - s0)
            good &= (gather_u32(b, at) == h) & (gather_u32(b, at + 4 + h) == d)
        k = m if good.all() else int(np.argmin(good))
        if k < MIN_RUN:
            continue
        offs = np.array([off - s0 for off, _, _ in cyc], np.int64)
        out.append(np.array([cyc[-1][0]], np.int64))  # the last record walked, not handed out yet
        out.append((base[1:k, None] + offs).reshape(-1))
        return s0 + k * stride
    return 0


#: records followed from every chunk's start at once (then each chunk that holds more is walked alone)
FRONTIER_STEPS = 4


def chunk_record_starts(raw: bytes, b: np.ndarray, starts: np.ndarray, ends: np.ndarray | None = None) -> np.ndarray:
    """Offsets of the records of several chunks joined in ``raw``, chunk k starting at ``starts[k]`` (and
    ending at ``ends[k]``: by default where the next starts).

    A chunk per message (or per message of each topic, interleaved) holds one or two records: the
    next record of every chunk is found at once from the one before, a few steps; a chunk that holds
    more is walked by :func:`record_starts`."""
    size = len(raw)
    front = np.asarray(starts, np.int64)
    ends = np.append(front[1:], size) if ends is None else np.asarray(ends, np.int64)
    keep = front < ends  # an empty chunk holds no record
    front, ends = front[keep], ends[keep]
    out = []
    for _ in range(FRONTIER_STEPS):
        if not len(front):
            break
        if (front + 8 > ends).any():
            raise BagFormatError("truncated record in chunk")
        hn = gather_u32(b, front)
        if (front + 8 + hn > ends).any():
            raise BagFormatError("truncated record in chunk")
        nxt = front + 8 + hn + gather_u32(b, front + 4 + hn)
        if (nxt > ends).any():
            raise BagFormatError("truncated record in chunk")
        out.append(front)
        more = nxt < ends
        front, ends = nxt[more], ends[more]
    for a, e in zip(front.tolist(), ends.tolist(), strict=True):
        out.append(a + record_starts(raw[a:e], b[a:e]))
    return np.sort(np.concatenate(out)) if out else np.empty(0, np.int64)


@dataclass(frozen=True)
class Shape:
    """A top-level record as the walk met it: op, header bytes and parsed fields ({} if not parsed),
    data length and whether its data is handed out (a run of such records repeats it)."""

    op: int
    key: bytes
    fields: dict[str, bytes]
    data_len: int
    kept: bool

    @property
    def total(self) -> int:
        return 8 + len(self.key) + self.data_len


@dataclass
class Run:
    """``at`` (int64 offsets) of ``k`` records of one shape, found together; ``data[i]`` is record i's data."""

    shape: Shape
    at: np.ndarray
    data: np.ndarray  # (k, data_len) uint8, a view of the walk's buffer
    head: np.ndarray  # (k, header length) uint8, the records' headers, a view of it too


#: a run is looked for only when this many cycles of records fit in the buffer
MIN_RUN = 4


def periodic_run(arr: np.ndarray, off: int, stop: int, cycle: list[Shape]) -> tuple[int, Run | None]:
    """Cycles of records from ``arr[off:]`` (before ``stop``) that repeat ``cycle`` exactly (the records
    the walk just met: a chunk and its index-data record per message, or one chunk-info record); 0 if
    fewer than MIN_RUN. Returns the count and the run of the cycle's one kept record (None if none).

    A bag written a chunk per message is two small records per message; walking them one by one in
    Python costs more than the messages. Repeated cycles sit at a constant stride, so a window of
    them is one (k, stride) array: each record's lengths and header bytes are compared at once (all of
    them for a kept record, whose parsed fields are reused; only the field layout and op for the
    skipped index records and chunk infos, whose values change from record to record)."""
    stride = sum(s.total for s in cycle)
    m = (stop - off) // stride
    if m < MIN_RUN:
        return 0, None
    block = arr[off : off + m * stride].reshape(m, stride)
    k, lo, size = 0, 0, 4 * MIN_RUN  # windows growing 4x: a walk that is not periodic pays little
    while lo < m:
        hi = min(m, lo + size)
        good = _repeats(arr, range(off + stride * lo, off + stride * hi, stride), cycle)
        if not good.all():
            k = lo + int(np.argmin(good))
            break
        lo, size, k = hi, size * 4, hi
    if k < MIN_RUN:
        return 0, None
    run, at = None, 0
    for s in cycle:
        if s.kept:
            hn = len(s.key)
            data = block[:k, at + 8 + hn : at + 8 + hn + s.data_len]
            run = Run(s, at + stride * np.arange(k, dtype=np.int64), data, block[:k, at + 4 : at + 4 + hn])
        at += s.total
    return k, run


def _repeats(arr: np.ndarray, starts: range, cycle: list[Shape]) -> np.ndarray:
    """Which cycles of records starting at ``starts`` in ``arr`` repeat ``cycle`` (lengths and header bytes;
    compared as a few 8-byte words per record)."""
    good = np.ones(len(starts), bool)
    at = 0
    for s in cycle:
        hn = len(s.key)
        # the record's header length, header and data length, as one row of bytes
        row = struct.pack("<I", hn) + s.key + struct.pack("<I", s.data_len)
        free = None
        if not s.fields:  # values vary: compare the field layout and the op
            free = np.zeros(len(row), bool)
            for name, (vo, vl) in layout(s.key, 0, hn).items():
                if name != "op":
                    free[4 + vo : 4 + vo + vl] = True
        good &= rows_match(arr, range(starts.start + at, starts.stop + at, starts.step), row, free)
        at += s.total
    return good
