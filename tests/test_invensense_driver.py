"""MPU-9150 / MPU-6500 drivers against docs/reference/sensors.md §2.4/§3 worked examples and the FIFO simulator."""

import numpy as np
import pytest
from simchips import ConstantSource, RampSource, new_clock, wire

from imustation.drivers import invensense as chip
from imustation.drivers.invensense import MPU6500, MPU9150, MPU6500Driver, MPU9150Driver, decode_frames
from imustation.drivers.sim.faults import FaultPlan, FaultSpec
from imustation.drivers.sim.invensense import InvenSenseSim
from imustation.errors import ChipIdMismatch, DeviceError, SettingError
from imustation.units import DEG2RAD, G0

DRIVER = {"mpu9150": MPU9150Driver, "mpu6500": MPU6500Driver}


def test_worked_examples_data_registers():
    # docs/reference/sensors.md §2.4: accel "40 00" -> 1 g (+-2 g); temp "F2 70" -> 26.32 degC;
    # gyro "FF 7E" -> -0.992 deg/s
    frame = bytes.fromhex("4000 0000 0000 F270 FF7E 0000 0000")
    accel, temp, gyro = decode_frames(frame)
    assert accel[0].tolist() == [16384, 0, 0] and temp[0] == -3472 and gyro[0].tolist() == [-130, 0, 0]
    assert accel[0, 0] * chip.ACCEL_RANGES[0].scale / G0 == pytest.approx(1.000)
    assert gyro[0, 0] * chip.GYRO_RANGES[0].scale / DEG2RAD == pytest.approx(-0.992, abs=5e-4)
    assert chip.decode_temperature(int(temp[0]), MPU9150) == pytest.approx(26.32, abs=5e-3)


def test_worked_example_mpu6500_temperature():
    # docs/reference/sensors.md §3: TEMP "06 88" -> 1672 -> 1672/333.87 + 21 = 26.008 degC
    _, temp, _ = decode_frames(bytes(6) + bytes.fromhex("0688") + bytes(6))
    assert temp[0] == 1672
    assert chip.decode_temperature(1672, MPU6500) == pytest.approx(26.008, abs=5e-4)


@pytest.mark.parametrize(
    "rate,bw,div",
    [(1000, 42, 0), (200, 42, 4), (4, 42, 249), (8000, 256, 0), (1000, 256, 7), (1000 / 3, 98, 2)],
)
def test_rates_reachable(rate, bw, div):
    assert chip.sample_divider(MPU9150, rate, bw)[1] == div


@pytest.mark.parametrize("rate,bw", [(300, 42), (3, 42), (8000, 42), (2000, 98), (0.5, 5)])
def test_rates_unreachable_name_the_formula(rate, bw):
    with pytest.raises(SettingError, match=r"1000/\(1\+div\) Hz, div 0..255|8000/\(1\+div\) Hz, div 0..255"):
        MPU9150Driver.check_settings({"rate_hz": rate, "bandwidth_hz": bw})


def test_bandwidth_tables_differ_per_variant():
    with pytest.raises(SettingError, match="bandwidth_hz = 41"):
        MPU9150Driver.check_settings({"bandwidth_hz": 41})
    assert MPU6500Driver.check_settings({"bandwidth_hz": 41, "rate_hz": 500})["rate_hz"] == 500


def make(driver="mpu9150", settings=None, gyro=(0.01, -0.02, 0.03), accel=(0.0, 0.0, G0), plan=None, gyro_src=None,
         accel_src=None):  # fmt: skip
    clock = new_clock()
    variant = chip.VARIANTS[driver]
    sim = InvenSenseSim(
        variant,
        clock,
        gyro_src or (lambda fs: ConstantSource(fs, gyro, temp_c=30.0)),
        accel_src or (lambda fs: ConstantSource(fs, accel)),
        plan,
    )
    drv, smbus = wire(DRIVER[driver], sim, settings)
    return clock, sim, drv


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_open_wakes_and_configures(driver):
    clock, sim, drv = make(driver, {"rate_hz": 500, "gyro_range_dps": 1000, "accel_range_g": 8})
    info = drv.open()
    assert sim.sim_resets == 1
    assert sim.regs[0x6B] == 0x01  # awake, PLL with X gyro
    assert sim.regs[0x19] == 1  # 1000/(1+1) = 500 Hz
    assert sim.regs[0x1B] == 2 << 3 and sim.regs[0x1C] == 2 << 3
    assert sim.regs[0x23] == 0xF8 and sim.regs[0x6A] == 0x40
    if driver == "mpu6500":
        assert sim.regs[0x1D] == 0x03  # ACCEL_CONFIG2: A_DLPF_CFG = same code as DLPF_CFG (41 Hz)
    assert info.rate_hz == 500
    frames = chip.VARIANTS[driver].fifo_bytes // 14
    assert info.poll_interval_s == pytest.approx(int(0.4 * frames) / 500)
    assert [c.name for c in info.channels] == ["gyro", "accel", "temp"]


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_stream_decodes_constant_values_exactly(driver):
    gyro_counts, accel_counts = np.array([131, -262, 1]), np.array([-100, 200, 16384])
    clock, sim, drv = make(
        driver, gyro=gyro_counts * chip.GYRO_RANGES[0].scale, accel=accel_counts * chip.ACCEL_RANGES[0].scale
    )
    info = drv.open()
    n = 0
    for _ in range(40):
        clock.sleep(info.poll_interval_s)
        block = drv.read_block()
        assert block.lost == 0
        assert (block.channels["gyro"] == gyro_counts).all() and (block.channels["accel"] == accel_counts).all()
        temp = block.channels["temp"] * info.channels[2].scale + info.channels[2].offset
        assert np.allclose(temp, 30.0, atol=info.channels[2].scale)
        n += block.n
    assert n == round(40 * info.poll_interval_s * 200)


