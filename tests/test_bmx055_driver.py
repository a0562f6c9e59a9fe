"""BMX055 gyro driver against docs/reference/sensors.md §1 worked examples and its simulator."""

import errno

import numpy as np
import pytest

from imustation.clock import VirtualClock
from imustation.drivers import bmx055 as chip
from imustation.drivers.bmx055 import BMX055Gyro, decode_rates, decode_temperature
from imustation.drivers.bus.i2c import I2CBus
from imustation.drivers.sim.bmx055 import BMG160Sim
from imustation.drivers.sim.faults import FaultPlan, FaultSpec
from imustation.drivers.sim.i2c import SimSMBus
from imustation.drivers.sim.sources import NoiseSource
from imustation.errors import ChipIdMismatch, DeviceError, NackError, SettingError
from imustation.units import DEG2RAD


def test_worked_example_rate_bytes():
    # docs/reference/sensors.md §1.4: bytes "34 12" at range code 0 -> 284.146 deg/s (16.4 LSB/deg/s)
    counts = decode_rates(bytes.fromhex("3412F0FF0000"))[0]
    assert counts.tolist() == [4660, -16, 0]
    scale0 = chip.range_row(2000).scale
    assert counts[0] * scale0 / DEG2RAD == pytest.approx(284.146, abs=5e-4)
    assert counts[1] * scale0 / DEG2RAD == pytest.approx(-0.9756, abs=5e-5)


@pytest.mark.parametrize("raw,celsius", [(0x08, 27.0), (0xF6, 18.0), (0x00, 23.0)])
def test_worked_example_temperature(raw, celsius):
    assert decode_temperature(raw) == celsius


def test_bw_table_400hz_is_code_3():
    assert chip.odr_row(400, 47).code == 0x03


class ConstantSource:
    """3-axis constant rate in rad/s (for exact decode checks)."""

    def __init__(self, fs_hz, value):
        self.fs_hz = fs_hz
        self.value = np.asarray(value, dtype=float)

    def next(self, n):
        return np.tile(self.value, (n, 1))

    def temperature(self, t_s):
        return 27.0


def make(settings=None, source=None, address=0x68):
    clock = VirtualClock()
    sim = BMG160Sim(clock, source or (lambda fs: NoiseSource([chip_model()] * 3, fs, 1)))
    smbus = SimSMBus({address: sim})
    bus = I2CBus(smbus, "sim:test")
    drv = BMX055Gyro(bus.device(address), settings or {}, sleep=clock.sleep)
    return clock, sim, smbus, drv


def chip_model():
    from imustation.analysis.estimators.models.standard import StandardModel

    return StandardModel(1e-4, 1e-6, 500.0)


def test_open_configures_registers():
    clock, sim, smbus, drv = make({"rate_hz": 400, "bandwidth_hz": 47, "gyro_range_dps": 125})
    info = drv.open()
    assert sim.regs[0x10] == 0x80 | 0x03  # reserved bit set on read-back, §1.3
    assert sim.regs[0x0F] == 0x04
    assert sim.fifo_mode == chip.FIFO_MODE_STREAM
    assert sim.sim_resets == 1
    assert info.rate_hz == 400
    assert info.channels[0].scale == pytest.approx(DEG2RAD / 262.4)


def test_stream_decodes_constant_rate_exactly():
    value_counts = np.array([100, -200, 300])
    scale = chip.range_row(125).scale
    _, sim, _, drv = make(source=lambda fs: ConstantSource(fs, value_counts * scale))
    clock = sim.clock
    drv.open()
    clock.sleep(0.1)
    block = drv.read_block()
    assert block.n == 40  # 0.1 s at 400 Hz
    assert (block.channels["gyro"] == value_counts).all()
    assert (block.channels["temp"] == 8).all()  # 27 degC -> raw 8
    assert drv.read_rates().tolist() == value_counts.tolist()


def test_fifo_overrun_is_reported():
    _, sim, _, drv = make()
    drv.open()
    sim.clock.sleep(1.0)  # 400 frames into a 100-frame FIFO
    block = drv.read_block()
    assert block.n == 100
    assert block.lost == -1 and "overrun" in block.note
    sim.clock.sleep(0.05)
    again = drv.read_block()
    assert again.lost == 0 and again.n == 20


def test_reset_detected_even_with_the_power_on_range_and_bw():
    # 2000 Hz / 523 Hz and +-2000 deg/s are BW and RANGE code 0, their power-on values, and a reset
    # also leaves the FIFO in bypass: without a marker the chip would go silent, unnoticed
    clock = VirtualClock()
    plan = FaultPlan([FaultSpec("reset", at_s=1.0)], clock)
    sim = BMG160Sim(clock, lambda fs: ConstantSource(fs, (0.0, 0.0, 0.0)), plan)
    bus = I2CBus(SimSMBus({0x68: sim}), "sim:test")
    settings = {"rate_hz": 2000, "bandwidth_hz": 523, "gyro_range_dps": 2000}
    drv = BMX055Gyro(bus.device(0x68), settings, sleep=clock.sleep)
    info = drv.open()
    with pytest.raises(DeviceError, match="configuration lost"):
        for _ in range(50):
            clock.sleep(info.poll_interval_s)
            drv.read_block()
    assert clock.now_ns() < 1.2e9


