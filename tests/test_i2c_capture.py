"""Simulated captures of the I2C chips end to end: file contents, FIFO overflow, chip reset, `devices`."""

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.acquisition import capture
from imustation.acquisition.config import parse_config
from imustation.cli import cli
from imustation.drivers.sim import simulated_truth
from imustation.runfile import open_run
from imustation.units import DEG2RAD, G0

DEVICES = [
    # opened in this order: the MPUs' reset waits come before the fast-filling BMX055 FIFO is set up
    {"name": "mpu9150", "driver": "mpu9150", "bus": "i2c:2", "rate_hz": 200, "bandwidth_hz": 42},
    {"name": "mpu6500", "driver": "mpu6500", "bus": "i2c:2", "address": 0x69, "rate_hz": 250, "bandwidth_hz": 92,
     "gyro_range_dps": 500, "accel_range_g": 4},
    {"name": "acc", "driver": "bmx055_accel", "bus": "i2c:1", "rate_hz": 125},
]  # fmt: skip
DURATION_S = 60.0


def slots(run, name):
    """Sample periods spanned by a device's time stamps: samples written + lost if none is unaccounted."""
    t = run.read(name, "t")
    return round((t[-1] - t[0]) * run.devices[name].rate_hz / 1e9) + 1


def config(devices=DEVICES, seed=5, faults=None):
    devices = [dict(d) for d in devices]
    for d in devices:
        if faults and d["name"] in faults:
            d["sim"] = {"faults": faults[d["name"]]}
    return parse_config({"station": {"seed": seed}, "device": devices})


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory):
    cfg = config()
    out = tmp_path_factory.mktemp("i2c") / "clean.h5"
    summary = capture(cfg, out, DURATION_S, simulate=True)
    return cfg, out, summary


def test_file_contents(clean_run):
    cfg, out, summary = clean_run
    with open_run(out) as run:
        assert run.events() == []
        for name, rate in (("mpu9150", 200), ("mpu6500", 250), ("acc", 125)):
            dev = run.devices[name]
            assert dev.rate_hz == rate and dev.settings["rate_hz"] == rate
            assert summary.samples[name] == dev.n == slots(run, name)
            assert abs(dev.n - DURATION_S * rate) <= 0.4 * 73 + 0.3 * rate  # last poll, opening of later devices
            t = run.read(name, "t")
            assert np.all(np.diff(t) == 1e9 / rate)
            assert dev.channels["accel"].units == "m/s^2" and dev.channels["accel"].axes == ("x", "y", "z")
        m9, m65, acc = run.devices["mpu9150"], run.devices["mpu6500"], run.devices["acc"]
        assert m9.identity == "who_am_i=0x68" and m65.identity == "who_am_i=0x70" and acc.identity == "chip_id=0xFA"
        assert m9.settings["smplrt_div"] == 4 and m9.settings["dlpf_cfg"] == 3 and m9.settings["bandwidth_hz"] == 42
        assert m65.settings["gyro_range_dps"] == 500 and m65.settings["accel_range_g"] == 4
        assert m9.channels["gyro"].scale == pytest.approx(DEG2RAD / 131)
        assert m65.channels["gyro"].scale == pytest.approx(DEG2RAD / 65.5)
        assert m65.channels["accel"].scale == pytest.approx(G0 / 8192)
        assert acc.channels["accel"].scale == pytest.approx(G0 / 1024)
        assert m9.channels["temp"].offset == 36.53 and m65.channels["temp"].offset == 21.0
        truth = simulated_truth(cfg)
        for name in ("mpu9150", "mpu6500", "acc"):
            ch = run.devices[name].channels["accel"]
            a = run.read(name, "accel").astype(float) * ch.scale
            mean = a.mean(axis=0)
            # gravity on z plus the drawn turn-on bias, within a few mg
            b_on = np.array([truth[f"{name}/accel/{ax}"].b_on for ax in "xyz"])
            assert np.all(np.abs(mean - b_on - np.array([0, 0, G0])) < 3e-3 * G0), mean
            assert abs(mean[2] - G0) < 6e-3 * G0
            temp = run.read(name, "temp").astype(float) * run.devices[name].channels["temp"].scale
            temp += run.devices[name].channels["temp"].offset
            assert np.all(np.abs(temp - 30.0) < 0.6)
        # gyro noise of the MPU-9150 z axis: Table IV white noise at 200 Hz. Oracle: sigma_w * sqrt(fs);
        # the std of 12 000 samples has a relative SE of 1/sqrt(2N) = 0.65 %, quantisation adds 0.2 %
        g = run.read("mpu9150", "gyro").astype(float) * m9.channels["gyro"].scale
        sigma = truth["mpu9150/gyro/z"].sigma_w * np.sqrt(200)
        assert np.std(g[:, 2]) == pytest.approx(sigma, rel=0.03)


