"""Data-ready counters: the ADIS16448's DIO1 wired to the CP2130's GPIO.4 event counter or the MCP2210's GP6
interrupt counter (docs/reference/bridge-counters.md, docs/capture.md), all on virtual clocks."""

from __future__ import annotations

import pytest

from imustation.acquisition.timeline import Timeline
from imustation.clock import VirtualClock
from imustation.drivers import adis16448 as adis
from imustation.drivers.bus import spi_cp2130 as cp
from imustation.drivers.bus import spi_mcp2210 as mcp
from imustation.drivers.bus.spi_open import open_spi
from imustation.drivers.sim.adis16448 import ADIS16448Sim
from imustation.drivers.sim.sources import NoiseSource
from imustation.drivers.sim.spi_bridges import CP2130Sim, MCP2210Sim
from imustation.drivers.sim.usb_backend import SimUSBBackend
from imustation.errors import DeviceError, SettingError
from imustation.runfile import open_run
from tests.test_holes import assert_the_file_accounts_for_every_sample, capture_lab, lab

PIN = {"cp2130": "gpio4", "mcp2210": "gp6"}


class Logged:
    """Record what the host sends a simulated bridge: control transfers and OUT reports."""

    def __init__(self, fn):
        self.controls: list[tuple[int, int, object]] = []
        self.outs: list[bytes] = []
        control, out = fn.control, fn.out

        def logged_control(rt, req, value, index, data):
            self.controls.append((rt, req, data if isinstance(data, int) else bytes(data)))
            return control(rt, req, value, index, data)

        def logged_out(ep, data):
            self.outs.append(bytes(data))
            return out(ep, data)

        fn.control, fn.out = logged_control, logged_out


def rig(scheme: str, *, wired: bool = True, url_rest: str = ""):
    clock = VirtualClock()
    chip = ADIS16448Sim(clock, lambda fs: NoiseSource.for_device("adis16448", "xyz", fs, {}, 3))
    fn = CP2130Sim("1") if scheme == "cp2130" else MCP2210Sim("1")
    fn.attach(0, chip)
    if wired:
        fn.wire_counter(PIN[scheme], chip.data_ready_edges)
    log = Logged(fn)
    spi = open_spi(f"{scheme}:{url_rest}", mode=adis.SPI_MODE, sleep=clock.sleep, backend=SimUSBBackend([fn]))
    return clock, chip, fn, log, spi


def test_the_packets_match_the_datasheets_layouts():
    # CP2130 (AN792 Set/Get_Event_Counter): mode byte (bit 7 overflow, bits 2:0 GPIO.4 mode), count big-endian
    assert cp.pack_event_counter(cp.EVTCNTR_RISING_EDGE, 0) == bytes([0x04, 0x00, 0x00])
    assert cp.pack_event_counter(cp.EVTCNTR_RISING_EDGE, 0x1234) == bytes([0x04, 0x12, 0x34])
    assert cp.unpack_event_counter(bytes([0x84, 0x12, 0x34])) == (True, 4, 0x1234)
    # MCP2210 (DS22288A §3.4.1, Tables 3-56/3-57): byte 1 0x00 reads then resets; count at bytes 4-5, low first
    assert mcp.interrupt_count_command(reset=True) == bytes([0x12, 0x00]) + bytes(62)
    assert mcp.interrupt_count_command(reset=False)[:2] == bytes([0x12, 0x01])
    assert mcp.interrupt_count(bytes([0x12, 0x00, 0, 0, 0x34, 0x12]) + bytes(58)) == 0x1234
    # chip settings (report bytes 4..18): GP6 (byte 10) dedicated, byte 17 bits 3:1 = 010 rising edges,
    # remote wake-up (bit 4) and SPI bus release (bit 0) kept
    settings = bytearray(mcp.CHIP_SETTINGS_LEN)
    settings[mcp.OTHER_SETTINGS_AT] = 0x11
    out = mcp.with_interrupt_counter(bytes(settings))
    assert out[6] == 0x02 and out[13] == 0x15 and out[:6] == bytes(6)


