"""MCAP files of ROS 1 messages (profile ``ros1``: what ``mcap convert`` makes of a ROS 1 bag), streamed.

rosbags reads MCAP of the ``ros2`` profile only. This reader walks an MCAP file record by record
(https://mcap.dev/spec): one chunk in memory at a time (none / lz4 / zstd), each chunk's CRC checked
when it has one, and hands out the messages of each chunk in file order, as :mod:`.rosbag1` does
for a bag, so :mod:`.ros1` decodes their ``sensor_msgs/Imu`` and ``/Temperature`` with numpy (a
ROS 1 message in MCAP is the serialised message of a bag).

Records: ``<opcode u8><length u64><content>``; strings and byte arrays carry a u32 length, maps a
u32 byte length. Topics and message counts come from the summary section (its Statistics record)
when the file has one, else from a scan. A file cut short is read up to the last complete record
(:attr:`Mcap1.unread_from` says where it stopped); a damaged record or chunk is a
:class:`McapFormatError`.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator

import numpy as np

from imustation.acquisition.importers.chunked import ChunkedFile
from imustation.acquisition.importers.ros1records import ChunkMessages, Connection, normalize_topic

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_STATISTICS, OP_DATA_END = 0x0B, 0x0F
#: the largest record this reader holds in memory (a chunk of a sane writer is a few MB)
MAX_RECORD = 1 << 31

_REC = struct.Struct("<BQ")


class McapFormatError(ValueError):
    """Not a readable MCAP file, or a damaged record in it."""


def _str(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end = pos + 4 + n
    if end > len(buf):
        raise McapFormatError("string runs past its record")
    try:
        return buf[pos + 4 : end].decode(), end
    except UnicodeDecodeError:
        raise McapFormatError("string that is not UTF-8") from None


def profile(path: str) -> str | None:
    """The profile an MCAP file's header names (``"ros1"``, ``"ros2"``, ...), None when it is not MCAP."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(8 + 9 + 4 + 256)
    except OSError:
        return None
    if not head.startswith(MAGIC) or len(head) < 21 or head[8] != OP_HEADER:
        return None
    try:
        return _str(head, 17)[0]
    except (McapFormatError, struct.error):
        return None


def _decompress(kind: str, data: bytes, size: int) -> bytes:
    try:
        if kind == "":
            out = data
        elif kind == "lz4":
            import lz4.frame

            out = lz4.frame.decompress(data)
        elif kind == "zstd":
            try:
                from compression import zstd  # Python 3.14
            except ImportError:
                from backports import zstd
            out = zstd.decompress(data)
        else:
            raise McapFormatError(f"chunk compression {kind!r} is not supported")
    except McapFormatError:
        raise
    except Exception as exc:  # noqa: BLE001 - each codec raises its own error type; all mean "damaged chunk"
        raise McapFormatError(f"{kind} chunk does not decompress ({exc.__class__.__name__}: {exc})") from None
    if len(out) != size:
        raise McapFormatError(f"chunk holds {len(out)} bytes, its header says {size}")
    return out