def test_fifo_overflow_gives_gap_with_exact_count(tmp_path):
    # a 1 s stall of the bus: 200 samples arrive while the 73-frame FIFO is not read
    cfg = config(DEVICES[:1], faults={"mpu9150": [{"kind": "stall", "at_s": 30.0, "duration_s": 1.0}]})
    out = tmp_path / "stall.h5"
    capture(cfg, out, DURATION_S, simulate=True)
    with open_run(out) as run:
        events = run.events()
        n = run.devices["mpu9150"].n
        span = slots(run, "mpu9150")
    assert [e.kind for e in events] == ["overrun"]
    # the poll that stalled came one poll interval (29 periods) after the previous one:
    # 29 + 200 samples were produced and none of them survived the FIFO reset
    assert events[0].lost == 29 + 200
    assert n + events[0].lost == span


def test_chip_reset_gives_fault_reconnect_gap(tmp_path):
    faults = {
        "mpu6500": [{"kind": "reset", "at_s": 20.0}],
        "acc": [{"kind": "reset", "at_s": 40.0}, {"kind": "stuck_fifo", "at_s": 10.0, "duration_s": 2.0}],
        "mpu9150": [{"kind": "stuck_fifo", "at_s": 25.0, "duration_s": 2.0}],
    }
    out = tmp_path / "reset.h5"
    capture(config(faults=faults), out, DURATION_S, simulate=True)
    with open_run(out) as run:
        events = run.events()
        for name, kinds in (
            ("mpu6500", ["fault", "reconnect", "gap"]),
            ("acc", ["gap", "fault", "reconnect", "gap"]),
            ("mpu9150", ["gap"]),
        ):
            mine = [e for e in events if e.source == name]
            assert [e.kind for e in mine] == kinds, mine
            lost = sum(e.lost for e in mine)
            n = run.devices[name].n
            # a reset loses the samples of the re-initialisation; a stuck FIFO ~2 s
            assert lost > 0
            # stuck FIFO: its last samples are stamped at the next read, so up to one
            # poll interval of the loss is hidden in the time stamps
            poll = {"mpu6500": 14, "acc": 12, "mpu9150": 29}[name]
            assert slots(run, name) - poll - 2 <= n + lost <= slots(run, name) + 2
    stuck = [e for e in events if "stopped filling" in e.detail]
    assert {e.source for e in stuck} == {"acc", "mpu9150"}