@pytest.mark.parametrize("scheme", ["cp2130", "mcp2210"])
def test_the_bridge_counts_the_chips_data_ready_pulses(scheme):
    clock, chip, fn, log, spi = rig(scheme)
    assert spi.start_event_counter(PIN[scheme]) == 1 << 16
    if scheme == "cp2130":
        assert (cp.REQTYPE_OUT, cp.REQ_SET_EVENT_COUNTER, bytes([0x04, 0, 0])) in log.controls
        assert (cp.REQTYPE_IN, cp.REQ_GET_EVENT_COUNTER, 3) in log.controls
    else:
        sets = [r for r in log.outs if r[0] == mcp.CMD_SET_CHIP_SETTINGS]
        # after the chip select's designation at open: GP6 dedicated, byte 17 bits 3:1 rising edges
        assert len(sets) == 2 and sets[-1][4 + 6] == 0x02 and sets[-1][17] >> 1 & 7 == 0b010
        assert log.outs[-1] == mcp.interrupt_count_command(reset=True)
    assert spi.read_event_counter() == 0
    period = 1.0 / chip.rate_hz
    clock.sleep(10.5 * period)
    assert spi.read_event_counter() == 10  # one pulse per sample made
    clock.sleep(65536 * period)
    assert spi.read_event_counter() == 10  # 16 bits: it wrapped
    # the chip's data-ready output switched off (MSC_CTRL bit 2): no pulses, none counted
    chip.spi_transfer(bytes([0x80 | adis.REG_MSC_CTRL, 0x00]), adis.SPI_MODE, 1e6)
    clock.sleep(20 * period)
    assert spi.read_event_counter() == 10


def test_a_pin_the_bridge_cannot_count_on_is_one_clear_error():
    _, _, _, _, spi = rig("cp2130", wired=False)
    with pytest.raises(SettingError, match="counts edges only on gpio4"):
        spi.start_event_counter("gp6")
    _, _, _, _, spi = rig("mcp2210", wired=False, url_rest="?cs=6")
    with pytest.raises(SettingError, match="GP6 is this chip's select"):
        spi.start_event_counter("gp6")
    _, _, fn, _, spi = rig("cp2130", wired=False)
    fn.gpio4_counter_input = False  # an OTP ROM that left GPIO.4 a plain GPIO
    with pytest.raises(DeviceError, match="OTP pin configuration"):
        spi.start_event_counter("gpio4")


def _poll(drv, clock, seconds, step_s, timeline, info, edges_at_reads):
    """Poll ``drv`` every ``step_s`` for ``seconds`` on the virtual clock, placing every block."""
    for _ in range(round(seconds / step_s)):
        clock.sleep(step_s)
        t = clock.now_ns()
        block = drv.read_block()
        edges_at_reads.append(block)
        timeline.place(block, t)


@pytest.mark.parametrize("scheme", ["cp2130", "mcp2210"])
def test_a_missed_sample_is_counted_exactly_from_the_counter(scheme):
    clock, chip, _, log, spi = rig(scheme)
    drv = adis.ADIS16448(spi, {"data_ready": PIN[scheme]}, sleep=clock.sleep)
    drv.clock_ns = clock.now_ns
    info = drv.open()
    assert info.has_counter and info.settings["counter_modulus"] == 1 << 16
    tl = Timeline(1e9 / info.rate_hz, info.settings["counter_modulus"], overflow=info.overflow, buffer_s=info.buffer_s)
    blocks: list = []
    period = 1.0 / info.rate_hz
    _poll(drv, clock, 0.5, period / 2, tl, info, blocks)
    assert tl.lost == 0
    before = chip.data_ready_edges()
    clock.sleep(7.3 * period - period / 2)  # the reader is held up: no poll for 7.3 periods
    _poll(drv, clock, period / 2, period / 2, tl, info, blocks)
    after = chip.data_ready_edges()  # at the read after the hold-up
    _poll(drv, clock, 0.5, period / 2, tl, info, blocks)
    blocks.append(drv.drain())
    tl.place(blocks[-1], clock.now_ns(), poll=False)
    counters = [int(c) for b in blocks if b.counter is not None for c in b.counter]
    assert counters == sorted(counters) and len(set(counters)) == len(counters)
    # the sample read after the hold-up is the newest: those made before it, since the last read, are lost
    assert tl.lost == after - before - 1 >= 6 and tl.gaps == 1
    assert tl.samples + tl.lost == counters[-1] - counters[0] + 1  # every pulse is a sample written or lost
    # polls that found the count unchanged read no burst: about one burst per sample, not one per poll
    polls = round(0.5 / (period / 2)) * 2
    assert chip.sim_bursts < 0.6 * polls


