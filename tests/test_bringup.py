"""Bring-up diagnosis (``imustation devices``): every failure with its cause and remedy, on fake /dev and /sys."""

from __future__ import annotations

import os

import pytest
from click.testing import CliRunner

from imustation.acquisition import load_config
from imustation.acquisition.doctor import check_station
from imustation.acquisition.hostview import HostView
from imustation.cli import cli
from imustation.clock import VirtualClock


def write(path, text=""):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def config(tmp_path, body):
    p = tmp_path / "c.toml"
    p.write_text('[station]\nname = "lab"\n' + body)
    return load_config(p)


I2C = '[[device]]\nname = "gyro"\ndriver = "bmx055"\nbus = "i2c:1"\n'
CP2130 = '[[device]]\nname = "adis"\ndriver = "adis16448"\nbus = "cp2130:?cs=0&hz=1000000"\n'
MTI = '[[device]]\nname = "mti"\ndriver = "mti"\nbus = "serial:/dev/ttyUSB1?baud=921600"\nrate_hz = 400\n'


def view(root, denied=(), groups=None):
    """A host under ``root``; ``denied``: nodes this user may not open; ``groups``: node -> owning group."""
    groups = groups or {}
    return HostView(
        dev_root=str(root / "dev"),
        sys_root=str(root / "sys"),
        access=lambda p: os.path.relpath(p, root) not in denied,
        group_of=lambda p: groups.get(os.path.relpath(p, root), "root"),
        user="op",
    )


def diagnose(tmp_path, body, host):
    (finding,) = check_station(config(tmp_path, body), simulate=False, clock=VirtualClock(), view=host)
    assert not finding.ok
    return finding


def test_i2c_node_missing_module_not_loaded(tmp_path):
    (tmp_path / "sys" / "module").mkdir(parents=True)
    f = diagnose(tmp_path, I2C, view(tmp_path))
    assert "i2c-dev is not loaded" in f.cause and "modprobe i2c-dev" in f.remedy
    assert "/etc/modules-load.d" in f.remedy


def test_i2c_bus_not_enabled_lists_the_adapters(tmp_path):
    (tmp_path / "sys" / "module" / "i2c_dev").mkdir(parents=True)
    write(tmp_path / "sys" / "class" / "i2c-adapter" / "i2c-20" / "name", "fef04500.i2c\n")
    f = diagnose(tmp_path, I2C, view(tmp_path))
    assert "no I2C adapter 1" in f.cause and "i2c-20 (fef04500.i2c)" in f.cause
    assert "raspi-config nonint do_i2c 0" in f.remedy and "dtparam=i2c_arm=on" in f.remedy


def test_i2c_permission_names_the_group(tmp_path):
    write(tmp_path / "dev" / "i2c-1")
    f = diagnose(tmp_path, I2C, view(tmp_path, denied={"dev/i2c-1"}, groups={"dev/i2c-1": "i2c"}))
    assert "permission denied on /dev/i2c-1 (group i2c" in f.cause
    assert "sudo usermod -aG i2c op" in f.remedy
    # a node only root may open: the udev rules first
    f = diagnose(tmp_path, I2C, view(tmp_path, denied={"dev/i2c-1"}))
    assert "imustation setup udev" in f.remedy and "usermod -aG i2c op" in f.remedy


def usb(root, port, vid, pid, busnum, devnum, product=""):
    d = root / "sys" / "bus" / "usb" / "devices" / port
    for key, value in dict(idVendor=vid, idProduct=pid, busnum=busnum, devnum=devnum, product=product).items():
        write(d / key, f"{value}\n")


def test_usb_bridge_absent_lists_the_usb_devices(tmp_path):
    usb(tmp_path, "usb1", "1d6b", "0002", 1, 1, "xHCI Host Controller")
    usb(tmp_path, "1-1", "0403", "6001", 1, 4, "FT232R USB UART")
    write(tmp_path / "sys" / "bus" / "usb" / "devices" / "1-1:1.0" / "bInterfaceClass", "ff\n")  # an interface
    f = diagnose(tmp_path, CP2130, view(tmp_path))
    assert "no CP2130 with 10C4:87A0 on USB" in f.cause
    assert "1D6B:0002 xHCI Host Controller" in f.cause and "0403:6001 FT232R USB UART" in f.cause


def test_usb_bridge_without_permission_needs_the_udev_rule(tmp_path):
    usb(tmp_path, "1-2", "10c4", "87a0", 1, 5, "CP2130 USB-to-SPI Bridge")
    write(tmp_path / "dev" / "bus" / "usb" / "001" / "005")
    f = diagnose(tmp_path, CP2130, view(tmp_path, denied={"dev/bus/usb/001/005"}))
    assert "permission denied on /dev/bus/usb/001/005" in f.cause and "imustation setup udev" in f.remedy