def test_devices_command(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text(
        '[[device]]\nname = "imu"\ndriver = "mpu6500"\nbus = "i2c:1"\n'
        '[[device]]\nname = "acc"\ndriver = "bmx055_accel"\nbus = "i2c:1"\naddress = 0x19\n'
        '[[thermometer]]\nname = "ambient1"\ndriver = "mcp9804"\nbus = "i2c:1"\n'
        "[thermometer.sim]\ntemp_c = 19.5\ntemp_drift_c = 0.0\n"
    )
    res = CliRunner().invoke(cli, ["devices", str(p), "--simulate"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert lines[0].split()[:4] == ["device", "imu", "mpu6500", "i2c:1@0x68"] and "who_am_i=0x70" in lines[0]
    assert "acc" in lines[1] and "i2c:1@0x19" in lines[1] and "chip_id=0xFA" in lines[1]
    assert lines[2].split()[:4] == ["thermometer", "ambient1", "mcp9804", "i2c:1@0x18"]
    assert "manufacturer=0x0054 device=0x0201, 19.5000 degC" in lines[2]
    # without --simulate: no adapter here; every line carries the error, exit status 1
    p.write_text(p.read_text().replace("i2c:1", "i2c:99"))
    res = CliRunner().invoke(cli, ["devices", str(p)])
    assert res.exit_code == 1
    assert res.output.count("/dev/i2c-99 does not exist") == 3 and res.output.count("remedy:") == 3


def test_address_collision_is_a_config_error(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text(
        '[[device]]\nname = "acc"\ndriver = "bmx055_accel"\nbus = "i2c:1"\n'
        '[[thermometer]]\nname = "ambient1"\ndriver = "mcp9804"\nbus = "i2c:1"\n'
    )
    res = CliRunner().invoke(cli, ["devices", str(p), "--simulate"])
    assert res.exit_code == 1
    assert "thermometer ambient1.address: 0x18 on i2c:1 is already used by 'acc'" in res.output


def stress(stall_at_s):
    """A stall of the device's bus at ``stall_at_s``, a 5 s slow window, a burst of two NACKs."""
    return [
        {"kind": "stall", "at_s": stall_at_s, "duration_s": 1.0},
        {"kind": "slow", "at_s": 45.0, "duration_s": 5.0, "delay_s": 0.004},
        {"kind": "nack", "at_s": 52.0},
        {"kind": "nack", "at_s": 52.0},  # two in a row: within the bus's three tries
    ]


def test_every_i2c_driver_through_stalls_a_slow_bus_and_a_nack_burst(tmp_path):
    """Every I2C chip simulator, strict, with a stall per device, a slow-bus window and NACK bursts.

    The simulated clock is shared, so each device's stall holds every bus for 1 s: five
    overruns per FIFO device (four devices and the thermometer stall once each); the slow window
    (4 ms per transaction) and the NACK bursts lose nothing.
    """
    devices = [
        *DEVICES[:2],
        {"name": "gyro", "driver": "bmx055", "bus": "i2c:1", "address": 0x68},
        {"name": "acc", "driver": "bmx055_accel", "bus": "i2c:1", "address": 0x19, "read_mode": "fifo"},
    ]
    devices = [dict(d, sim={"faults": stress(10.0 * (i + 1))}) for i, d in enumerate(devices)]
    thermo = {"name": "amb", "driver": "mcp9804", "bus": "i2c:2", "address": 0x18, "sim": {"faults": stress(5.0)}}
    cfg = parse_config({"station": {"seed": 5}, "device": devices, "thermometer": [thermo]})
    out = tmp_path / "stress.h5"
    summary = capture(cfg, out, DURATION_S, simulate=True)
    assert summary.readings["amb"] == DURATION_S
    with open_run(out) as run:
        events = run.events()
        for dev in devices:
            name = dev["name"]
            mine = [e for e in events if e.source == name]
            assert [e.kind for e in mine] == ["overrun"] * 5, mine
            assert all(e.lost > 0 for e in mine)
            # every sample period is a sample written or a loss logged (the station measures
            # each overrun's loss from time; +-2 for the poll that straddles a stall)
            assert abs(run.devices[name].n + sum(e.lost for e in mine) - slots(run, name)) <= 2
            ch = run.devices[name].channels["temp"]
            temp = run.read(name, "temp").astype(float) * ch.scale + ch.offset
            assert np.all(np.abs(temp - 30.0) < 0.6)  # no shifted FIFO bytes were stored as frames
            if "accel" in run.devices[name].channels:
                a = run.read(name, "accel").astype(float) * run.devices[name].channels["accel"].scale
                assert np.all(np.abs(a[:, 2] - G0) < 0.1 * G0)


def test_a_nack_burst_longer_than_the_retries_is_one_fault(tmp_path):
    burst = [{"kind": "nack", "at_s": 20.0}] * 3  # three in a row: every try of one transaction
    cfg = config(DEVICES[1:2], faults={"mpu6500": burst})
    out = tmp_path / "nack.h5"
    capture(cfg, out, 30.0, simulate=True)
    with open_run(out) as run:
        events = run.events()
        assert [e.kind for e in events] == ["fault", "reconnect", "gap"]
        assert "no acknowledge" in events[0].detail
        n, lost = run.devices["mpu6500"].n, events[-1].lost
        assert slots(run, "mpu6500") - 14 - 2 <= n + lost <= slots(run, "mpu6500") + 2