def test_without_the_wire_the_driver_reads_as_before():
    clock, chip, _, log, spi = rig("cp2130", wired=False)
    drv = adis.ADIS16448(spi, {}, sleep=clock.sleep)
    drv.clock_ns = clock.now_ns
    info = drv.open()
    assert not info.has_counter and "counter_modulus" not in info.settings and info.settings["data_ready"] == "none"
    blocks = []
    for _ in range(200):
        clock.sleep(0.5 / info.rate_hz)
        blocks.append(drv.read_block())
    assert all(b.counter is None for b in blocks) and sum(b.n for b in blocks) > 80
    assert not [c for c in log.controls if c[1] in (cp.REQ_GET_EVENT_COUNTER, cp.REQ_SET_EVENT_COUNTER)]
    assert chip.sim_bursts >= 200  # a burst at every poll, as before


def test_a_capture_with_the_wire_accounts_for_every_sample_by_the_counter(tmp_path, monkeypatch):
    """The lab on its virtual clock, the ADIS16448's DIO1 wired to the CP2130: a 2 s stall of another bus
    holds the one-thread station; the ADIS16448's loss is a counter jump, a bad CRC another, each counted
    once, and the file (with the count as the device counter) accounts for every sample."""
    raw = lab()
    adis_dev = next(d for d in raw["device"] if d["name"] == "adis")
    adis_dev["data_ready"] = "gpio4"
    adis_dev["sim"]["faults"] = [{"kind": "checksum", "at_s": 7.0}]
    path, produced = capture_lab(tmp_path, raw, 10.0, monkeypatch)
    checks = assert_the_file_accounts_for_every_sample(path)
    c = checks["adis"]
    assert c.samples + c.logged == produced["adis"]
    assert c.holes.samples == 819 + 1  # the stall (2 s at 409.6 Hz, less the sample read after it) and the CRC
    with open_run(path) as run:
        events = [e for e in run.events() if e.source == "adis" and e.kind == "gap"]
        assert len(events) == 2 and all(e.detail.startswith("counter jump") for e in events)
        assert "checksum" in events[1].detail
        assert run.devices["adis"].has_counter


def test_a_data_ready_pin_the_bus_cannot_count_on_is_a_config_error():
    from imustation.acquisition.config import parse_config
    from imustation.errors import ConfigError

    def cfg(bus, pin):
        device = {"name": "adis", "driver": "adis16448", "bus": bus, "data_ready": pin}
        return parse_config({"station": {}, "device": [device]})

    assert cfg("cp2130:?cs=0", "gpio4").devices[0].settings["data_ready"] == "gpio4"
    assert cfg("mcp2210:?cs=1", "gp6").devices[0].settings["data_ready"] == "gp6"
    with pytest.raises(ConfigError, match=r"device\[0\].data_ready.*'gp6' on a cp2130: bus: allowed \"gpio4\""):
        cfg("cp2130:?cs=0", "gp6")
    with pytest.raises(ConfigError, match=r"'gpio4' on a mcp2210: bus: allowed \"gp6\""):
        cfg("mcp2210:", "gpio4")
    with pytest.raises(ConfigError, match="data_ready = 'dio1'"):
        cfg("cp2130:", "dio1")
