"""MPU-9150 / MPU-6500 drivers against docs/reference/sensors.md §2.4/§3 worked examples and the FIFO simulator."""

import numpy as np
import pytest
from simchips import ConstantSource, RampSource, new_clock, wire

from imustation.acquisition.config import load_config
from imustation.drivers import invensense as chip
from imustation.drivers.invensense import MPU6500, MPU9150, MPU6500Driver, MPU9150Driver, decode_frames
from imustation.drivers.sim.faults import FaultPlan, FaultSpec
from imustation.drivers.sim.invensense import InvenSenseSim
from imustation.errors import ChipIdMismatch, ConfigError, DeviceError, SettingError
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


@pytest.mark.parametrize("bw", [250, 3600])
def test_mpu6500_divider_does_not_apply_with_dlpf_cfg_0_or_7(bw):
    # RM-MPU-6500A Register 25: SMPLRT_DIV only effective for FCHOICE_B = 00 and 0 < DLPF_CFG < 7;
    # with DLPF_CFG 0 / 7 the chip runs at 8 kHz whatever the divider
    assert chip.sample_divider(MPU6500, 8000, bw)[1] == 0
    with pytest.raises(SettingError, match=rf"rate_hz = 1000 with bandwidth_hz = {bw}.*8000 Hz.*SMPLRT_DIV"):
        MPU6500Driver.check_settings({"rate_hz": 1000, "bandwidth_hz": bw})
    with pytest.raises(SettingError, match=r"bandwidth_hz 184, 92, 41, 20, 10, 5"):
        MPU6500Driver.check_settings({"rate_hz": 500, "bandwidth_hz": bw})


def test_mpu6500_rate_error_names_the_file_and_key(tmp_path):
    p = tmp_path / "lab.toml"
    p.write_text('[[device]]\nname = "imu"\ndriver = "mpu6500"\nbus = "i2c:1"\nrate_hz = 1000\nbandwidth_hz = 250\n')
    with pytest.raises(ConfigError) as err:
        load_config(p)
    text = str(err.value)
    assert str(p) in text and "device[0] (imu)" in text and "rate_hz = 1000" in text and "\n" not in text


@pytest.mark.parametrize("driver,rate,bw", [("mpu9150", 8000, 256), ("mpu9150", 4000, 256), ("mpu6500", 8000, 250)])
def test_rates_beyond_the_i2c_bus_are_refused(driver, rate, bw):
    # 14-byte frames x 9 clocks per byte at the rate must fit the 400 kHz fast-mode bus
    with pytest.raises(SettingError, match=r"400 kHz"):
        DRIVER[driver].check_settings({"rate_hz": rate, "bandwidth_hz": bw})
    assert MPU9150Driver.check_settings({"rate_hz": 8000 / 3, "bandwidth_hz": 256})["rate_hz"] == 8000 / 3


