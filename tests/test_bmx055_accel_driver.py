"""BMX055 accelerometer driver against docs/reference/sensors.md §1.5-§1.7 worked examples and its simulator."""

import numpy as np
import pytest
from simchips import ConstantSource, RampSource, new_clock, wire

from imustation.drivers import bmx055_accel as chip
from imustation.drivers.bmx055_accel import BMX055Accel, decode_accel, decode_temperature
from imustation.drivers.sim.bmx055_accel import BMA2x2Sim
from imustation.drivers.sim.faults import FaultPlan, FaultSpec
from imustation.errors import ChipIdMismatch, DeviceError, SettingError
from imustation.units import G0


@pytest.mark.parametrize(
    "data,count,g",
    [
        # docs/reference/sensors.md §1.7 worked examples at +-2 g
        ("0140", 1024, 1.000),
        ("F1FF", -1, -0.977e-3),
        ("0080", -2048, -2.000),
        ("F07F", 2047, 1.999),
    ],
)
def test_worked_examples_12bit(data, count, g):
    counts, new = decode_accel(bytes.fromhex(data * 3))
    assert counts.tolist() == [[count] * 3]
    scale = chip.range_row(2).scale
    assert counts[0, 0] * scale / G0 == pytest.approx(g, abs=5e-4)
    # new_data is bit 0 of the LSB: set in the first two examples, clear in the others
    assert new[0, 0] == bool(int(data[:2], 16) & 1)


@pytest.mark.parametrize("raw,celsius", [(0x08, 27.0), (0xF6, 18.0), (0x00, 23.0)])
def test_worked_example_temperature(raw, celsius):
    assert decode_temperature(raw) == celsius  # docs/reference/sensors.md §1.5


def test_tables():
    # §1.7: ODR = 1 / update time = 2 x bandwidth; Linux default 0x0B = 125 Hz
    assert chip.bw_row(125).code == 0x0B
    assert [r.odr_hz for r in chip.BW_TABLE] == [15.625, 31.25, 62.5, 125, 250, 500, 1000, 2000]
    # §1.7 scale: range * 2 / 4096 g per LSB (Linux 9577 um/s^2 at +-2 g)
    assert chip.range_row(2).scale == pytest.approx(9577e-6, rel=1e-4)
    assert chip.range_row(16).scale == pytest.approx(76614e-6, rel=1e-4)


def make(settings=None, value=(0.0, 0.0, G0), plan=None, source=None):
    clock = new_clock()
    sim = BMA2x2Sim(clock, source or (lambda fs: ConstantSource(fs, value)), plan)
    drv, smbus = wire(BMX055Accel, sim, settings)
    return clock, sim, drv


def test_open_configures_registers_and_reads_back():
    clock, sim, drv = make({"rate_hz": 500, "accel_range_g": 8})
    info = drv.open()
    assert sim.regs[0x0F] == 0x08 and sim.regs[0x10] == 0x0D
    assert sim.regs[0x17] == 0x10  # data_en: the configuration marker
    assert sim.fifo_mode == chip.FIFO_MODE_STREAM
    assert sim.sim_resets == 1
    assert info.rate_hz == 500 and info.settings["bandwidth_hz"] == 250
    assert info.channels[0].name == "accel" and info.channels[0].scale == pytest.approx(G0 / 256)
    assert info.poll_interval_s == pytest.approx(12 / 500)


@pytest.mark.parametrize("mode", ["fifo", "data_ready"])
def test_stream_decodes_constant_values_exactly(mode):
    counts = np.array([100, -200, 1000])
    scale = chip.range_row(4).scale
    clock, sim, drv = make({"accel_range_g": 4, "read_mode": mode}, value=counts * scale)
    info = drv.open()
    got = []
    for _ in range(50):
        clock.sleep(info.poll_interval_s)
        block = drv.read_block()
        assert block.lost == 0
        got.append(block.channels["accel"])
        assert (block.channels["temp"] == 8).all()  # 27 degC -> raw 8
    got = np.concatenate(got)
    # 50 polls of 12 or 0.5 periods at 125 Hz
    assert len(got) == round(50 * info.poll_interval_s * 125)
    assert (got == counts).all()


def test_fifo_keeps_every_sample_in_order():
    scale = chip.range_row(16).scale
    made = []
    clock, sim, drv = make(
        {"accel_range_g": 16, "rate_hz": 1000}, source=lambda fs: made.append(RampSource(fs, scale)) or made[-1]
    )
    info = drv.open()
    blocks = []
    for _ in range(30):
        clock.sleep(info.poll_interval_s)
        blocks.append(drv.read_block().channels["accel"][:, 0])
    x = np.concatenate(blocks)
    # contiguous, and ending with the newest sample the chip produced
    assert np.array_equal(x, np.arange(x[0], x[0] + len(x)))
    assert x[-1] == made[-1].i


def test_overrun_reported_and_cleared():
    clock, sim, drv = make()
    drv.open()
    clock.sleep(1.0)  # 125 frames into a 32-frame FIFO
    block = drv.read_block()
    assert block.n == 32 and block.lost == -1 and "overrun" in block.note
    clock.sleep(0.08)
    again = drv.read_block()
    assert again.lost == 0 and again.n == 10