def test_sleeping_chip_makes_no_data():
    clock, sim, drv = make()
    assert sim.regs[0x6B] == 0x40  # MPU-9150 powers up asleep (§2.1)
    clock.sleep(1.0)
    assert sim.sim_produced == 0
    drv.open()
    produced = sim.sim_produced
    sim.on_write(0x6B, 0x41)  # back to sleep
    clock.sleep(1.0)
    sim.before_read(0x3B, 1)
    assert sim.sim_produced == produced


def test_overflow_resets_fifo_and_reports_unknown_loss():
    clock, sim, drv = make("mpu6500")
    info = drv.open()
    clock.sleep(1.0)  # 200 frames into 512 bytes
    sim.before_read(chip.REG_FIFO_COUNT_H, 2)
    assert len(sim.fifo) == 512 and sim.regs[0x72:0x74] == bytes([0x02, 0x00])
    block = drv.read_block()
    assert block.n == 0 and block.lost == -1 and "overrun" in block.note
    assert len(sim.fifo) == 0 and not sim.int_status & chip.INT_FIFO_OFLOW
    clock.sleep(info.poll_interval_s)
    again = drv.read_block()
    assert again.lost == 0 and again.n == 14


def test_overflow_by_count_alone():
    # FIFO_OFLOW_INT already read (cleared) elsewhere: a count at capacity still means overflow
    clock, sim, drv = make()
    drv.open()
    clock.sleep(1.0)
    sim.before_read(0x3A, 1)
    sim.int_status = 0
    assert drv.read_block().lost == -1


def test_partial_frame_waits_for_the_rest():
    clock, sim, drv = make(gyro_src=lambda fs: RampSource(fs, chip.GYRO_RANGES[0].scale))
    drv.open()
    clock.sleep(0.005)  # one sample at 200 Hz
    sim._advance()
    frame = bytes(sim.fifo)
    assert len(frame) == 14
    sim.fifo.clear()
    sim.fifo += frame + frame[:6]  # a second frame is being written
    first = drv.read_block()
    assert first.n == 1 and len(sim.fifo) == 6
    sim.fifo += frame[6:]
    second = drv.read_block()
    assert second.n == 1 and (second.channels["gyro"] == first.channels["gyro"]).all()


def test_empty_fifo_repeats_last_byte():
    clock, sim, drv = make()
    drv.open()
    clock.sleep(0.005)
    data = drv.regs.read(chip.REG_FIFO_R_W, 16)
    assert data[14:] == bytes([data[13]]) * 2  # §2.5: reading an empty FIFO returns the last byte again


def test_high_rate_holds_accel_at_1khz():
    clock, sim, drv = make(
        settings={"rate_hz": 8000, "bandwidth_hz": 256},
        accel_src=lambda fs: RampSource(fs, chip.ACCEL_RANGES[0].scale),
    )
    info = drv.open()
    clock.sleep(info.poll_interval_s)
    x = drv.read_block().channels["accel"][:, 0]
    assert len(x) == 29
    runs = np.diff(np.flatnonzero(np.diff(x)))
    assert (runs == 8).all() and (np.diff(np.unique(x)) == 1).all()


def test_reset_detected_then_reinitialised():
    clock = new_clock()
    plan = FaultPlan([FaultSpec("reset", at_s=2.0)], clock)
    sim = InvenSenseSim(MPU6500, clock, *[lambda fs: ConstantSource(fs, (0, 0, 0))] * 2, plan)
    drv, _ = wire(MPU6500Driver, sim)
    info = drv.open()
    with pytest.raises(DeviceError, match="configuration lost"):
        for _ in range(100):
            clock.sleep(info.poll_interval_s)
            drv.read_block()
    assert 2.0 <= clock.now_ns() / 1e9 <= 2.0 + 2 * info.poll_interval_s + 0.2
    assert sim.sim_resets == 2
    drv.open()
    clock.sleep(info.poll_interval_s)
    assert drv.read_block().n == 14


def test_stuck_fifo_reported_once():
    clock = new_clock()
    plan = FaultPlan([FaultSpec("stuck_fifo", at_s=1.0, duration_s=0.5)], clock)
    sim = InvenSenseSim(
        MPU9150, clock, lambda fs: ConstantSource(fs, (0, 0, 0)), lambda fs: ConstantSource(fs, (0, 0, G0)), plan
    )
    drv, _ = wire(MPU9150Driver, sim)
    info = drv.open()
    seen = []
    while clock.now_ns() < 2.5e9:
        clock.sleep(info.poll_interval_s)
        block = drv.read_block()
        seen.append((block.n, block.lost))
    assert sum(1 for _, lost in seen if lost) == 1
    assert (0, 0) in seen


def test_wrong_who_am_i():
    clock = new_clock()
    sim = InvenSenseSim(
        MPU6500, clock, lambda fs: ConstantSource(fs, (0, 0, 0)), lambda fs: ConstantSource(fs, (0, 0, 0))
    )
    drv, _ = wire(MPU9150Driver, sim)
    with pytest.raises(ChipIdMismatch, match=r"MPU-9150.*\(id 0x68\), found id 0x70"):
        drv.open()
