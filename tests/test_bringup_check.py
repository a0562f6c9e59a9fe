"""``capture --check``: a short simulated capture judged GO or NO-GO, each failure named."""

from __future__ import annotations

from click.testing import CliRunner

from imustation.acquisition import load_config
from imustation.acquisition.bringup import judge, run_check
from imustation.cli import cli

RIG = """
[station]
name = "rig"
seed = 2

[[device]]
name = "gyro"
driver = "bmx055"
bus = "i2c:1"
gyro_range_dps = 125
{gyro_sim}

[[device]]
name = "acc"
driver = "bmx055_accel"
bus = "i2c:1"
address = 0x19
{acc_sim}

[[thermometer]]
name = "room"
driver = "mcp9804"
bus = "i2c:1"
"""


def rig(tmp_path, gyro_sim="", acc_sim=""):
    p = tmp_path / "rig.toml"
    p.write_text(RIG.format(gyro_sim=gyro_sim, acc_sim=acc_sim))
    return p


def readings(report, device):
    return {r.what: r for d in report.devices if d.name == device for r in d.readings}


def test_a_still_healthy_rig_is_go(tmp_path):
    report = run_check(load_config(rig(tmp_path)), 10.0, simulate=True, fsync=False)
    assert report.go and [d.name for d in report.devices] == ["gyro", "acc", "room"]
    gyro, acc = readings(report, "gyro"), readings(report, "acc")
    assert gyro["rate"].value.startswith("400.00 Hz of 400") and gyro["losses"].value.startswith("0 samples lost")
    assert {"gyro x bias", "gyro y bias", "gyro z bias", "temperature"} <= set(gyro)
    assert acc["gravity"].ok and acc["gravity"].value.startswith(("0.99", "1.00"))
    assert report.lines()[-1] == "GO"


def test_no_go_names_each_failure(tmp_path):
    """Half a g of gravity (a wrong scale), a bias of 8 % of full scale, a bus that drops out for 3 s."""
    gyro_sim = '[device.sim]\nb_on_dps = [10.0, 0.0, 0.0]\nfaults = [{kind = "disconnect", at_s = 3, duration_s = 3}]'
    acc_sim = "[device.sim]\ngravity_g = [0.0, 0.0, 0.5]"
    cfg = rig(tmp_path, gyro_sim, acc_sim)
    report = run_check(load_config(cfg), 10.0, simulate=True, fsync=False)
    assert not report.go
    gyro, acc = readings(report, "gyro"), readings(report, "acc")
    assert not gyro["gyro x bias"].ok and "8.00% of +-125" in gyro["gyro x bias"].value
    assert gyro["gyro y bias"].ok
    assert not gyro["losses"].ok and "1 faults" in gyro["losses"].value
    assert not acc["gravity"].ok and acc["gravity"].value.startswith("0.50")
    assert report.lines()[-1] == "NO-GO: gyro, acc"
    res = CliRunner().invoke(cli, ["capture", str(cfg), "--simulate", "--check", "10s", "--no-fsync"])
    assert res.exit_code == 1 and "NO-GO: gyro, acc" in res.output and "FAIL gravity" in res.output


def test_a_device_without_data_is_no_go(tmp_path):
    from imustation.channels import ChannelSpec
    from imustation.runfile import DeviceSpec, RunWriter

    path = tmp_path / "empty.h5"
    spec = DeviceSpec("g", "bmx055", "m", "i2c:1", "id", 400.0, {}, (ChannelSpec("gyro", "int16", "rad/s", 1e-3),))
    RunWriter(path, station="s", config_text="", simulated=True, devices=[spec], fsync=False).close()
    report = judge(str(path))
    assert not report.go and readings(report, "g")["samples"].why == "the device delivered no data"


def test_check_refuses_the_options_it_would_ignore(tmp_path):
    """``--check 30s -o x.h5`` kept no file and ``--duration 1h`` checked 30 s, silently: now one line, exit 2."""
    cfg = rig(tmp_path)
    ignored = (["-o", str(tmp_path / "x.h5")], ["--duration", "1h"], ["--real-time"], ["--resume", "--rotate", "1h"])
    for extra in ignored:
        res = CliRunner().invoke(cli, ["capture", str(cfg), "--simulate", "--check", "1s", "--no-fsync", *extra])
        assert res.exit_code == 2, (extra, res.output)
        named = res.output.split(":")[2]  # imustation: error: --check with A, B: ...
        assert all(opt in named for opt in extra if opt.startswith("-")) and "keeps no run" in res.output
    assert not (tmp_path / "x.h5").exists()
