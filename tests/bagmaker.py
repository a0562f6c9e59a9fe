"""Small ROS 1 / ROS 2 (sqlite3, MCAP) bags with sensor_msgs/Imu messages, written with rosbags."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_imu_bag(path, t_ns, gyro, accel, *, fmt="ros1", topic="/imu/data", extra_topic=True) -> Path:
    """Write Imu messages stamped ``t_ns`` (header.stamp) in the given order; fmt ros1 | mcap | sqlite3."""
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    Imu = store.types["sensor_msgs/msg/Imu"]
    String = store.types["std_msgs/msg/String"]

    def msg(i, t):
        return _imu_msg(store, fmt, i, t, gyro[i], accel[i])

    t0 = int(t_ns[0])
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer

        with Writer(path) as w:
            c = w.add_connection(topic, Imu.__msgtype__, typestore=store)
            s = w.add_connection("/status", String.__msgtype__, typestore=store) if extra_topic else None
            for i, t in enumerate(t_ns):
                w.write(c, t0 + i * 1000, store.serialize_ros1(msg(i, int(t)), Imu.__msgtype__))
            if s is not None:
                w.write(s, t0, store.serialize_ros1(String(data="hello"), String.__msgtype__))
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        with Writer(path, version=9, storage_plugin=plugin) as w:
            c = w.add_connection(topic, Imu.__msgtype__, typestore=store)
            s = w.add_connection("/status", String.__msgtype__, typestore=store) if extra_topic else None
            for i, t in enumerate(t_ns):
                w.write(c, t0 + i * 1000, store.serialize_cdr(msg(i, int(t)), Imu.__msgtype__))
            if s is not None:
                w.write(s, t0, store.serialize_cdr(String(data="hello"), String.__msgtype__))
    return path


def imu_template(fmt: str = "ros1", frame_id: str = "imu") -> tuple[bytes, int, int]:
    """A serialised Imu message and the offsets of (sec, nsec) and the 37 float64 after the header."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    raw = _one(store, fmt, frame_id)
    stamp_at = 4  # ROS1: after uint32 seq; CDR: after the 4-byte encapsulation header
    return raw, stamp_at, len(raw) - 37 * 8


def _imu_msg(store, fmt, seq, t_ns, gyro, accel, frame_id="imu"):
    """One sensor_msgs/Imu of ``store`` (ROS 1 headers carry ``seq``), stamped ``t_ns``."""
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    V3 = store.types["geometry_msgs/msg/Vector3"]
    Q = store.types["geometry_msgs/msg/Quaternion"]
    cov = np.zeros(9)
    kw = {"seq": seq} if fmt == "ros1" else {}
    stamp = Time(sec=int(t_ns // 10**9), nanosec=int(t_ns % 10**9))
    return store.types["sensor_msgs/msg/Imu"](
        header=Header(**kw, stamp=stamp, frame_id=frame_id),
        orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=cov,
        angular_velocity=V3(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])), angular_velocity_covariance=cov,
        linear_acceleration=V3(x=float(accel[0]), y=float(accel[1]), z=float(accel[2])),
        linear_acceleration_covariance=cov,
    )  # fmt: skip


def _one(store, fmt, frame_id):
    m = _imu_msg(store, fmt, 0, 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), frame_id)
    ser = store.serialize_ros1 if fmt == "ros1" else store.serialize_cdr
    return bytes(ser(m, m.__msgtype__))


