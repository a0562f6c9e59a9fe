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
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    Vector3 = store.types["geometry_msgs/msg/Vector3"]
    Quaternion = store.types["geometry_msgs/msg/Quaternion"]
    String = store.types["std_msgs/msg/String"]
    cov = np.zeros(9)

    def msg(i, t):
        hdr = Header(seq=i, stamp=Time(sec=int(t // 10**9), nanosec=int(t % 10**9)), frame_id="imu") if fmt == "ros1" \
            else Header(stamp=Time(sec=int(t // 10**9), nanosec=int(t % 10**9)), frame_id="imu")  # fmt: skip
        return Imu(
            header=hdr,
            orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=cov,
            angular_velocity=Vector3(x=float(gyro[i, 0]), y=float(gyro[i, 1]), z=float(gyro[i, 2])),
            angular_velocity_covariance=cov,
            linear_acceleration=Vector3(x=float(accel[i, 0]), y=float(accel[i, 1]), z=float(accel[i, 2])),
            linear_acceleration_covariance=cov,
        )

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