def test_serial_port_absent_lists_by_id(tmp_path):
    by_id = tmp_path / "dev" / "serial" / "by-id"
    by_id.mkdir(parents=True)
    write(tmp_path / "dev" / "ttyUSB3")
    os.symlink("../../ttyUSB3", by_id / "usb-Xsens_MTi-100_03880001-if00-port0")
    f = diagnose(tmp_path, MTI, view(tmp_path))
    assert "serial port /dev/ttyUSB1 does not exist" in f.cause
    assert "/dev/serial/by-id/usb-Xsens_MTi-100_03880001-if00-port0 -> /dev/ttyUSB3" in f.cause
    assert "by-id" in f.remedy
    # the port there, owned by dialout: join the group
    write(tmp_path / "dev" / "ttyUSB1")
    f = diagnose(tmp_path, MTI, view(tmp_path, denied={"dev/ttyUSB1"}, groups={"dev/ttyUSB1": "dialout"}))
    assert "sudo usermod -aG dialout op" in f.remedy


@pytest.mark.parametrize(("driver", "configured", "answers"), [("dsp3000", 115200, 38400), ("mti", 921600, 115200)])
def test_baud_mismatch_names_the_rate_the_device_answers_at(tmp_path, driver, configured, answers, monkeypatch):
    """Simulated serial devices at a fixed line rate: the probe finds it."""
    if driver == "mti":  # the MTi simulator follows the port; fix it at its factory rate as a real unit is
        from imustation.drivers.sim.xsens_mti import MTiSim

        monkeypatch.setattr(MTiSim, "baud", answers, raising=False)
    body = f'[[device]]\nname = "d"\ndriver = "{driver}"\nbus = "serial:/dev/ttyUSB0?baud={configured}"\n'
    (f,) = check_station(config(tmp_path, body), simulate=True, clock=VirtualClock())
    assert not f.ok
    assert f"no valid answer at {configured} baud; the device answers at {answers} baud" in f.cause
    assert f"?baud={answers}" in f.remedy


def test_devices_cli_exit_status_and_remedies(tmp_path):
    (tmp_path / "sys" / "module").mkdir(parents=True)
    p = tmp_path / "c.toml"
    p.write_text(I2C + CP2130 + MTI)
    res = CliRunner().invoke(cli, ["devices", str(p), "--host-root", str(tmp_path)])
    assert res.exit_code == 1
    assert res.output.count("remedy:") == 3 and "3 of 3 did not answer" in res.output
    assert "host clock:" in res.output
    res = CliRunner().invoke(cli, ["devices", str(p), "--simulate"])
    assert res.exit_code == 0, res.output


def test_nack_on_a_simulated_bus_names_wiring_and_strap(tmp_path):
    body = I2C + '  [device.sim]\n  faults = [{kind = "disconnect", at_s = 0, duration_s = 100}]\n'
    (f,) = check_station(config(tmp_path, body), simulate=True, clock=VirtualClock())
    assert not f.ok and f.cause == "nothing answers at i2c:1@0x68"
    assert "pull-ups" in f.remedy and "address strap" in f.remedy and "i2cdetect -y 1" in f.remedy


def test_a_refused_setting_is_not_taken_for_a_baud_mismatch(tmp_path):
    """400 Hz MTi output does not fit 115200 baud: a setting to change, not a line rate to probe."""
    body = '[[device]]\nname = "mti"\ndriver = "mti"\nbus = "serial:/dev/ttyUSB0?baud=115200"\nrate_hz = 400\n'
    (f,) = check_station(config(tmp_path, body), simulate=True, clock=VirtualClock())
    assert not f.ok and f.cause == "a setting the device refuses" and "rate_hz = 200 or less" in f.detail


def test_devices_columns_line_up_with_long_bus_urls():
    """The lab's serial and SPI bus URLs (31 characters) pushed their identity out of the column."""
    from imustation.configs import config_path

    res = CliRunner().invoke(cli, ["devices", config_path("lab-example.toml"), "--simulate"])
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith(("device", "thermometer"))]
    keys = ("chip_id", "chip_id", "who_am_i", "who_am_i", "prod_id", "device_id", "no identity", *["manufacturer"] * 3)
    assert len(lines) == len(keys), res.output
    assert len({ln.index(key) for ln, key in zip(lines, keys, strict=True)}) == 1, res.output