def test_reset_detected_by_marker_even_with_por_range_and_bw():
    # +-2 g at 2000 Hz are the power-on PMU_RANGE/PMU_BW values: only the marker shows the reset
    clock = new_clock()
    plan = FaultPlan([FaultSpec("reset", at_s=1.0)], clock)
    sim = BMA2x2Sim(clock, lambda fs: ConstantSource(fs, (0, 0, G0)), plan)
    drv, _ = wire(BMX055Accel, sim, {"rate_hz": 2000, "accel_range_g": 2})
    drv.open()
    clock.sleep(0.005)
    drv.read_block()
    clock.sleep(1.0)
    with pytest.raises(DeviceError, match="configuration lost.*chip reset"):
        drv.read_block()
    drv.open()  # the station re-initialises
    clock.sleep(0.005)
    assert drv.read_block().n == 10


def test_stuck_fifo_reported_once_when_frames_return():
    clock = new_clock()
    plan = FaultPlan([FaultSpec("stuck_fifo", at_s=1.0, duration_s=0.5)], clock)
    sim = BMA2x2Sim(clock, lambda fs: ConstantSource(fs, (0, 0, G0)), plan)
    drv, _ = wire(BMX055Accel, sim)
    info = drv.open()
    notes = []
    while clock.now_ns() < 2e9:
        clock.sleep(info.poll_interval_s)
        block = drv.read_block()
        notes.append((block.n, block.lost))
    lost = [i for i, (_, lost) in enumerate(notes) if lost]
    assert len(lost) == 1 and notes[lost[0]][0] > 0
    assert notes[lost[0] - 1] == (0, 0)  # empty while stuck


def test_wrong_chip_and_bad_settings():
    clock, sim, drv = make()
    sim.regs[0x00] = 0x0F  # a gyro die at the accelerometer's address
    sim.on_write = lambda reg, value: None
    with pytest.raises(ChipIdMismatch, match=r"expected BMX055 accelerometer \(id 0xFA\), found id 0x0F"):
        drv.open()
    with pytest.raises(SettingError, match="rate/bandwidth pairs"):
        BMX055Accel.check_settings({"rate_hz": 125, "bandwidth_hz": 125})
    with pytest.raises(SettingError, match="rate_hz = 400"):
        BMX055Accel.check_settings({"rate_hz": 400})
    with pytest.raises(SettingError, match="read_mode = 'poll'"):
        BMX055Accel.check_settings({"read_mode": "poll"})
    assert BMX055Accel.check_settings({"rate_hz": 250})["bandwidth_hz"] == 125


# --- the simulator holds the chip to its data sheet (docs/reference/conformance-bmx055.md) ----------


def bare_accel():
    clock = new_clock()
    sim = BMA2x2Sim(clock, lambda fs: ConstantSource(fs, (0.0, 0.0, G0)))

    def write(reg, *values):
        sim.i2c_write(bytes([reg, *values]))

    def read(reg, n):
        sim.i2c_write(bytes([reg]))
        return sim.i2c_read(n)

    return clock, sim, write, read


def test_sim_soft_reset_needs_1_8_ms_before_writes():
    clock, sim, write, read = bare_accel()
    write(chip.REG_SOFTRESET, chip.SOFTRESET_CMD)
    write(chip.REG_PMU_RANGE, 0x05)
    assert read(chip.REG_PMU_RANGE, 1)[0] == 0x03 and sim.sim_ignored_writes == 1
    clock.sleep(0.0018)
    write(chip.REG_PMU_RANGE, 0x05)
    assert read(chip.REG_PMU_RANGE, 1)[0] == 0x05


def test_sim_deep_suspend_takes_only_pmu_lpw_and_samples_nothing():
    clock, sim, write, read = bare_accel()
    write(chip.FIFO_MODE.reg, chip.FIFO_MODE.encode(chip.FIFO_MODE_STREAM))
    write(chip.REG_PMU_LPW, 0x20)  # deep suspend
    write(chip.REG_PMU_RANGE, 0x05)
    clock.sleep(0.5)
    assert read(chip.REG_PMU_RANGE, 1)[0] == 0x03 and read(chip.REG_FIFO_STATUS, 1)[0] == 0
    write(chip.REG_PMU_LPW, chip.LPW_NORMAL)
    clock.sleep(0.005)  # power-on PMU_BW 0x0F: 2000 Hz, 10 frames
    assert read(chip.REG_FIFO_STATUS, 1)[0] == 10


def test_sim_read_only_registers():
    clock, sim, write, read = bare_accel()
    for reg in (chip.REG_CHIP_ID, chip.REG_ACCD_X_LSB, chip.REG_TEMP, 0x0A, chip.REG_FIFO_STATUS):
        write(reg, 0x55)
    assert read(chip.REG_CHIP_ID, 1)[0] == chip.CHIP_ID_VALUE and read(0x0A, 1)[0] == 0
