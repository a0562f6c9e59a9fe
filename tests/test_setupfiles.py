"""``imustation setup udev|service``: the files parse, say what they must, and pass the system's verifiers."""

from __future__ import annotations

import shutil
import subprocess

import pytest
from click.testing import CliRunner

from imustation.acquisition.setupfiles import parse_udev_rules, parse_unit
from imustation.cli import cli
from imustation.drivers.bus.spi_cp2130 import CP2130
from imustation.drivers.bus.spi_mcp2210 import MCP2210


def run(*args):
    res = CliRunner().invoke(cli, list(args))
    assert res.exit_code == 0, res.output
    return res.output


def test_udev_rules_parse_and_cover_every_bus():
    rules = parse_udev_rules(run("setup", "udev"))
    matches = [{(k, a): v for k, a, op, v in rule if op == "=="} for rule in rules]
    assigns = [{k: v for k, a, op, v in rule if op == "="} for rule in rules]
    i2c = [a for m, a in zip(matches, assigns, strict=True) if m.get(("SUBSYSTEM", "")) == "i2c-dev"]
    assert i2c == [{"GROUP": "i2c", "MODE": "0660"}]
    for bridge in (CP2130, MCP2210):
        ids = (f"{bridge.DEFAULT_VID:04x}", f"{bridge.DEFAULT_PID:04x}")
        usb = [
            a
            for m, a in zip(matches, assigns, strict=True)
            if m.get(("SUBSYSTEM", "")) == "usb" and (m.get(("ATTR", "idVendor")), m.get(("ATTR", "idProduct"))) == ids
        ]
        assert usb == [{"GROUP": "plugdev", "MODE": "0660"}], bridge.NAME
    tty = [m for m in matches if m.get(("SUBSYSTEM", "")) == "tty"]
    assert {m[("ATTRS", "idVendor")] for m in tty} == {"2639", "0403"}


@pytest.mark.parametrize(
    "bad",
    [
        'SUBSYSTEM=="usb", GROUP="plugdev" MODE="0660"',  # missing comma
        'SUBSYSTEM=="usb", GROUPS="plugdev"',  # no such key
        'GROUP="plugdev"',  # matches everything
        'SUBSYSTEM=="usb", MODE="rw"',
        'ATTRS=="x", GROUP="a"',
    ],
)
def test_udev_parser_refuses_malformed_rules(bad):
    with pytest.raises(ValueError):
        parse_udev_rules(bad)


def test_udev_rules_pass_udevadm_verify(tmp_path):
    if shutil.which("udevadm") is None:
        pytest.skip("udevadm not installed (the parser above checks the rules)")
    version = subprocess.run(["udevadm", "--version"], capture_output=True, text=True, check=False).stdout.strip()
    if not version.isdigit() or int(version) < 253:
        # Debian 12's udev (252, which the CI's chromium install brings) has no 'verify' verb yet
        pytest.skip(f"udevadm {version} has no 'verify' verb (systemd 253 added it); the parser above checks the rules")
    p = tmp_path / "70-imustation.rules"
    p.write_text(run("setup", "udev"))
    res = subprocess.run(["udevadm", "verify", str(p)], capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stdout + res.stderr


def unit_text(tmp_path):
    cfg = tmp_path / "lab.toml"
    cfg.write_text('[station]\nname = "lab-a"\n[[device]]\nname = "g"\ndriver = "bmx055"\nbus = "i2c:1"\n')
    return run("setup", "service", str(cfg), "-o", str(tmp_path / "night.h5"), "--user", "root", "--duration", "10h")


def test_service_unit_parses_and_grants_what_the_capture_needs(tmp_path):
    unit = parse_unit(unit_text(tmp_path))
    svc = unit["Service"]
    assert svc["KillSignal"] == "SIGTERM" and svc["KillMode"] == "mixed" and int(svc["TimeoutStopSec"]) >= 30
    assert svc["Restart"] == "on-failure"
    assert svc["LimitMEMLOCK"] == "infinity" and int(svc["LimitRTPRIO"]) > 0 and int(svc["Nice"]) < 0
    start = svc["ExecStart"].split()
    assert start[start.index("capture") + 1] == str(tmp_path / "lab.toml")
    assert "--resume" in start and start[start.index("-o") + 1] == str(tmp_path / "night.h5")
    assert start[start.index("--duration") + 1] == "10h" and "--rotate" in start
    assert unit["Install"]["WantedBy"] == "multi-user.target"
    with pytest.raises(ValueError, match="Nicety is not a \\[Service\\] directive"):
        parse_unit("[Service]\nNicety=3\n")


def test_service_unit_passes_systemd_analyze_verify(tmp_path):
    if shutil.which("systemd-analyze") is None:
        pytest.skip("systemd-analyze not installed (the parser above checks the unit)")
    p = tmp_path / "imustation-lab-a.service"
    p.write_text(unit_text(tmp_path))
    res = subprocess.run(["systemd-analyze", "verify", str(p)], capture_output=True, text=True, check=False)
    # verify only warns about unknown keys and bad values: any word about this file is a failure
    said = [line for line in (res.stdout + res.stderr).splitlines() if p.name in line]
    assert res.returncode == 0 and not said, res.stdout + res.stderr


def test_service_refuses_a_bad_duration(tmp_path):
    cfg = tmp_path / "lab.toml"
    cfg.write_text('[[device]]\nname = "g"\ndriver = "bmx055"\nbus = "i2c:1"\n')
    res = CliRunner().invoke(cli, ["setup", "service", str(cfg), "-o", "x.h5", "--duration", "soon"])
    assert res.exit_code == 2 and "soon" in res.output
