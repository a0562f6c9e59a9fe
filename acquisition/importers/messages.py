"""Vectorised decoding of serialised ``sensor_msgs/Imu`` (ROS 1, CDR) and ``/Temperature`` (ROS 1) with numpy.

Both layouts are a header (stamp, frame_id string) followed by 37 float64:
orientation (4), its covariance (9), angular_velocity (3), covariance (9),
linear_acceleration (3), covariance (9). Only the stamp, angular_velocity and
linear_acceleration are read. ``sensor_msgs/Temperature``: the header, then
temperature and variance (float64); in ROS 2 bags rosbags deserialises them (:mod:`.ros2`).
A message whose length does not fit the layout raises ValueError (the caller then
falls back to a full deserialiser or reports it).

Also the shape every reader of the importer hands out (:data:`Rows`: times, rates, accelerations or None).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from imustation.acquisition.importers.bytegather import gather_u32

#: the message types as ROS 2 (and rosbags) and ROS 1 bags name them
IMU_TYPES = ("sensor_msgs/msg/Imu", "sensor_msgs/Imu")
TEMP_TYPES = ("sensor_msgs/msg/Temperature", "sensor_msgs/Temperature")
#: md5sum of sensor_msgs/Imu (ROS 1): the layout :func:`decode_imu_ros1` knows
IMU_MD5 = "6a62c6daae103f4ff57a132d6f95cec2"
IMU_TAIL = 37 * 8
_GYRO_AT, _ACCEL_AT = 13 * 8, 25 * 8
_COLS = np.r_[np.arange(_GYRO_AT, _GYRO_AT + 24), np.arange(_ACCEL_AT, _ACCEL_AT + 24)]

Decoded = tuple[np.ndarray, np.ndarray, np.ndarray]
#: what every reader yields: ``(t_ns int64 (k,), gyro float64 (k, 3) rad/s, accel float64 (k, 3) m/s^2 | None)``;
#: a thermometer's block is ``(t_ns, celsius (k,), None)``
Rows = tuple[np.ndarray, np.ndarray, np.ndarray | None]
#: rows per block written (and held per topic while reading)
BLOCK_ROWS = 8192


def _empty() -> Decoded:
    return np.empty(0, np.int64), np.empty((0, 3)), np.empty((0, 3))


def _floats(b: np.ndarray, tail: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # the rows from the gyro to the accel by a window view (k * 120 bytes, not an index of k * 48 int64)
    rows = sliding_window_view(b, _ACCEL_AT + 24 - _GYRO_AT)[tail + _GYRO_AT]
    f = np.ascontiguousarray(rows[:, _COLS - _GYRO_AT]).view("<f8")  # (k, 6)
    return f[:, :3].copy(), f[:, 3:].copy()


def _check(start: np.ndarray, length: np.ndarray, size: int, minimum: int) -> None:
    if (length < minimum).any() or (start + length > size).any():
        raise ValueError("message shorter than a sensor_msgs/Imu")


def _bad(length: np.ndarray, expect: np.ndarray) -> None:
    if (length != expect).any():
        i = int(np.flatnonzero(length != expect)[0])
        raise ValueError(f"message {i} of the block: {length[i]} bytes, not the sensor_msgs/Imu layout")


def _ros1_head(buf, start, length, tail: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ROS 1 header (seq u32, stamp sec u32 + nsec u32, frame_id u32 length + bytes) then ``tail`` bytes:
    ``(uint8 buffer, stamps ns, offsets of the tails)``."""
    b = np.frombuffer(buf, np.uint8)
    start, length = np.asarray(start, np.int64), np.asarray(length, np.int64)
    _check(start, length, len(b), 16 + tail)
    sec, nsec, flen = gather_u32(b, start + 4), gather_u32(b, start + 8), gather_u32(b, start + 12)
    _bad(length, 16 + flen + tail)
    return b, sec * 1_000_000_000 + nsec, start + 16 + flen


def _cdr_head(raws: list, tail: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CDR: 4-byte encapsulation header (little endian: ``00 01``), stamp sec i32 + nanosec u32, frame_id
    (u32 length with the NUL + bytes), padding to 8 (counted after the encapsulation header), ``tail`` bytes
    of float64."""
    length = np.fromiter((len(r) for r in raws), np.int64, len(raws))
    start = np.concatenate([[0], np.cumsum(length)[:-1]])
    b = np.frombuffer(b"".join(raws), np.uint8)
    _check(start, length, len(b), 16 + tail)
    if not ((b[start] == 0) & (b[start + 1] == 1)).all():
        raise ValueError("not little-endian CDR")
    sec = gather_u32(b, start + 4)
    sec = np.where(sec >= 2**31, sec - 2**32, sec)  # int32
    nsec, slen = gather_u32(b, start + 8), gather_u32(b, start + 12)
    floats_at = 4 + (16 + slen - 4 + 7) // 8 * 8
    _bad(length, floats_at + tail)
    return b, sec * 1_000_000_000 + nsec, start + floats_at


def decode_imu_ros1(buf, start, length) -> Decoded:
    """``(header.stamp ns int64 (k,), angular_velocity (k, 3), linear_acceleration (k, 3))`` of the ROS 1
    messages ``buf[start[i]:start[i] + length[i]]``."""
    if len(start) == 0:
        return _empty()
    b, t, tail = _ros1_head(buf, start, length, IMU_TAIL)
    return (t, *_floats(b, tail))


def decode_imu_cdr(raws: list) -> Decoded:
    """The same for a list of CDR (ROS 2) messages."""
    if not raws:
        return _empty()
    b, t, tail = _cdr_head(raws, IMU_TAIL)
    return (t, *_floats(b, tail))


def _temperature(b: np.ndarray, tail: np.ndarray) -> np.ndarray:
    return b[tail[:, None] + np.arange(8)].view("<f8")[:, 0].copy()


def decode_temperature_ros1(buf, start, length) -> tuple[np.ndarray, np.ndarray]:
    """``(header.stamp ns, temperature degC)`` of ROS 1 sensor_msgs/Temperature (header, temperature, variance)."""
    if len(start) == 0:
        return np.empty(0, np.int64), np.empty(0)
    b, t, tail = _ros1_head(buf, start, length, 16)
    return t, _temperature(b, tail)
