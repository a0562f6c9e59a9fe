"""MCP9804 thermometer: docs/reference/sensors.md §7 worked examples, pointer protocol, simulator, settings."""

import math

import pytest
from simchips import new_clock
from smbus2 import i2c_msg

from imustation.drivers.bus.i2c import I2CBus
from imustation.drivers.mcp9804 import MCP9804, decode_ta, encode_ta
from imustation.drivers.sim import make_thermometer_simulator
from imustation.drivers.sim.i2c import SimSMBus
from imustation.drivers.sim.mcp9804 import MCP9804Sim
from imustation.errors import DeviceError, SettingError


@pytest.mark.parametrize(
    "data,celsius,flags",
    [
        ("C190", 25.0, (True, True, False)),  # >= T_CRIT, > T_UPPER
        ("0194", 25.25, (False, False, False)),
        ("1FF0", -1.0, (False, False, False)),
        ("1E70", -25.0, (False, False, False)),
    ],
)
def test_worked_examples(data, celsius, flags):
    msb, lsb = bytes.fromhex(data)
    r = decode_ta(msb, lsb)
    assert r.celsius == celsius and (r.crit, r.upper, r.lower) == flags


def test_encode_is_the_inverse():
    for c in (25.0, 25.25, -1.0, -25.0, -0.0625, 124.9375, -40.0):
        assert decode_ta(*encode_ta(c)).celsius == c
    assert encode_ta(25.0, crit=True, upper=True) == bytes.fromhex("C190")


def sim_bus(temperature=lambda t: 22.0, address=0x18):
    clock = new_clock()
    sim = MCP9804Sim(clock, temperature)
    smbus = SimSMBus({address: sim})
    return clock, sim, smbus, I2CBus(smbus, "sim:test").device(address)


def test_id_registers_at_byte_level():
    # docs/reference/sensors.md §7: 0x06 -> 00 54, 0x07 -> 02 01, 0x08 -> single byte 03
    _, _, _, dev = sim_bus()
    assert dev.read(0x06, 2) == bytes.fromhex("0054")
    assert dev.read(0x07, 2) == bytes.fromhex("0201")
    assert dev.read(0x08, 1) == bytes.fromhex("03")


def test_pointer_persists_between_reads():
    clock, sim, smbus, dev = sim_bus()
    dev.read(0x06, 2)
    rd = i2c_msg.read(0x18, 2)
    smbus.i2c_rdwr(rd)  # a read without a pointer write reads the same register again
    assert bytes(rd) == bytes.fromhex("0054")


def test_open_and_read_default_resolution():
    clock, sim, _, dev = sim_bus(lambda t: 22.03)
    th = MCP9804(dev, {}, sleep=clock.sleep)
    assert th.open() == "manufacturer=0x0054 device=0x0201"
    # 22.03 truncated to 0.0625: 22.0; flags set against the 0 degC power-on limits
    r = th.read_reading()
    assert r.celsius == 22.0 and r.crit and r.upper and not r.lower


@pytest.mark.parametrize("res", [0.5, 0.25, 0.125, 0.0625])
def test_resolution_register_quantises(res):
    clock, sim, _, dev = sim_bus(lambda t: 21.8 + t * 0.01)
    th = MCP9804(dev, {"resolution_c": res}, sleep=clock.sleep)
    th.open()
    for _ in range(10):
        clock.sleep(1.0)
        c = th.read_celsius()
        assert c / res == int(c / res)
        truth = 21.8 + (clock.now_ns() / 1e9) * 0.01
        assert truth - res - 0.01 <= c <= truth  # truncation, one conversion old at most


def test_negative_temperatures():
    clock, sim, _, dev = sim_bus(lambda t: -10.3)
    th = MCP9804(dev, {}, sleep=clock.sleep)
    th.open()
    r = th.read_reading()
    assert r.celsius == math.floor(-10.3 / 0.0625) * 0.0625 == -10.3125
    assert r.lower and not r.upper and not r.crit


