"""Bus traces: a traced capture replays to the same file; a driver that asks otherwise is caught."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.acquisition import capture
from imustation.acquisition.config import parse_config
from imustation.cli import cli
from imustation.clock import VirtualClock
from imustation.drivers.bus.trace import Trace, TraceEnded, TraceMismatch
from imustation.errors import NackError
from imustation.runfile import open_run

LAB = {
    "station": {"seed": 4},
    "device": [
        {"name": "gyro", "driver": "bmx055", "bus": "i2c:1", "sim": {"faults": [{"kind": "nack", "every_s": 3}]}},
        {"name": "mpu", "driver": "mpu9150", "bus": "i2c:2", "rate_hz": 200, "bandwidth_hz": 42},
        {"name": "adis", "driver": "adis16448", "bus": "cp2130:"},
        {"name": "fog", "driver": "dsp3000", "bus": "serial:/dev/ttyUSB0"},
    ],
    "thermometer": [{"name": "amb", "driver": "mcp9804", "bus": "i2c:2", "address": 0x18}],
}


@pytest.fixture(scope="module")
def traced(tmp_path_factory):
    d = tmp_path_factory.mktemp("trace")
    cfg = parse_config(LAB)
    capture(cfg, d / "orig.h5", 20.0, simulate=True, trace=d / "bus.trace")
    return cfg, d


def _datasets(path):
    out = {}
    with open_run(path) as run:
        for dev in run.devices.values():
            for name in ("t", *dev.channels):
                out[f"{dev.name}/{name}"] = run.read(dev.name, name)
        for name in run.thermometers:
            out[f"thermo/{name}"] = run.temperatures(name)[1]
        out["events"] = [(e.t_ns, e.source, e.kind, e.lost) for e in run.events()]
    return out


def test_replay_reproduces_the_recorded_file(traced):
    cfg, d = traced
    capture(cfg, d / "replay.h5", 20.0, simulate=False, replay=d / "bus.trace")
    a, b = _datasets(d / "orig.h5"), _datasets(d / "replay.h5")
    assert a.keys() == b.keys()
    for key in a:
        if key == "events":
            assert a[key] == b[key]
        else:
            assert np.array_equal(a[key], b[key]), key
    assert len(a["gyro/gyro"]) == 8000 and len(a["adis/gyro"]) > 8000


def test_trace_records_faults_and_all_bus_kinds(traced):
    _, d = traced
    lines = [json.loads(x) for x in (d / "bus.trace").read_text().splitlines()]
    assert lines[0] == {"format": "imustation-trace", "version": 1}
    kinds = {rec["device"]: rec["kind"] for rec in lines if "device" in rec}
    assert kinds == {"gyro": "i2c", "mpu": "i2c", "adis": "spi", "fog": "serial", "amb": "i2c"}
    nacks = [r for r in lines if r.get("e", [""])[0] == "NackError"]
    assert nacks == []  # single NACKs are absorbed by the bus's retries below the trace
    assert any(r.get("m") == "transfer" for r in lines) and any(r.get("m") == "read_available" for r in lines)


def test_replay_catches_a_driver_that_asks_otherwise(traced):
    _, d = traced
    trace = Trace(d / "bus.trace")
    regs = trace.transport("gyro", "i2c", VirtualClock())
    with pytest.raises(TraceMismatch, match="driver asked read"):
        regs.read(0x00, 2)  # the driver's first call was a 1-byte CHIP_ID read


def test_replay_reraises_recorded_errors_and_ends(tmp_path):
    p = tmp_path / "t.trace"
    p.write_text(
        '{"format":"imustation-trace","version":1}\n'
        '{"device":"g","kind":"i2c","attrs":{"where":"i2c:1@0x68"}}\n'
        '{"d":"g","m":"read","a":[0,1],"e":["NackError","i2c:1@0x68 reg 0x00: no acknowledge"]}\n'
        '{"d":"g","m":"read","a":[0,1],"r":{"b":"0f"}}\n'
    )
    regs = Trace(p).transport("g", "i2c", VirtualClock())
    assert regs.where == "i2c:1@0x68"
    with pytest.raises(NackError):
        regs.read(0, 1)
    assert regs.read(0, 1) == b"\x0f"
    with pytest.raises(TraceEnded):
        regs.read(0, 1)


def test_cli_trace_and_replay(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[[device]]\nname="g"\ndriver="bmx055"\nbus="i2c:1"\n')
    r1 = CliRunner().invoke(
        cli,
        [
            "capture",
            str(cfg),
            "--simulate",
            "--duration",
            "5s",
            "-o",
            str(tmp_path / "a.h5"),
            "--trace",
            str(tmp_path / "a.trace"),
            "--quiet",
        ],
    )
    assert r1.exit_code == 0, r1.output
    r2 = CliRunner().invoke(
        cli,
        [
            "capture",
            str(cfg),
            "--duration",
            "5s",
            "-o",
            str(tmp_path / "b.h5"),
            "--replay",
            str(tmp_path / "a.trace"),
            "--quiet",
        ],
    )
    assert r2.exit_code == 0, r2.output
    with open_run(tmp_path / "a.h5") as a, open_run(tmp_path / "b.h5") as b:
        assert np.array_equal(a.read("g", "gyro"), b.read("g", "gyro"))
    bad = CliRunner().invoke(cli, ["capture", str(cfg), "--replay", str(cfg), "-o", str(tmp_path / "c.h5")])
    assert bad.exit_code == 2 and "not JSON" in bad.output