@pytest.mark.parametrize(
    "driver,clock_source",
    [("mpu9150", "PLL with X axis gyroscope reference"), ("mpu6500", "auto: PLL if ready, else internal oscillator")],
)
def test_clock_source_metadata_per_chip(driver, clock_source):
    # CLKSEL = 1: RM-MPU-6000A Register 107 "PLL with X axis gyroscope reference";
    # RM-MPU-6500A Register 107 "Auto selects the best available clock source - PLL if ready, else ..."
    clock, sim, drv = make(driver)
    assert drv.open().settings["clock_source"] == f"{clock_source} (CLKSEL = 1)"


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
    drv.sim_smbus = smbus  # the simulated adapter, for tests that inject transfer faults
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


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_overflow_resets_fifo_and_reports_unknown_loss(driver):
    clock, sim, drv = make(driver)
    info = drv.open()
    capacity = chip.VARIANTS[driver].fifo_bytes
    clock.sleep(2.0)  # 400 frames into 1024 / 512 bytes
    assert drv.regs.read(chip.REG_FIFO_COUNT_H, 2) == capacity.to_bytes(2, "big")
    block = drv.read_block()
    assert block.n == 0 and block.lost == -1 and "overrun" in block.note
    assert len(sim.fifo) == 0 and not sim.int_status & chip.INT_FIFO_OFLOW
    # the FIFO really was reset (MPU-9150: only while FIFO_EN = 0): the next poll reads
    # one poll interval of frames and nothing else
    clock.sleep(info.poll_interval_s)
    again = drv.read_block()
    assert again.lost == 0 and again.n == round(info.poll_interval_s * 200)


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_overflow_between_count_and_data_read_drops_the_misaligned_bytes(driver):
    # the host stalls after FIFO_COUNT was read: the FIFO overflows (oldest bytes lost, so the
    # 14-byte alignment is gone) before the frames are read; they must not be stored
    gyro_counts = np.array([131, -262, 1])
    clock, sim, drv = make(driver, gyro=gyro_counts * chip.GYRO_RANGES[0].scale)
    smbus = drv.sim_smbus
    info = drv.open()
    stall = {"armed": False}

    def fault(addr, msgs):
        if stall["armed"] and bytes(msgs[0])[0] == chip.REG_FIFO_R_W:
            stall["armed"] = False
            clock.sleep(2.0)

    smbus.sim_fault = fault
    clock.sleep(info.poll_interval_s)
    stall["armed"] = True
    block = drv.read_block()
    assert not stall["armed"] and block.lost == -1 and block.n == 0
    for _ in range(3):
        clock.sleep(info.poll_interval_s)
        block = drv.read_block()
        assert block.lost == 0 and block.n and (block.channels["gyro"] == gyro_counts).all()


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_fifo_reset_is_the_documented_sequence(driver):
    # RM-MPU-6000A rev 4.2 Register 106: FIFO_RESET resets the FIFO "while FIFO_EN equals 0";
    # the driver clears FIFO_EN, resets, re-enables (as Linux inv_mpu6050 does) on both chips
    clock, sim, drv = make(driver)
    drv.open()
    writes = []
    on_write = sim.on_write

    def record(reg, value):
        if reg == chip.REG_USER_CTRL:
            writes.append(value)
        on_write(reg, value)

    sim.on_write = record
    clock.sleep(2.0)
    assert drv.read_block().lost == -1
    assert writes == [0x00, chip.USER_CTRL_FIFO_RST, chip.USER_CTRL_FIFO_EN]


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_open_drops_the_start_up_samples(driver):
    clock, sim, drv = make(driver)
    drv.open()
    assert len(sim.fifo) == 0
    assert drv.read_block().n == 0


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
        settings={"rate_hz": 2000, "bandwidth_hz": 256},  # 8000/(1+3)
        accel_src=lambda fs: RampSource(fs, chip.ACCEL_RANGES[0].scale),
    )
    info = drv.open()
    clock.sleep(info.poll_interval_s)
    x = drv.read_block().channels["accel"][:, 0]
    assert len(x) == 29
    runs = np.diff(np.flatnonzero(np.diff(x)))
    assert (runs == 2).all() and (np.diff(np.unique(x)) == 1).all()


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


# --- the simulator holds the chip to its register map (docs/reference/conformance-invensense.md) --------


def awake_sim(driver):
    """A simulated chip woken and streaming 14-byte frames into its FIFO at 1 kHz, without the driver."""
    clock = new_clock()
    still, gravity = (lambda fs: ConstantSource(fs, (0, 0, 0))), (lambda fs: ConstantSource(fs, (0, 0, G0)))
    sim = InvenSenseSim(chip.VARIANTS[driver], clock, still, gravity)

    def write(reg, *values):
        sim.i2c_write(bytes([reg, *values]))

    def read(reg, n):
        sim.i2c_write(bytes([reg]))
        return sim.i2c_read(n)

    write(0x6B, 0x01)
    write(0x1A, 1)  # DLPF_CFG 1: 1 kHz
    write(0x38, chip.INT_ENABLE_VALUE)
    write(0x23, chip.FIFO_EN_FRAME)
    write(0x6A, chip.USER_CTRL_FIFO_EN)
    return clock, sim, write, read