class Mcap1(ChunkedFile):
    """Sequential reader of an MCAP file of ROS 1 messages: :meth:`index` and :meth:`chunks`."""

    def _start(self) -> None:
        if self.fh.read(8) != MAGIC:
            raise McapFormatError("not an MCAP file (magic missing)")
        op, content = self._record()
        if op != OP_HEADER:
            raise McapFormatError("first record is not the MCAP header")
        self.profile = _str(content, 0)[0]
        self.first_record = self.fh.tell()
        self.schemas: dict[int, str] = {}  # schema id -> message type name

    def _record(self) -> tuple[int, bytes]:
        head = self.fh.read(9)
        if len(head) < 9:
            raise EOFError("record cut short")
        op, n = _REC.unpack(head)
        if n > MAX_RECORD or self.fh.tell() + n > self.size:
            if self.fh.tell() + n > self.size and n <= MAX_RECORD:
                raise EOFError("record cut short")
            raise McapFormatError(f"record of {n} bytes (a corrupted length)")
        return op, self.fh.read(n)

    def _schema(self, content: bytes) -> None:
        (sid,) = struct.unpack_from("<H", content, 0)
        name, _ = _str(content, 2)
        self.schemas[sid] = name

    def _channel(self, content: bytes, conns: dict[int, Connection]) -> None:
        cid, sid = struct.unpack_from("<HH", content, 0)
        topic, pos = _str(content, 4)
        encoding, _ = _str(content, pos)
        msgtype = self.schemas.get(sid, "") if encoding == "ros1" else f"({encoding}) {self.schemas.get(sid, '')}"
        conns[cid] = Connection(cid, normalize_topic(topic), msgtype, "")

    def index(self) -> tuple[dict[int, Connection], dict[int, int]]:
        """Connections and message counts per channel id: from the summary section when the file has one
        with a Statistics record, else from a scan of every chunk."""
        try:
            found = self._summary()
        except (McapFormatError, EOFError, struct.error):
            found = None
        if found is not None:
            return found
        return self.scan()

    def _summary(self) -> tuple[dict[int, Connection], dict[int, int]] | None:
        if self.size < 8 + 8 + 9 + 20:
            return None
        self.fh.seek(self.size - 8)
        if self.fh.read(8) != MAGIC:
            return None
        self.fh.seek(self.size - 8 - 9 - 20)
        op, content = self._record()
        if op != OP_FOOTER:
            return None
        summary_start, _, _ = struct.unpack("<QQI", content)
        if not 0 < summary_start < self.size:
            return None
        self.fh.seek(summary_start)
        conns: dict[int, Connection] = {}
        counts: dict[int, int] | None = None
        while self.fh.tell() < self.size - 8 - 9 - 20:
            op, content = self._record()
            if op == OP_SCHEMA:
                self._schema(content)
            elif op == OP_CHANNEL:
                self._channel(content, conns)
            elif op == OP_STATISTICS:
                (nbytes,) = struct.unpack_from("<I", content, 42)
                pairs = np.frombuffer(content, np.dtype([("id", "<u2"), ("n", "<u8")]), nbytes // 10, 46)
                counts = {int(i): int(n) for i, n in zip(pairs["id"], pairs["n"], strict=True)}
        return (conns, counts) if counts is not None else None

    def chunks(self, conns: dict[int, Connection] | None = None) -> Iterator[ChunkMessages]:
        """The messages of each chunk (and of messages outside chunks) in file order; ``conns`` is filled
        with the channels met (``msgtype``: the schema name, e.g. ``sensor_msgs/Imu``)."""
        conns = {} if conns is None else conns
        self.fh.seek(self.first_record)
        self.unread_from = None
        self.chunks_read = self.messages_read = 0
        while True:
            at = self.fh.tell()
            try:
                op, content = self._record()
            except EOFError:
                if at < self.size:
                    self.unread_from = at
                return
            if op in (OP_FOOTER, OP_DATA_END):
                return
            if op == OP_SCHEMA:
                self._schema(content)
            elif op == OP_CHANNEL:
                self._channel(content, conns)
            elif op == OP_MESSAGE:
                msgs = self._messages(content, conns, single=True)
                self.messages_read += len(msgs.conn)
                yield msgs
            elif op == OP_CHUNK:
                _, _, size, crc = struct.unpack_from("<QQQI", content, 0)
                kind, pos = _str(content, 28)
                (n,) = struct.unpack_from("<Q", content, pos)
                data = content[pos + 8 : pos + 8 + n]
                if len(data) != n:
                    raise McapFormatError(f"chunk at byte {at}: its records run past the chunk")
                raw = _decompress(kind, data, size)
                if crc and zlib.crc32(raw) != crc:
                    raise McapFormatError(f"chunk at byte {at} fails its CRC (changed on disk)")
                msgs = self._messages(raw, conns)
                self.chunks_read += 1
                self.messages_read += len(msgs.conn)
                yield msgs

    def _messages(self, raw: bytes, conns: dict[int, Connection], single: bool = False) -> ChunkMessages:
        """The Message records of a chunk's records (``single``: ``raw`` is one Message record's content)."""
        if single:
            cid, _seq, log_time = struct.unpack_from("<HIQ", raw, 0)
            one = np.ones(1, np.int64)
            return ChunkMessages(raw, one * cid, one * log_time, one * 22, one * (len(raw) - 22))
        cids, times, starts, lengths = [], [], [], []
        pos, size = 0, len(raw)
        while pos < size:
            if pos + 9 > size:
                raise McapFormatError("record cut short inside a chunk")
            op, n = _REC.unpack_from(raw, pos)
            body = pos + 9
            if body + n > size:
                raise McapFormatError(f"record of {n} bytes runs past its chunk (a corrupted length)")
            if op == OP_MESSAGE:
                if n < 22:
                    raise McapFormatError("message record shorter than its fields")
                cid, _seq, log_time = struct.unpack_from("<HIQ", raw, body)
                cids.append(cid)
                times.append(log_time)
                starts.append(body + 22)
                lengths.append(n - 22)
            elif op == OP_SCHEMA:
                self._schema(raw[body : body + n])
            elif op == OP_CHANNEL:
                self._channel(raw[body : body + n], conns)
            pos = body + n
        return ChunkMessages(
            raw,
            np.array(cids, np.int64),
            np.array(times, np.int64),
            np.array(starts, np.int64),
            np.array(lengths, np.int64),
        )
