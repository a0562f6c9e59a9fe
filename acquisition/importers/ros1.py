"""Imu and Temperature blocks of a ROS 1 bag, streamed by :mod:`.rosbag1` and decoded with numpy.

One chunk of the bag is in memory at a time; the messages of the wanted topics
are decoded a chunk at a time (:func:`.messages.decode_imu_ros1`) and handed out
in blocks of at most ``block`` rows per topic, in file order (receive order
inside a chunk), never sorted.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator

import numpy as np

from imustation.acquisition.importers.mcap1 import Mcap1, McapFormatError
from imustation.acquisition.importers.messages import (
    IMU_TYPES,
    TEMP_TYPES,
    Rows,
    decode_imu_ros1,
    decode_temperature_ros1,
)
from imustation.acquisition.importers.ros1chunks import ChunkTable
from imustation.acquisition.importers.rosbag1 import BagFormatError, Connection, Ros1Bag
from imustation.errors import InputError

#: the last indexes read: (path, size, mtime ns) -> (connections, counts, the index was cut short). An
#: import reads a bag's index for its topics, its Imu definitions and its cut note: O(chunks) each time,
#: seconds for a bag of one message per chunk
_INDEXES: dict[tuple[str, int, int], tuple[dict[int, Connection], dict[int, int], bool, ChunkTable | None]] = {}


def _key(path: str) -> tuple[str, int, int]:
    st = os.stat(path)
    return os.path.abspath(path), st.st_size, st.st_mtime_ns


def ros1_index(path: str) -> tuple[dict[int, Connection], dict[int, int]]:
    """Connections and message counts per connection id of a ROS 1 bag (:meth:`.Ros1Bag.index`)."""
    try:
        key = _key(path)
        if key not in _INDEXES:
            with Ros1Bag(path) as bag:
                conns, counts = bag.index()
                if len(_INDEXES) >= 4:
                    _INDEXES.pop(next(iter(_INDEXES)))
                _INDEXES[key] = (conns, counts, bag.cut, bag.table)
        conns, counts, _cut, _table = _INDEXES[key]
        return dict(conns), dict(counts)
    except (BagFormatError, OSError, struct.error) as exc:
        raise InputError(f"{path}: not a readable ROS bag / MCAP file ({exc})") from None


def cut_note(bag: Ros1Bag) -> str:
    """One line on what a bag cut short or not closed held, after :meth:`.Ros1Bag.chunks` (else "").

    A closed bag's header says where its index starts and how many chunks it wrote, so a cut before
    the index loses ``chunk_count - chunks_read`` chunks and the data bytes up to ``index_pos``; the
    messages in them are estimated from the bytes per message of the chunks read (the index that
    counted them is gone). A cut inside the index loses nothing only when every chunk was read.
    """
    if bag.cut:
        stop = bag.unread_from if bag.unread_from is not None else bag.size
        missing = bag.chunk_count - bag.chunks_read
        partial = f", {bag.salvaged} of the chunk cut short" if bag.salvaged else ""
        head = (
            f"truncated bag: the file ends at byte {bag.size}, cut "
            f"{'at byte ' + str(bag.unread_from) if bag.unread_from is not None else _where(bag)} "
            f"(index at byte {bag.index_pos}); {bag.messages_read} messages before the cut imported "
            f"({bag.chunks_read} of {bag.chunk_count} chunks{partial})"
        )
        if missing <= 0 and bag.unread_from is None:
            return f"{head}, no message lost"
        gone = max(bag.index_pos - stop, 0)
        read = stop - bag.first_record
        whole = bag.messages_read - bag.salvaged  # in the chunks read whole, before ``stop``
        # the chunk cut short is in ``gone``: its salvaged messages are not lost
        est = f"~{max(round(whole * gone / read) - bag.salvaged, 0)}" if whole and read > 0 else "an unknown number of"
        # kept under the 256 bytes of an event's detail
        return f"{head}; not imported: bytes {stop}-{bag.index_pos}, {missing} chunks, {est} messages (estimated)"
    if bag.unread_from is not None:
        return (
            f"unindexed bag (recording not closed): bytes {bag.unread_from}-{bag.size} unreadable, not imported "
            f"({bag.messages_read} messages before them imported)"
        )
    return ""


def _where(bag: Ros1Bag) -> str:
    """Where a bag that ends on a record boundary was cut: inside its index, or before it."""
    if bag.size >= bag.index_pos:
        return "inside its index"
    return "between records"


def iter_ros1(
    path: str,
    topics: list[str],
    block: int,
    limit: int | None,
    temp_topics: tuple[str, ...] = (),
    notes: list[str] | None = None,
    mcap: bool = False,
) -> Iterator[tuple[str, Rows]]:
    """``(topic, block)`` of the Imu ``topics`` and Temperature ``temp_topics`` (see :func:`.bags.iter_bag`) of
    a ROS 1 bag, or (``mcap``) of an MCAP file of ROS 1 messages (profile ``ros1``; :mod:`.mcap1`)."""
    args = (topics, block, limit, temp_topics, notes)
    if mcap:
        yield from _read(path, Mcap1, McapFormatError, "damaged MCAP file", _mcap_note, *args)
    else:
        yield from _read(path, Ros1Bag, BagFormatError, "not a readable ROS bag", _bag_note, *args)


def _read(path, reader, error, what, note_of, *args) -> Iterator[tuple[str, Rows]]:
    """:func:`_decode` of the file ``path`` opened with ``reader`` (:class:`.Ros1Bag` or :class:`.Mcap1`); its
    ``error`` (and a record cut inside a field) one line: ``path: what (why)``."""
    try:
        with reader(path) as f:
            known = _INDEXES.get(_key(path)) if reader is Ros1Bag else None
            if known is not None:
                f.table = known[3]  # the chunks' positions, from the index read for the topics
            yield from _decode(path, f, *args, note_of)
    except (error, struct.error) as exc:
        raise InputError(f"{path}: {what} ({exc})") from None


def _bag_note(bag: Ros1Bag) -> str:
    if not bag.cut and bag.unread_from is None and bag.index_pos:
        # a bag cut inside its index (every message read): known from the index read for its topics
        known = _INDEXES.get(_key(bag.path))
        if known is not None:
            bag.cut = known[2]
        else:
            chunks, messages = bag.chunks_read, bag.messages_read
            bag.index()  # O(chunks)
            bag.chunks_read, bag.messages_read = chunks, messages
    return cut_note(bag)


def mcap1_index(path: str) -> tuple[dict[int, Connection], dict[int, int]]:
    """Channels and message counts per channel id of an MCAP file of ROS 1 messages (:meth:`.Mcap1.index`)."""
    try:
        with Mcap1(path) as m:
            return m.index()
    except (McapFormatError, OSError, struct.error) as exc:
        raise InputError(f"{path}: not a readable MCAP file ({exc})") from None


def _mcap_note(m: Mcap1) -> str:
    if m.unread_from is None:
        return ""
    return (
        f"truncated MCAP file: it ends at byte {m.size} inside a record that starts at byte {m.unread_from}; "
        f"{m.messages_read} messages before it imported ({m.chunks_read} chunks), what followed is not in the file"
    )


def _decode(path, bag, topics, block, limit, temp_topics, notes, note_of) -> Iterator[tuple[str, Rows]]:
    """The Imu and Temperature blocks of ``bag`` (a :class:`.Ros1Bag` or :class:`.Mcap1`: ``chunks(conns)``
    of ROS 1 messages), then its ``note_of(bag)`` appended to ``notes``."""
    names = [*topics, *temp_topics]
    pend: dict[str, list[tuple]] = {t: [] for t in names}
    have = dict.fromkeys(names, 0)
    seen = 0
    conns: dict = {}
    for ch in bag.chunks(conns):
        ids = [i for i, c in conns.items() if c.topic in topics and c.msgtype in IMU_TYPES]
        tids = [i for i, c in conns.items() if c.topic in temp_topics and c.msgtype in TEMP_TYPES]
        sel = np.isin(ch.conn, ids)
        if limit is not None and seen + int(sel.sum()) > limit:
            sel &= np.cumsum(sel) <= limit - seen
        seen += int(sel.sum())
        for t in names:
            mine = [i for i in (ids if t in topics else tids) if conns[i].topic == t]
            m = np.isin(ch.conn, mine) & (sel if t in topics else True)
            if not m.any():
                continue
            what = "Imu" if t in topics else "Temperature"
            decode = decode_imu_ros1 if t in topics else decode_temperature_ros1
            try:
                dec = decode(ch.buf, ch.start[m], ch.length[m])
            except ValueError as exc:
                raise InputError(f"{path}: topic {t}: undecodable {what} message ({exc})") from None
            pend[t].append(dec)
            have[t] += len(dec[0])
            if have[t] >= block:
                yield from _full_blocks(t, pend, have, block)
        if limit is not None and seen >= limit:
            break
        ch = None  # its buffer (a block of the file) is not held while the next is read
    if notes is not None and (limit is None or seen < limit):
        note = note_of(bag)
        if note:
            notes.append(note)
    for t in names:
        if have[t]:
            cols = [np.concatenate(x) for x in zip(*pend[t], strict=True)]
            yield t, (cols[0], cols[1], cols[2] if len(cols) > 2 else None)


def _full_blocks(t: str, pend: dict, have: dict, block: int) -> Iterator[tuple[str, Rows]]:
    cols = [np.concatenate(x) for x in zip(*pend[t], strict=True)]
    n = len(cols[0])
    k = (n // block) * block
    for i in range(0, k, block):
        part = [c[i : i + block] for c in cols]
        yield t, (part[0], part[1], part[2] if len(part) > 2 else None)
    pend[t] = [tuple(c[k:] for c in cols)] if k < n else []
    have[t] = n - k