@pytest.mark.parametrize("driver,resets", [("mpu9150", False), ("mpu6500", True)])
def test_sim_fifo_rst_while_fifo_enabled(driver, resets):
    # RM-MPU-6000A rev 4.2 Reg 106: FIFO_RESET acts "while FIFO_EN equals 0" (else: nothing);
    # RM-MPU-6500A rev 2.1 Reg 106: "Reset is asynchronous"
    clock, sim, write, read = awake_sim(driver)
    clock.sleep(0.030)
    assert int.from_bytes(read(0x72, 2), "big") == 30 * 14
    write(0x6A, chip.USER_CTRL_FIFO_EN | chip.USER_CTRL_FIFO_RST)
    assert (len(sim.fifo) == 0) is resets
    write(0x6A, 0x00)
    write(0x6A, chip.USER_CTRL_FIFO_RST)
    write(0x6A, chip.USER_CTRL_FIFO_EN)
    assert len(sim.fifo) == 0 and sim.regs[0x6A] == chip.USER_CTRL_FIFO_EN  # FIFO_RST clears itself


@pytest.mark.parametrize("driver,fills", [("mpu9150", False), ("mpu6500", True)])
def test_sim_user_ctrl_fifo_en_zero(driver, fills):
    # 6050 set: a disabled FIFO "cannot be written to or read from"; 6500: FIFO_EN = 0 only
    # "disable[s] FIFO access from serial interface", writes follow the FIFO_EN register
    clock, sim, write, read = awake_sim(driver)
    write(0x6A, 0x00)
    clock.sleep(0.010)
    assert int.from_bytes(read(0x72, 2), "big") == (140 if fills else 0)
    read(0x74, 14)
    assert len(sim.fifo) == (140 if fills else 0)


@pytest.mark.parametrize(
    "driver,fchoice_b,dlpf,div,rate",
    [("mpu9150", 0, 0, 7, 1000), ("mpu9150", 0, 7, 7, 1000), ("mpu9150", 0, 3, 7, 125), ("mpu6500", 0, 0, 7, 8000),
     ("mpu6500", 0, 7, 7, 8000), ("mpu6500", 0, 3, 7, 125), ("mpu6500", 1, 3, 7, 32000), ("mpu6500", 2, 3, 7, 32000)],
)  # fmt: skip
def test_sim_runs_at_the_rate_its_register_map_gives(driver, fchoice_b, dlpf, div, rate):
    # 6050: 8 kHz gyro output with DLPF_CFG 0/7, then / (1 + SMPLRT_DIV); 6500: the divider only
    # for FCHOICE_B = 00 and 0 < DLPF_CFG < 7 (8 kHz with DLPF_CFG 0/7, 32 kHz with FCHOICE_B != 00)
    clock, sim, write, read = awake_sim(driver)
    write(0x19, div)
    write(0x1A, dlpf)
    write(0x1B, fchoice_b)
    produced = sim.sim_produced
    clock.sleep(0.5)
    sim._advance()
    assert sim.rate_hz == rate and sim.sim_produced - produced == rate // 2


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_sim_registers_take_no_writes_while_starting_after_reset(driver):
    clock, sim, write, read = awake_sim(driver)
    write(0x6B, chip.PWR1_DEVICE_RESET)
    write(0x19, 4)
    assert sim.regs[0x19] == 0 and sim.sim_ignored_writes == 1
    clock.sleep(0.100)  # RM-MPU-6000A Reg 107: wait 100 ms after DEVICE_RESET
    write(0x19, 4)
    assert sim.regs[0x19] == 4


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_sim_read_only_registers_and_interrupt_flags(driver):
    clock, sim, write, read = awake_sim(driver)
    for reg in (0x75, 0x3A, 0x3B, 0x41, 0x48, 0x72, 0x73):
        write(reg, 0x5A)
    assert read(0x75, 1)[0] == chip.VARIANTS[driver].who_am_i
    clock.sleep(0.01)
    assert read(0x3A, 1)[0] == chip.INT_DATA_RDY and read(0x3A, 1)[0] == 0  # cleared by reading INT_STATUS
    write(0x38, 0x00)  # sources disabled: their status bits stay 0
    clock.sleep(2.0)
    assert read(0x3A, 1)[0] == 0 and int.from_bytes(read(0x72, 2), "big") == chip.VARIANTS[driver].fifo_bytes


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_sim_fifo_count_h_latches_both_bytes(driver):
    # Registers 114/115: reading FIFO_COUNT_H loads both; FIFO_COUNT_L alone gives the latched value
    clock, sim, write, read = awake_sim(driver)
    clock.sleep(0.010)
    assert read(0x72, 2) == (140).to_bytes(2, "big")
    clock.sleep(0.010)
    assert read(0x73, 1)[0] == 140 and read(0x72, 2) == (280).to_bytes(2, "big")