def imu_payloads(fmt: str, t_ns, gyro, accel, seq0: int = 0, frame_id: str = "imu") -> np.ndarray:
    """(k, L) uint8: serialised Imu messages built with numpy from a template (fast, for big bags)."""
    raw, st, fo = imu_template(fmt, frame_id)
    k = len(t_ns)
    out = np.tile(np.frombuffer(raw, np.uint8), (k, 1))
    t_ns = np.asarray(t_ns, dtype=np.int64)
    if fmt == "ros1":
        out[:, 0:4] = (np.arange(seq0, seq0 + k, dtype="<u4")).view(np.uint8).reshape(k, 4)
    out[:, st : st + 4] = (t_ns // 10**9).astype("<u4").view(np.uint8).reshape(k, 4)
    out[:, st + 4 : st + 8] = (t_ns % 10**9).astype("<u4").view(np.uint8).reshape(k, 4)
    f = out[:, fo:].copy().view("<f8")  # (k, 37)
    f[:, 13:16] = gyro
    f[:, 25:28] = accel
    out[:, fo:] = f.view(np.uint8)
    return out


def write_big_imu_bag(path, n, *, fmt="ros1", compression=None, rate_hz=400.0, block=65536, topics=("/imu/data",),
                      extra_every=0, seed=0, chunk_bytes=None, temp_every=0, lz4_options=None) -> Path:  # fmt: skip
    """A bag of ``n`` Imu messages per topic at ``rate_hz`` (white noise), written in blocks with numpy templates.

    ``compression``: ROS1 chunk compression None | "bz2" | "lz4". ``extra_every``: a std_msgs/String message
    on /status every that many Imu messages (0: none). Log time = header stamp (+ 1 us per further topic,
    whose frame_id is ``imu_link<j>``: messages of another length). ``temp_every``: a sensor_msgs/Temperature
    on /imu/temperature every that many Imu messages, stamped as that Imu message + 0.2 ms, 20 + i * 1e-4 degC
    (i: the Imu message's index). ``lz4_options``: keywords of ``lz4.frame.compress`` for the lz4 chunks
    (e.g. ``{"content_checksum": True, "store_size": False}``: a content checksum and no content size, as
    ROS's roslz4 writes; rosbags writes a content size and no checksum). Returns the bag path.
    """
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    imu_t = store.types["sensor_msgs/msg/Imu"].__msgtype__
    String = store.types["std_msgs/msg/String"]
    Temperature = store.types["sensor_msgs/msg/Temperature"]
    rng = np.random.default_rng(seed)
    period = int(round(1e9 / rate_hz))
    t0 = 1_700_000_000_000_000_000
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer

        w = Writer(path)
        if compression:
            w.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
        if lz4_options is not None:
            import lz4.frame

            w.compressor = lambda x: lz4.frame.compress(x, **lz4_options)
        if chunk_bytes:
            w.chunk_threshold = chunk_bytes
        ser = store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        w = Writer(path, version=9, storage_plugin=plugin)
        ser = store.serialize_cdr
    with w:
        conns = [w.add_connection(tp, imu_t, typestore=store) for tp in topics]
        s = w.add_connection("/status", String.__msgtype__, typestore=store) if extra_every else None
        sraw = bytes(ser(String(data="ok"), String.__msgtype__)) if s is not None else b""
        tc = w.add_connection("/imu/temperature", Temperature.__msgtype__, typestore=store) if temp_every else None
        Hdr, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]

        def temp_raw(i, t):
            t += 200_000
            hdr = Hdr(**({"seq": i} if fmt == "ros1" else {}), stamp=Time(sec=t // 10**9, nanosec=t % 10**9),
                      frame_id="imu")  # fmt: skip
            return bytes(ser(Temperature(header=hdr, temperature=20 + i * 1e-4, variance=0.0), Temperature.__msgtype__))

        for i in range(0, n, block):
            k = min(block, n - i)
            t = t0 + np.arange(i, i + k, dtype=np.int64) * period
            pays = [imu_payloads(fmt, t + j * 1000, rng.normal(0, 1e-3, (k, 3)), rng.normal(0, 1, (k, 3)), i,
                                 "imu" if j == 0 else f"imu_link{j}") for j in range(len(topics))]  # fmt: skip
            for r in range(k):  # in record-time order
                for j, c in enumerate(conns):
                    w.write(c, int(t[r]) + j * 1000, pays[j][r].tobytes())
                    if j == 0 and s is not None and (i + r) % extra_every == 0:
                        w.write(s, int(t[r]) + 500, sraw)
                    if j == 0 and tc is not None and (i + r) % temp_every == 0:
                        w.write(tc, int(t[r]) + 600, temp_raw(i + r, int(t[r])))
    return path


def write_ros1_mcap(path, t_ns, gyro, accel, *, topic="/imu/data", chunk_msgs=500, compression="", crc=True,
                    summary=True, extra_topics=()) -> Path:  # fmt: skip
    """An MCAP file of ROS 1 sensor_msgs/Imu messages as ``mcap convert`` writes one from a bag (profile
    ``ros1``, schema encoding ``ros1msg``, message encoding ``ros1``; chunks of ``chunk_msgs`` messages
    compressed with "" | "lz4" | "zstd", their CRCs when ``crc``; a summary with a Statistics record when
    ``summary``). ``extra_topics``: Imu topics with a channel and no message. Written by hand
    (https://mcap.dev/spec): the mcap package is not a dependency."""
    import struct
    import zlib

    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    store = get_typestore(Stores.ROS1_NOETIC)
    imu = store.types["sensor_msgs/msg/Imu"].__msgtype__

    def s(x: str) -> bytes:
        b = x.encode()
        return struct.pack("<I", len(b)) + b

    def rec(op: int, content: bytes) -> bytes:
        return struct.pack("<BQ", op, len(content)) + content

    def compress(raw: bytes) -> bytes:
        if compression == "lz4":
            import lz4.frame

            return lz4.frame.compress(raw)
        if compression == "zstd":
            from backports import zstd

            return zstd.compress(raw)
        return raw

    schema = rec(0x03, struct.pack("<H", 1) + s("sensor_msgs/Imu") + s("ros1msg") + s("# definition"))
    meta = s("md5sum") + s("6a62c6daae103f4ff57a132d6f95cec2")
    topics = [topic, *extra_topics]
    channels = [rec(0x04, struct.pack("<HH", i + 1, 1) + s(tp) + s("ros1") + struct.pack("<I", len(meta)) + meta)
                for i, tp in enumerate(topics)]  # fmt: skip
    out = bytearray(b"\x89MCAP0\r\n" + rec(0x01, s("ros1") + s("imustation tests")))
    out += schema + b"".join(channels)
    msgs = [bytes(store.serialize_ros1(_imu_msg(store, "ros1", i, int(t), g, a), imu))
            for i, (t, g, a) in enumerate(zip(t_ns, gyro, accel, strict=True))]  # fmt: skip
    for i in range(0, len(msgs), chunk_msgs):
        raw = b"".join(rec(0x05, struct.pack("<HIQQ", 1, i + j, int(t_ns[i + j]), int(t_ns[i + j])) + m)
                       for j, m in enumerate(msgs[i : i + chunk_msgs]))  # fmt: skip
        data = compress(raw)
        head = struct.pack("<QQQI", int(t_ns[i]), int(t_ns[min(i + chunk_msgs, len(msgs)) - 1]), len(raw),
                           zlib.crc32(raw) if crc else 0)  # fmt: skip
        out += rec(0x06, head + s(compression) + struct.pack("<Q", len(data)) + data)
    out += rec(0x0F, struct.pack("<I", 0))
    summary_start = len(out) if summary else 0
    if summary:
        counts = struct.pack("<HQ", 1, len(msgs)) + b"".join(
            struct.pack("<HQ", i + 2, 0) for i in range(len(extra_topics))
        )
        stats = struct.pack("<QHIIIIQQ", len(msgs), 1, len(topics), 0, 0, -(-len(msgs) // chunk_msgs),
                            int(t_ns[0]), int(t_ns[-1])) + struct.pack("<I", len(counts)) + counts  # fmt: skip
        out += schema + b"".join(channels) + rec(0x0B, stats)
    out += rec(0x02, struct.pack("<QQI", summary_start, 0, 0)) + b"\x89MCAP0\r\n"
    path.write_bytes(bytes(out))
    return path


def roslz4_bag(path, n: int, chunk: int) -> tuple[Path, bytes, int, int, int]:
    """A one-message-per-chunk lz4 bag of ``n`` Imu messages whose frames carry a content checksum and no
    content size (as ROS's roslz4 writes them), and where chunk ``chunk`` keeps its frame: (path, the bag's
    bytes, the chunk record's offset, its lz4 frame's offset, the frame's length). The frame follows the
    chunk record's header and its 4-byte data length."""
    from rosbags.rosbag1 import Reader

    src = write_big_imu_bag(path, n, compression="lz4", chunk_bytes=1,
                            lz4_options={"content_checksum": True, "store_size": False})  # fmt: skip
    data = src.read_bytes()
    with Reader(src) as r:
        at = [c.pos for c in r.chunk_infos][chunk]
    hl = int.from_bytes(data[at : at + 4], "little")
    frame = at + 8 + hl
    return src, data, at, frame, int.from_bytes(data[at + 4 + hl : frame], "little")