def test_wrong_chip_id_is_a_clear_error():
    _, sim, _, drv = make()
    sim.regs[0x00] = 0x68  # some other chip
    sim.on_write = lambda reg, value: None  # a chip that ignores the reset too
    with pytest.raises(ChipIdMismatch, match=r"expected BMX055 gyro \(id 0x0F\), found id 0x68"):
        drv.open()


def test_missing_device_raises_nack_after_retries():
    _, _, smbus, drv = make(address=0x69)  # chip at 0x69, driver asks 0x68
    drv.regs = I2CBus(smbus, "sim:test").device(0x68)
    with pytest.raises(NackError, match="0x68"):
        drv.identify()


def test_transient_bus_error_is_retried():
    _, _, smbus, drv = make()
    failures = iter([OSError(errno.EIO, "glitch")])

    def fault(addr, msgs):
        err = next(failures, None)
        if err:
            raise err

    smbus.sim_fault = fault
    assert drv.identify() == 0x0F


def test_bad_settings_list_allowed_values():
    with pytest.raises(SettingError, match="rate/bandwidth pairs"):
        BMX055Gyro.check_settings({"rate_hz": 400, "bandwidth_hz": 12})
    with pytest.raises(SettingError, match="gyro_range_dps = 300"):
        BMX055Gyro.check_settings({"gyro_range_dps": 300})
    with pytest.raises(SettingError, match="not a setting"):
        BMX055Gyro.check_settings({"odr": 400})


# --- the simulator holds the chip to its data sheet (docs/reference/conformance-bmx055.md) ----------


def bare_gyro():
    clock = VirtualClock()
    sim = BMG160Sim(clock, lambda fs: ConstantSource(fs, (0.0, 0.0, 0.0)))

    def write(reg, *values):
        sim.i2c_write(bytes([reg, *values]))

    def read(reg, n):
        sim.i2c_write(bytes([reg]))
        return sim.i2c_read(n)

    return clock, sim, write, read


def test_sim_soft_reset_needs_30_ms_before_writes():
    clock, sim, write, read = bare_gyro()
    write(chip.REG_SOFTRESET, chip.SOFTRESET_CMD)
    write(chip.RANGE.reg, 3)
    assert read(chip.RANGE.reg, 1)[0] == 0 and sim.sim_ignored_writes == 1
    clock.sleep(0.030)
    write(chip.RANGE.reg, 3)
    assert read(chip.RANGE.reg, 1)[0] == 3


def test_sim_suspend_takes_only_lpm1_and_samples_nothing():
    clock, sim, write, read = bare_gyro()
    write(chip.FIFO_MODE.reg, chip.FIFO_MODE.encode(chip.FIFO_MODE_STREAM))
    write(chip.REG_LPM1, 0x80)  # suspend
    write(chip.RANGE.reg, 3)
    clock.sleep(0.5)
    assert read(chip.RANGE.reg, 1)[0] == 0 and read(chip.REG_FIFO_STATUS, 1)[0] == 0
    write(chip.REG_LPM1, chip.LPM1_NORMAL)
    clock.sleep(0.010)  # 2000 Hz power-on ODR: 20 frames
    assert read(chip.REG_FIFO_STATUS, 1)[0] == 20


@pytest.mark.parametrize("mode,frames,overrun", [(0, 0, False), (1, 100, True), (2, 100, True)])
def test_sim_fifo_modes(mode, frames, overrun):
    # bypass collects nothing; FIFO mode stops at 100 frames and flags the overrun; stream keeps the newest
    clock, sim, write, read = bare_gyro()
    write(chip.FIFO_MODE.reg, chip.FIFO_MODE.encode(mode))
    clock.sleep(0.1)  # 200 frames at 2000 Hz
    status = read(chip.REG_FIFO_STATUS, 1)[0]
    assert chip.FIFO_STATUS_COUNT.decode(status) == frames and bool(chip.FIFO_STATUS_OVERRUN.decode(status)) is overrun


def test_sim_read_only_registers():
    clock, sim, write, read = bare_gyro()
    for reg in (chip.REG_CHIP_ID, chip.REG_RATE_X_LSB, chip.REG_TEMP, 0x0A, chip.REG_FIFO_STATUS):
        write(reg, 0x55)
    assert read(chip.REG_CHIP_ID, 1)[0] == chip.CHIP_ID_VALUE and read(chip.REG_FIFO_STATUS, 1)[0] == 0
    write(chip.BW.reg, 0x03)
    assert read(chip.BW.reg, 1)[0] == 0x83  # bit 7 reads 1 whatever is written


def test_start_up_wait_after_normal_mode():
    # data sheet t_su 30 ms; Linux bmg160_core.c waits BMG160_MAX_STARTUP_TIME_MS = 80 ms after entering
    # normal mode (runtime resume): the driver waits 80 ms before its first FIFO read (before: 30 ms)
    clock, sim, smbus, drv = make()
    times = {}
    on_write, i2c_read = sim.on_write, sim.i2c_read

    def log_write(reg, value):
        if reg == chip.REG_LPM1 and value == chip.LPM1_NORMAL:
            times["normal"] = clock.now_ns()
        on_write(reg, value)

    def log_read(n):
        if sim.pointer in (chip.REG_TEMP, chip.REG_FIFO_DATA):  # the first poll after the wait
            times.setdefault("fifo", clock.now_ns())
        return i2c_read(n)

    sim.on_write, sim.i2c_read = log_write, log_read
    drv.open()
    assert times["fifo"] - times["normal"] >= 0.080e9
