"""ROS bags (ROS 1 ``.bag``, ROS 2 bag folders, ``.mcap``): which reader, which topics, Imu blocks.

ROS 1 bags are streamed by imustation's own reader (:mod:`.ros1`) unless their
Imu connection has another definition than sensor_msgs/Imu; everything else is
read with rosbags (:mod:`.ros2`). ``reader="old"`` reads every format with
rosbags message by message (the import as it was, for comparison: docs/import.md).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from imustation.acquisition.importers.mcap1 import profile
from imustation.acquisition.importers.messages import BLOCK_ROWS, IMU_MD5, IMU_TYPES, TEMP_TYPES, Rows
from imustation.acquisition.importers.ros1 import iter_ros1, mcap1_index, ros1_index
from imustation.acquisition.importers.ros2 import iter_rosbags, rosbags_connections
from imustation.errors import InputError

BAG_EXTS = (".bag", ".mcap")


def bag_format(path: str) -> str:
    """``"mcap"``, ``"rosbag1"`` or ``"rosbag2"`` (a bag folder): the device model of an imported bag."""
    return "mcap" if path.endswith(".mcap") else "rosbag1" if path.endswith(".bag") else "rosbag2"


def _streaming(path: str, reader: str) -> bool:
    """Read with :mod:`.ros1` (ROS 1 ``.bag`` files unless ``reader == "old"``)."""
    if reader not in ("new", "old"):
        raise ValueError(f"bag reader {reader!r}: 'new' or 'old'")
    return reader == "new" and Path(path).is_file() and path.lower().endswith(".bag")


def _ros1_mcap(path: str) -> bool:
    """An MCAP file whose profile is not ROS 2's: ROS 1 messages (``mcap convert`` of a bag), which
    rosbags refuses; read by :mod:`.mcap1` whatever the reader asked for."""
    return Path(path).is_file() and path.lower().endswith(".mcap") and profile(path) not in (None, "ros2")


def bag_connections(path: str, reader: str = "new") -> list[tuple[str, str, int]]:
    """``(topic, msgtype, message count)`` of every connection of a bag."""
    if _streaming(path, reader) or _ros1_mcap(path):
        conns, counts = ros1_index(path) if _streaming(path, reader) else mcap1_index(path)
        return [(c.topic, c.msgtype, counts.get(c.id, 0)) for c in conns.values()]
    return rosbags_connections(path)


def bag_topics(path: str, topic: str | None = None, reader: str = "new") -> list[tuple[str, int]]:
    """``(topic, message count)`` of the Imu topics of a bag (only ``topic`` if given)."""
    return imu_topics(path, topic, bag_connections(path, reader))


def _count_messages(conns: list[tuple[str, str, int]], types: tuple[str, ...]) -> dict[str, int]:
    """Messages per topic of the connections of ``types`` (``(topic, msgtype, count)`` of every connection)."""
    out: dict[str, int] = {}
    for tp, mt, n in conns:
        if mt in types:
            out[tp] = out.get(tp, 0) + n
    return out


def imu_topics(path: str, topic: str | None, conns: list[tuple[str, str, int]]) -> list[tuple[str, int]]:
    """Imu topics and their message counts from ``(topic, msgtype, count)`` of every connection."""
    imu = _count_messages(conns, IMU_TYPES)
    if topic is not None:
        if topic not in imu:
            have = ", ".join(sorted(imu)) or "none"
            raise InputError(f"{path}: no sensor_msgs/Imu topic {topic} (Imu topics: {have})")
        return [(topic, imu[topic])]
    if not imu:
        topics = ", ".join(sorted({c[0] for c in conns})) or "none"
        raise InputError(f"{path}: no sensor_msgs/Imu topic (topics: {topics})")
    return sorted(imu.items())


def temperature_topics(conns: list[tuple[str, str, int]]) -> list[str]:
    """The sensor_msgs/Temperature topics, sorted."""
    return sorted(_count_messages(conns, TEMP_TYPES))


def iter_bag(
    path: str,
    topics: list[str],
    block: int = BLOCK_ROWS,
    limit: int | None = None,
    reader: str = "new",
    temp_topics: tuple[str, ...] | list[str] = (),
    notes: list[str] | None = None,
) -> Iterator[tuple[str, Rows]]:
    """``(topic, block)`` of the Imu messages of ``topics`` in file order, ``block`` rows per topic at most.

    ``temp_topics``: sensor_msgs/Temperature topics, yielded as ``(topic, (t_ns, celsius (k,), None))``.
    ``limit``: stop after that many Imu messages. ``notes``: what the reader has to say is appended (the
    unreadable tail of an unindexed ROS 1 bag).
    ``reader="new"``: ROS 1 bags are read with :mod:`.ros1` (one chunk in memory, messages decoded
    with numpy), ROS 2 bags and MCAP with rosbags, a block of raw CDR messages decoded at once with numpy.
    ``reader="old"``: rosbags for every format, messages deserialised one by one (the import as it was).
    """
    if _ros1_mcap(path):
        yield from iter_ros1(path, topics, block, limit, tuple(temp_topics), notes, mcap=True)
        return
    if _streaming(path, reader):
        conns, _ = ros1_index(path)
        if all(c.md5sum == IMU_MD5 for c in conns.values() if c.topic in topics and c.msgtype in IMU_TYPES):
            yield from iter_ros1(path, topics, block, limit, tuple(temp_topics), notes)
            return
        # an Imu definition other than sensor_msgs/Imu's: let rosbags decode it from the bag's definition
    yield from iter_rosbags(path, topics, block, limit, reader, temp_topics)
