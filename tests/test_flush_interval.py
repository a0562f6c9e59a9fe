"""The writer's promise: data older than flush_interval_s (host time) is on disk."""

import numpy as np

from imustation.runfile import ChannelSpec, DeviceSpec, RunWriter, open_run

DEV = DeviceSpec(
    name="g",
    driver="test",
    model="test",
    bus="sim:",
    identity="-",
    rate_hz=100.0,
    settings={},
    channels=(ChannelSpec("gyro", "int16", "rad/s", 1e-4, 0.0, ("x", "y", "z")),),
)


def test_blocks_reach_disk_within_the_flush_interval(tmp_path, monkeypatch):
    now = [1000.0]
    monkeypatch.setattr("imustation.runfile.writer.time.monotonic", lambda: now[0])
    path = tmp_path / "f.h5"
    w = RunWriter(path, station="s", config_text="", simulated=True, devices=[DEV], flush_interval_s=1.0)
    block = np.ones((10, 3), dtype=np.int16)
    t = np.arange(10, dtype=np.int64)
    w.append("g", t, {"gyro": block})
    now[0] += 0.5
    w.append("g", t + 10, {"gyro": block})
    assert w.samples_flushed["g"] == 0  # younger than the interval: may still be queued
    with open_run(path) as run:
        assert run.devices["g"].n == 0
    now[0] += 0.6  # the first block is now 1.1 s old
    w.flush_if_due()
    assert w.samples_flushed["g"] == 20
    with open_run(path) as run:  # a second reader sees it while the writer is open (SWMR)
        assert run.devices["g"].n == 20
    w.close()
