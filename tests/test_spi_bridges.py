"""USB-to-SPI bridges: URL grammar, CP2130/MCP2210 framing (docs/reference/sensors.md §4.7), pyusb errors."""

import pytest

from imustation.clock import VirtualClock
from imustation.drivers.bus.spi_open import open_spi
from imustation.drivers.bus.url import parse_bus_url, parse_usb_target
from imustation.drivers.sim.faults import FaultPlan, FaultSpec
from imustation.drivers.sim.spi_bridges import CP2130Sim, MCP2210Sim
from imustation.drivers.sim.usb_backend import SimUSBBackend
from imustation.errors import BusClosed, BusTimeout, InputError


class Echo:
    """SPI target answering each byte + 1, recording transactions."""

    def __init__(self):
        self.seen = []

    def spi_transfer(self, tx, mode, hz):
        self.seen.append((bytes(tx), mode, hz))
        return bytes((b + 1) & 0xFF for b in tx)


class Recording:
    """Wrap a simulated bridge function and record what the host sends."""

    def __init__(self, fn):
        self.fn, self.controls, self.outs = fn, [], []
        orig_control, orig_out = fn.control, fn.out

        def control(rt, req, value, index, data):
            self.controls.append((rt, req, bytes(data) if not isinstance(data, int) else data))
            return orig_control(rt, req, value, index, data)

        def out(ep, data):
            self.outs.append((ep, bytes(data)))
            return orig_out(ep, data)

        fn.control, fn.out = control, out


def bridge(scheme, url_rest="", plan=None, serial="0001"):
    clock = VirtualClock()
    fn = CP2130Sim(serial, plan) if scheme == "cp2130" else MCP2210Sim(serial, plan)
    target = Echo()
    fn.attach(0, target)
    rec = Recording(fn)
    spi = open_spi(f"{scheme}:{url_rest}", mode=3, sleep=clock.sleep, backend=SimUSBBackend([fn]))
    return spi, target, rec, fn


def test_url_grammar():
    u = parse_bus_url("cp2130:10C4:87A0/00ABC?cs=2&hz=500000")
    t = parse_usb_target(u, 0x10C4, 0x87A0)
    assert (t.vid, t.pid, t.serial) == (0x10C4, 0x87A0, "00ABC")
    assert u.int_param("cs", 0, 0, 10) == 2 and u.int_param("hz", 0, 1, 12_000_000) == 500000
    assert parse_usb_target(parse_bus_url("mcp2210:"), 0x04D8, 0x00DE).vid == 0x04D8
    assert parse_usb_target(parse_bus_url("mcp2210:/X1"), 0x04D8, 0x00DE).serial == "X1"
    with pytest.raises(InputError, match="VID:PID"):
        parse_usb_target(parse_bus_url("cp2130:10C4"), 0x10C4, 0x87A0)
    with pytest.raises(InputError, match="cs=11 outside 0..10"):
        open_spi("cp2130:?cs=11", mode=3)
    with pytest.raises(InputError, match="unknown parameter 'speed'"):
        open_spi("cp2130:?speed=1", mode=3)


def test_cp2130_framing_matches_sensors_md():
    # docs/reference/sensors.md §4.7 example: channel 0, mode 3, CS push-pull, 1.5 MHz
    spi, target, rec, _ = bridge("cp2130", "?hz=1500000")
    assert spi.transfer(bytes([0x56, 0x00])) == bytes([0x57, 0x01])
    assert (0x40, 0x31, bytes([0x00, 0x3B])) in rec.controls
    assert (0x40, 0x25, bytes([0x00, 0x02])) in rec.controls
    assert rec.outs[-1] == (0x01, bytes.fromhex("00 00 02 00 02 00 00 00 56 00"))
    assert target.seen[-1] == (bytes([0x56, 0x00]), 3, 1.5e6)
    assert spi.hz == 1.5e6


@pytest.mark.parametrize("scheme", ["cp2130", "mcp2210"])
def test_data_transfers_hand_pyusb_arrays(scheme, monkeypatch):
    # pyusb takes array('B') as is and converts anything else through a caught
    # exception per call; the bridges' per-sample path must not pay for that
    import array

    import usb.core

    spi, target, _, _ = bridge(scheme)
    spi.ensure_open()
    seen = []
    write, read = usb.core.Device.write, usb.core.Device.read

    def checked_write(dev, ep, data, timeout=None):
        seen.append(("out", type(data)))
        return write(dev, ep, data, timeout)

    def checked_read(dev, ep, size_or_buffer, timeout=None):
        seen.append(("in", type(size_or_buffer)))
        return read(dev, ep, size_or_buffer, timeout)

    monkeypatch.setattr(usb.core.Device, "write", checked_write)
    monkeypatch.setattr(usb.core.Device, "read", checked_read)
    for n in (2, 26, 2):
        assert spi.transfer(bytes(range(n))) == bytes(range(1, n + 1))
    assert seen and all(kind is array.array for _, kind in seen)
    assert {d for d, _ in seen} == {"out", "in"}


