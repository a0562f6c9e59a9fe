"""MCAP files of ROS 1 messages (what ``mcap convert`` makes of a bag), accepted as docs/import.md
promises, and damaged MCAP files of either profile refused in one line (issue 33)."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from bagmaker import write_imu_bag, write_ros1_mcap
from click.testing import CliRunner
from test_bad_input import assert_one_line_error

from imustation.acquisition.importers import import_recording
from imustation.cli import cli
from imustation.runfile import open_run

T0 = 1_700_000_000_000_000_000
PERIOD = 5_000_000


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def record(n=2000, seed=1):
    rng = np.random.default_rng(seed)
    t = T0 + np.arange(n, dtype=np.int64) * PERIOD
    return t, 1e-3 * rng.normal(size=(n, 3)), rng.normal(size=(n, 3)) + [0, 0, 9.81]


@pytest.mark.parametrize("compression", ["", "lz4", "zstd"])
@pytest.mark.parametrize("summary", [True, False])
def test_ros1_profile_mcap_imports_exactly(tmp_path, compression, summary):
    """Before: 'not a readable ROS bag / MCAP file (Profile is not ros2)'."""
    t, g, a = record()
    src = write_ros1_mcap(tmp_path / "conv.mcap", t, g, a, compression=compression, summary=summary,
                          extra_topics=("/imu/spare",))  # fmt: skip
    res = import_recording(str(src), str(tmp_path / "o.h5"), block=700)
    assert res.reports["imu_data"].n == len(t) and any("/imu/spare skipped" in n for n in res.notes)
    with open_run(tmp_path / "o.h5") as r:
        np.testing.assert_array_equal(r.read("imu_data", "t"), t - T0)
        np.testing.assert_array_equal(r.read("imu_data", "gyro"), g)
        np.testing.assert_array_equal(r.read("imu_data", "accel"), a)
        assert r.devices["imu_data"].model == "mcap" and r.devices["imu_data"].rate_hz == pytest.approx(200.0)
    res = run("analyze", src, "--channel", "imu_data/gyro/z", "-m", "40")
    assert res.exit_code == 0, res.output


def _chunk_at(data: bytes) -> int:
    """Offset of the first Chunk record (opcode 0x06) after the header, schema and channel records."""
    pos = 8
    while data[pos] != 0x06:
        (n,) = struct.unpack_from("<Q", data, pos + 1)
        pos += 9 + n
    return pos


@pytest.mark.parametrize("profile", ["ros1", "ros2"])
def test_damaged_mcap_is_one_line(tmp_path, profile):
    t, g, a = record(3000)
    if profile == "ros1":
        src = write_ros1_mcap(tmp_path / "good.mcap", t, g, a, chunk_msgs=1000)
    else:
        src = next(write_imu_bag(tmp_path / "r2", t, g, a, fmt="mcap").glob("*.mcap"))
    data = src.read_bytes()
    at = _chunk_at(data)
    (n,) = struct.unpack_from("<Q", data, at + 1)
    # a flipped byte inside the first chunk's records: its CRC fails (rosbags writes no CRC: a wrong one)
    flipped = bytearray(data)
    if profile == "ros1":
        flipped[at + 9 + n - 40] ^= 0x10
    else:
        flipped[at + 9 + 24 : at + 9 + 28] = struct.pack("<I", 0xDEADBEEF)
    (tmp_path / "crc.mcap").write_bytes(bytes(flipped))
    # the first chunk's record length corrupted
    long = bytearray(data)
    long[at + 1 : at + 9] = struct.pack("<Q", 2**40)
    (tmp_path / "length.mcap").write_bytes(bytes(long))
    for name in ("crc.mcap", "length.mcap"):
        for cmd in (["import", tmp_path / name, "-o", tmp_path / f"{name}.h5"], ["analyze", tmp_path / name]):
            res = run(*cmd)
            if profile == "ros2" and name == "length.mcap" and res.exit_code == 0:
                # rosbags finds the chunk through the summary's chunk index, not the record length:
                # every sample is read as written
                with open_run(tmp_path / f"{name}.h5") as r:
                    np.testing.assert_array_equal(r.read("imu_data", "gyro"), g)
                continue
            assert_one_line_error(res, name)


def test_ros1_mcap_without_crc_and_cut_short(tmp_path):
    t, g, a = record(3000)
    src = write_ros1_mcap(tmp_path / "nocrc.mcap", t, g, a, crc=False, chunk_msgs=1000)
    assert import_recording(str(src), str(tmp_path / "o.h5")).reports["imu_data"].n == 3000
    data = src.read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: int(len(data) * 0.5)])
    res = run("import", tmp_path / "cut.mcap", "-o", tmp_path / "cut.h5")
    assert res.exit_code == 0, res.output
    assert "truncated MCAP file" in res.output and "1000 messages before it imported (1 chunks)" in res.output
    with open_run(tmp_path / "cut.h5") as r:
        np.testing.assert_array_equal(r.read("imu_data", "gyro"), g[:1000])
    assert zlib.crc32(b"") == 0