def test_shutdown_is_left_at_open():
    clock, sim, _, dev = sim_bus()
    dev.write(0x01, bytes([0x01, 0x00]))  # SHDN
    th = MCP9804(dev, {}, sleep=clock.sleep)
    th.open()
    assert sim.regs16[0x01] == 0
    assert th.read_celsius() == 22.0


def test_wrong_ids():
    clock, sim, _, dev = sim_bus()
    sim.regs16[0x06] = 0x001E  # another vendor's JC-42 part
    with pytest.raises(DeviceError, match="expected MCP9804.*manufacturer 0x001E"):
        MCP9804(dev, {}, sleep=clock.sleep).open()


def test_lost_resolution_is_detected():
    clock, sim, _, dev = sim_bus()
    th = MCP9804(dev, {"resolution_c": 0.25}, sleep=clock.sleep)
    th.open()
    sim._power_on()
    with pytest.raises(DeviceError, match="resolution register lost"):
        th.read_celsius()


def test_thermometer_simulator_defaults_and_keys():
    clock = new_clock()
    sim, plan = make_thermometer_simulator("mcp9804", clock, {}, {}, 1)
    assert plan is None
    dev = I2CBus(SimSMBus({0x18: sim}), "sim:").device(0x18)
    th = MCP9804(dev, {}, sleep=clock.sleep)
    th.open()
    readings = []
    for _ in range(3600):
        clock.sleep(1.0)
        readings.append(th.read_celsius())
    assert all(21.5 - 0.0625 <= c <= 22.5 for c in readings)  # 22.0 +- 0.5 drift
    assert len(set(readings)) > 3  # it drifts
    with pytest.raises(SettingError, match="sim.sigma_w: not a thermometer sim key"):
        make_thermometer_simulator("mcp9804", clock, {}, {"sigma_w": 1e-4}, 1)


@pytest.mark.parametrize(
    "settings,needle",
    [
        ({"rate_hz": 5}, "rate_hz = 5"),
        ({"rate_hz": 0}, "rate_hz = 0"),
        ({"resolution_c": 0.1}, "resolution_c = 0.1"),
        ({"rate": 1}, "not a setting"),
    ],
)
def test_bad_settings(settings, needle):
    with pytest.raises(SettingError, match=needle):
        MCP9804.check_settings(settings)


def test_default_settings():
    assert MCP9804.check_settings({}) == {"rate_hz": 1.0, "resolution_c": 0.0625}


# --- the simulator holds the chip to its data sheet (docs/reference/conformance-mcp9804.md) ----------


def test_sim_read_only_registers():
    _, sim, _, dev = sim_bus()
    for ptr in (0x00, 0x05, 0x06, 0x07):
        dev.write(ptr, bytes.fromhex("1234"))
    assert dev.read(0x00, 2) == bytes.fromhex("001F") and dev.read(0x06, 2) == bytes.fromhex("0054")
    assert dev.read(0x07, 2) == bytes.fromhex("0201") and dev.read(0x05, 2) != bytes.fromhex("1234")


def test_sim_lock_bits_freeze_the_limits_until_a_reset():
    # DS22203C Register 5-2: Crit. Lock / Win. Lock stay set until a reset; SHDN cannot be set while locked
    _, sim, _, dev = sim_bus()
    dev.write(0x04, bytes.fromhex("0190"))  # T_CRIT 25 degC
    dev.write(0x01, bytes.fromhex("00C0"))  # both locks
    dev.write(0x04, bytes.fromhex("0200"))
    dev.write(0x02, bytes.fromhex("0200"))
    dev.write(0x01, bytes.fromhex("0100"))  # try to clear the locks and shut down
    assert dev.read(0x04, 2) == bytes.fromhex("0190") and dev.read(0x02, 2) == bytes.fromhex("0000")
    assert dev.read(0x01, 2) == bytes.fromhex("00C0")
    sim._power_on()
    dev.write(0x04, bytes.fromhex("0200"))
    assert dev.read(0x04, 2) == bytes.fromhex("0200")