def test_cp2130_clock_is_fastest_not_above_request():
    spi, target, _, _ = bridge("cp2130", "?hz=1000000")
    spi.transfer(b"\0\0")
    assert spi.hz == 750e3 and target.seen[-1][2] == 750e3


def test_mcp2210_framing():
    spi, target, rec, fn = bridge("mcp2210")
    tx = bytes(range(40, 68))  # 28 bytes: one transaction
    assert spi.transfer(tx) == bytes(b + 1 for b in tx)
    assert target.seen == [(tx, 3, 1e6)]
    reports = [d for _, d in rec.outs]
    assert all(len(r) == 64 for r in reports)
    settings = next(r for r in reports if r[0] == 0x40)
    # bit rate 1e6 LE, ..., bytes per transaction 28, mode 3 (field layout of docs/reference/sensors.md §4.7)
    assert settings[4:8] == bytes.fromhex("40 42 0F 00") and settings[18:20] == bytes([28, 0]) and settings[20] == 3
    assert settings[10] & 1 == 0 and settings[8] & 1 == 1  # GP0 active low, idle high
    chip_settings = next(r for r in reports if r[0] == 0x21)
    assert chip_settings[4] == 0x01  # GP0 designated chip select
    assert not fn.kernel_driver  # the HID driver was detached
    transfer = next(r for r in reports if r[0] == 0x42)
    assert transfer[:4] == bytes([0x42, 28, 0, 0]) and transfer[4:32] == tx
    # a second transfer of the same size does not resend the SPI settings
    n = sum(r[0] == 0x40 for r in reports)
    spi.transfer(tx)
    assert sum(d[0] == 0x40 for _, d in rec.outs) == n


def test_mcp2210_long_transfer_is_chunked():
    spi, target, _, _ = bridge("mcp2210")
    tx = bytes(i & 0xFF for i in range(150))
    assert spi.transfer(tx) == bytes((b + 1) & 0xFF for b in tx)
    assert target.seen[-1][0] == tx


@pytest.mark.parametrize("scheme", ["cp2130", "mcp2210"])
def test_device_selection_and_errors(scheme):
    spi, _, _, _ = bridge(scheme, "/0042", serial="0042")
    spi.transfer(b"\0\0")
    spi2, _, _, _ = bridge(scheme, "/9999", serial="0042")
    with pytest.raises(BusClosed, match="no .* with serial '9999' \\(found: 0042\\)"):
        spi2.transfer(b"\0\0")
    empty = open_spi(f"{scheme}:", mode=3, backend=SimUSBBackend([]))
    with pytest.raises(BusClosed) as err:
        empty.ensure_open()
    assert "\n" not in str(err.value) and "no " in str(err.value)


@pytest.mark.parametrize("scheme", ["cp2130", "mcp2210"])
def test_timeout_is_retried_then_disconnect_is_typed(scheme):
    clock = VirtualClock()
    plan = FaultPlan([FaultSpec("nack", at_s=1.0), FaultSpec("disconnect", at_s=5.0, duration_s=2.0)], clock)
    fn = CP2130Sim("1", plan) if scheme == "cp2130" else MCP2210Sim("1", plan)
    fn.attach(0, Echo())
    spi = open_spi(f"{scheme}:", mode=3, sleep=clock.sleep, backend=SimUSBBackend([fn]))
    spi.transfer(b"\1\2")
    clock.sleep(2.0)
    assert spi.transfer(b"\1\2") == b"\2\3" and spi.retried == 1
    clock.sleep(3.5)
    with pytest.raises(BusClosed, match="gone during SPI transfer"):
        spi.transfer(b"\1\2")
    with pytest.raises(BusClosed):
        spi.ensure_open()  # still unplugged: not enumerated
    clock.sleep(2.0)
    assert spi.transfer(b"\1\2") == b"\2\3"  # re-plugged: found and set up again


def test_persistent_timeout_gives_bus_timeout():
    import usb.core

    clock = VirtualClock()
    fn = CP2130Sim("1")
    fn.attach(0, Echo())
    spi = open_spi("cp2130:", mode=3, sleep=clock.sleep, backend=SimUSBBackend([fn]))
    spi.ensure_open()

    def never(ep, data):
        raise usb.core.USBTimeoutError("Operation timed out", -7, 110)

    fn.out = never
    with pytest.raises(BusTimeout, match="timeout during SPI transfer of 2 bytes \\(3 tries\\)"):
        spi.transfer(b"\0\0")
