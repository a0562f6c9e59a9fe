"""KVH DSP-3000: line parsing against docs/reference/sensors.md §6 vectors, resync, status 0, modes, driver on sim."""

import numpy as np
import pytest

from imustation.clock import VirtualClock
from imustation.drivers import kvh_dsp3000 as kvh
from imustation.drivers.bus.serial_port import SerialPort
from imustation.drivers.sim.faults import FaultPlan, FaultSpec
from imustation.drivers.sim.kvh_dsp3000 import DSP3000Sim
from imustation.drivers.sim.serial_handlers import register, unregister
from imustation.drivers.sim.sources import NoiseSource
from imustation.errors import DeviceError, SettingError
from imustation.units import DEG2RAD


def test_sensors_md_vectors():
    counts, flag = kvh.parse_line(b"       0.015733   1")
    assert (counts, flag) == (15733, 1)
    assert counts * 1e-6 * DEG2RAD == pytest.approx(2.746e-4, rel=1e-3)
    assert kvh.parse_line(b"  -12.500000   0") == (-12_500_000, 0)
    assert kvh.parse_line(b"0.015733   1") is None  # no leading space [KVH-R]
    assert kvh.parse_line(b"   0.015733   2") is None  # status must be 0 or 1
    assert kvh.parse_line(b"   -0.000001   1") == (-1, 1)  # the sign of a value below 1 survives


def test_reader_resyncs_on_crlf():
    r = kvh.LineReader()
    stream = b"0733   1\r\n   1.000000   1\r\n  -2.5   1\r\n   3.0q0000   1\r\n   4.000000   0\r\n   5.0000"
    scan = r.feed(stream)
    counts, flags = scan.frames
    assert counts.tolist() == [1_000_000, -2_500_000, 4_000_000] and flags.tolist() == [1, 1, 0]
    assert scan.extra["bad_lines"] == 1  # the partial first line is not an error, the damaged one is
    scan = r.feed(b"00   1\r\n")
    assert scan.frames[0].tolist() == [5_000_000]


def rig(mode="rate", faults=(), baud=38400, name="fog-test"):
    clock = VirtualClock()
    plan = FaultPlan(list(faults), clock) if faults else None
    sim = DSP3000Sim(clock, lambda fs: NoiseSource.for_device("dsp3000", ("z",), fs, {}, 5), plan)
    url = register(name, sim)
    port = SerialPort(f"serial:/dev/ttyS0?baud={baud}", baud_default=38400, sim_url=url)
    return kvh.KVHDSP3000(port, {"mode": mode}, sleep=clock.sleep), sim, clock


@pytest.mark.parametrize("mode", ["rate", "incremental_angle"])
def test_modes_give_the_same_rate(mode):
    drv, sim, clock = rig(mode, name=f"fog-{mode}")
    try:
        info = drv.open()
        assert sim.mode == mode and info.settings["mode"] == mode
        blocks = []
        for _ in range(50):
            clock.sleep(info.poll_interval_s)
            blocks.append(drv.read_block())
        gyro = np.concatenate([b.channels["gyro"] for b in blocks])[:, 0] * info.channels[0].scale
        assert sum(b.lost for b in blocks) == 0 and 995 <= len(gyro) <= 1000
        # oracle: Table IV white noise 1.56e-5 rad/s/sqrt(Hz) at 100 Hz -> std 1.56e-4 rad/s; bias drawn
        # with std 0.5 deg/s. The std of 1000 samples is within 10 % of sigma_w*sqrt(fs) (chi-square, 5 sigma).
        assert np.std(gyro) == pytest.approx(1.56e-5 * 10, rel=0.12)
    finally:
        unregister(f"fog-{mode}")


def test_status_zero_and_damaged_lines_become_lost_samples():
    drv, _, clock = rig(faults=[FaultSpec("reset", at_s=2.0), FaultSpec("corrupt", at_s=5.0),
                                FaultSpec("short_read", at_s=6.0)], name="fog-f")  # fmt: skip
    try:
        info = drv.open()
        lost, notes, n = 0, [], 0
        for _ in range(40):
            clock.sleep(info.poll_interval_s)
            b = drv.read_block()
            lost, n = lost + b.lost, n + b.n
            if b.note:
                notes.append(b.note)
        assert any(note.startswith("status 0") for note in notes)
        assert sum("resync" in note for note in notes) == 2
        assert 95 <= lost <= 103  # 1 s of start-up lines + 2 damaged lines (+1 merged by the lost CR LF)
        assert n + lost == pytest.approx(800, abs=3)
    finally:
        unregister("fog-f")


def test_wrong_baud_rate_is_reported():
    drv, _, _ = rig(baud=115200, name="fog-baud")
    try:
        with pytest.raises(DeviceError, match="wrong baud rate"):
            drv.open()
    finally:
        unregister("fog-baud")


def test_bad_settings():
    with pytest.raises(SettingError, match="mode = 'integrated'"):
        kvh.KVHDSP3000.check_settings({"mode": "integrated"})
    with pytest.raises(SettingError, match="rate_hz = 1000"):
        kvh.KVHDSP3000.check_settings({"rate_hz": 1000})
