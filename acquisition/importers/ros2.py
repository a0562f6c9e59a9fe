"""Imu and Temperature blocks of ROS 2 bags (sqlite3, mcap) and ``.mcap`` files, read with ``rosbags``.

rosbags' readers index chunks, not messages (O(chunks) memory). The raw CDR Imu
messages of a block are decoded together with numpy (:func:`.messages.decode_imu_cdr`);
rosbags' deserialiser (messages whose definition is not in the bag: the ROS 2
Humble type store) decodes anything else, and every message with ``reader="old"``.
Also the fallback for ROS 1 bags whose Imu definition is not sensor_msgs/Imu's.
Messages come in rosbags' order (log time).
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from imustation.acquisition.importers.messages import IMU_TYPES, TEMP_TYPES, Rows, decode_imu_cdr
from imustation.errors import InputError


def _stamp_ns(msg) -> int:
    st = msg.header.stamp
    return int(st.sec) * 1_000_000_000 + int(st.nanosec)


def _open_bag(path: str):
    """An open rosbags ``AnyReader`` of ``path``; InputError when it is not a readable bag."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    try:
        reader = AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises several reader errors; all mean "not a readable bag"
        raise InputError(f"{path}: not a readable ROS bag / MCAP file ({exc})") from None
    return reader


def _reader_errors() -> tuple[type[BaseException], ...]:
    """What rosbags' readers raise for a damaged file (a chunk failing its CRC, a corrupted record length,
    a compressed block that does not decompress), besides their own ReaderErrors."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Ros1ReaderError
    from rosbags.rosbag2 import ReaderError

    return (ReaderError, Ros1ReaderError, AnyReaderError, struct.error, EOFError, OSError, ValueError, KeyError,
            IndexError, RuntimeError, MemoryError, OverflowError)  # fmt: skip


def _checked(path: str, messages: Iterator) -> Iterator:
    """``messages`` of a rosbags reader; a damaged file is one InputError naming it, not a traceback."""
    errors = _reader_errors()
    it = iter(messages)
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except errors as exc:
            text = str(exc).splitlines()[0][:200] if str(exc) else exc.__class__.__name__
            raise InputError(f"{path}: damaged bag / MCAP file ({text})") from None
        yield item


def rosbags_connections(path: str) -> list[tuple[str, str, int]]:
    """``(topic, msgtype, message count)`` of every connection, as rosbags lists them."""
    bag = _open_bag(path)
    try:
        return [(c.topic, c.msgtype, int(c.msgcount)) for c in bag.connections]
    finally:
        bag.close()


def iter_rosbags(
    path: str,
    topics: list[str],
    block: int,
    limit: int | None,
    reader: str,
    temp_topics: tuple[str, ...] | list[str] = (),
) -> Iterator[tuple[str, Rows]]:
    """``(topic, block)`` of the Imu ``topics`` and Temperature ``temp_topics`` (see :func:`.bags.iter_bag`)."""
    bag = _open_bag(path)
    try:
        conns = [c for c in bag.connections if c.topic in topics and c.msgtype in IMU_TYPES]
        tconns = [c for c in bag.connections if c.topic in temp_topics and c.msgtype in TEMP_TYPES]
        # ROS 2 / MCAP: the raw CDR messages of a block are decoded together with numpy (reader="new")
        cdr = reader == "new" and all(getattr(c.ext, "serialization_format", "") == "cdr" for c in conns)
        raws: dict[str, list] = {t: [] for t in topics}
        temps: dict[str, list] = {t: [] for t in temp_topics}
        bufs = {t: np.empty((block, 7)) for t in topics}
        fill = dict.fromkeys(topics, 0)
        stamps = {t: np.empty(block, dtype=np.int64) for t in topics}
        seen = 0
        for conn, _logtime, raw in _checked(path, bag.messages(connections=conns + tconns)):
            t = conn.topic
            if conn.msgtype in TEMP_TYPES:
                try:
                    msg = bag.deserialize(raw, conn.msgtype)
                except Exception as exc:
                    raise InputError(f"{path}: topic {t}: undecodable Temperature message ({exc})") from None
                temps[t].append((_stamp_ns(msg), float(msg.temperature)))
                if len(temps[t]) == block:
                    yield t, _temp_block(temps[t])
                    temps[t] = []
                continue
            if cdr:
                raws[t].append(raw)
                if len(raws[t]) == block:
                    yield t, _decode_cdr(path, bag, t, raws[t])
                    raws[t] = []
            else:
                try:
                    msg = bag.deserialize(raw, conn.msgtype)
                except Exception as exc:
                    raise InputError(f"{path}: topic {conn.topic}: undecodable Imu message ({exc})") from None
                i = fill[t]
                w, a = msg.angular_velocity, msg.linear_acceleration
                stamps[t][i] = _stamp_ns(msg)
                bufs[t][i] = (0.0, w.x, w.y, w.z, a.x, a.y, a.z)
                fill[t] = i + 1
                if i + 1 == block:
                    yield t, (stamps[t].copy(), bufs[t][:, 1:4].copy(), bufs[t][:, 4:7].copy())
                    fill[t] = 0
            seen += 1
            if limit is not None and seen >= limit:
                break
        for t in topics:
            k = fill[t]
            if k:
                yield t, (stamps[t][:k].copy(), bufs[t][:k, 1:4].copy(), bufs[t][:k, 4:7].copy())
            if raws[t]:
                yield t, _decode_cdr(path, bag, t, raws[t])
        for t in temp_topics:
            if temps[t]:
                yield t, _temp_block(temps[t])
    finally:
        bag.close()


def _temp_block(rows: list[tuple[int, float]]) -> tuple[np.ndarray, np.ndarray, None]:
    return np.array([r[0] for r in rows], np.int64), np.array([r[1] for r in rows], np.float64), None


def _decode_cdr(path: str, bag, topic: str, raws: list) -> Rows:
    """A block of CDR Imu messages: numpy when they have the standard layout, else rosbags' deserialiser."""
    try:
        return decode_imu_cdr(raws)
    except ValueError:
        pass
    k = len(raws)
    t, g, a = np.empty(k, np.int64), np.empty((k, 3)), np.empty((k, 3))
    for i, raw in enumerate(raws):
        try:
            msg = bag.deserialize(raw, "sensor_msgs/msg/Imu")
        except Exception as exc:
            raise InputError(f"{path}: topic {topic}: undecodable Imu message ({exc})") from None
        w, acc = msg.angular_velocity, msg.linear_acceleration
        t[i], g[i], a[i] = _stamp_ns(msg), (w.x, w.y, w.z), (acc.x, acc.y, acc.z)
    return t, g, a
