"""Field quirks the register maps leave out (docs/reference/conformance-invensense.md, "Field quirks"):
the simulators show each one on request, and the drivers record every sample the chip sends, in frame."""

import numpy as np
import pytest
from simchips import ConstantSource, RampSource, new_clock, wire

from imustation.acquisition.config import load_config
from imustation.clock import VirtualClock
from imustation.drivers import invensense as chip
from imustation.drivers import kvh_dsp3000 as kvh
from imustation.drivers.bus.serial_port import SerialPort
from imustation.drivers.invensense import MPU6500Driver, MPU9150Driver
from imustation.drivers.sim import make_simulator
from imustation.drivers.sim.invensense import InvenSenseSim
from imustation.drivers.sim.kvh_dsp3000 import DSP3000Sim
from imustation.drivers.sim.serial_handlers import register, unregister
from imustation.errors import ConfigError, DeviceError, SettingError
from imustation.units import G0

DRIVER = {"mpu9150": MPU9150Driver, "mpu6500": MPU6500Driver}
TEMP_C = 30.0


def quirky(driver, *quirks, settings=None):
    """A driver on a chip showing ``quirks``; the gyro x/y/z counts of sample i are i (a ramp), the
    accelerometer reads +1 g on z and the die 30 degC, so a frame read out of step is seen at once."""
    clock = new_clock()
    sim = InvenSenseSim(
        chip.VARIANTS[driver],
        clock,
        lambda fs: RampSource(fs, chip.GYRO_RANGES[0].scale, temp_c=TEMP_C),
        lambda fs: ConstantSource(fs, (0.0, 0.0, G0)),
        quirks=frozenset(quirks),
    )
    drv, smbus = wire(DRIVER[driver], sim, settings)
    return clock, sim, drv, smbus


def record(clock, drv, info, polls):
    """``polls`` polls one poll interval apart: (gyro, accel, temp rows of the blocks, lost flags)."""
    blocks = []
    for _ in range(polls):
        clock.sleep(info.poll_interval_s)
        blocks.append(drv.read_block())
    return blocks


def assert_in_frame(drv, blocks):
    """Every stored row is a whole frame: accel (0, 0, 1 g), the die temperature, and the gyro ramp
    going up by one count per sample (one run per stretch between losses)."""
    v = drv.VARIANT
    temp_counts = round((TEMP_C - v.temp_offset_c) * v.temp_lsb_per_c)
    run = []
    for b in blocks:
        if b.lost:
            run = []
        if not b.n:
            continue
        assert (b.channels["accel"] == [0, 0, 16384]).all()
        assert (b.channels["temp"] == temp_counts).all()
        g = b.channels["gyro"]
        assert (g[:, 0] == g[:, 1]).all() and (g[:, 1] == g[:, 2]).all()
        run = np.concatenate([run, g[:, 0]])
        assert (np.diff(run) == 1).all()


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_stuck_overflow_bit_every_sample_recorded(driver):
    # Linux commit 6e82ae6b8d11 "iio: imu: inv_mpu6050: fix no data on MPU6050": some chips always set
    # FIFO_OFLOW_INT; a driver that resets on it records nothing (before: 0 of 3000 samples in 15 s)
    clock, sim, drv, _ = quirky(driver, "stuck_overflow_bit")
    info = drv.open()
    produced = sim.sim_produced
    blocks = record(clock, drv, info, round(15.0 / info.poll_interval_s))
    n = sum(b.n for b in blocks)
    assert not any(b.lost for b in blocks)
    assert n == sim.sim_produced - produced - len(sim.fifo) // chip.FRAME_BYTES
    assert n == len(blocks) * round(info.poll_interval_s * 200) > 2900  # ~15 s at 200 Hz
    assert_in_frame(drv, blocks)


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_overflow_by_count_with_a_stuck_bit_still_resets(driver):
    # the byte count alone decides: a stalled host still gets its overflow dropped and reported
    clock, sim, drv, _ = quirky(driver, "stuck_overflow_bit")
    info = drv.open()
    clock.sleep(info.poll_interval_s)
    assert drv.read_block().lost == 0
    clock.sleep(2.0)
    block = drv.read_block()
    assert block.lost == -1 and block.n == 0 and "overrun" in block.note
    assert_in_frame(drv, record(clock, drv, info, 5))


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_overflow_margin_is_three_frames(driver):
    # Linux inv_mpu_ring.c: reset when the count reaches the capacity less three frames
    clock, sim, drv, _ = quirky(driver)
    drv.open()
    limit = chip.VARIANTS[driver].fifo_bytes - 3 * chip.FRAME_BYTES
    assert chip.VARIANTS[driver].overflow_bytes == limit
    clock.sleep((limit // chip.FRAME_BYTES) / 200)  # one frame short of the limit
    assert drv.read_block().lost == 0
    clock.sleep((limit // chip.FRAME_BYTES + 1) / 200)  # the limit reached
    assert drv.read_block().lost == -1


def test_reset_while_sensors_write_leaves_no_frame_tail():
    # MPU-6500: FIFO_RST is asynchronous; a reset while FIFO_EN (0x23) routes the sensors cuts the frame
    # being written (before: after the first reset every recorded row was a misaligned frame)
    clock, sim, drv, smbus = quirky("mpu6500", "async_reset_tail")
    info = drv.open()
    stall = {"armed": False}

    def fault(addr, msgs):
        if stall["armed"] and bytes(msgs[0])[0] == chip.REG_FIFO_R_W:
            stall["armed"] = False
            clock.sleep(1.0)  # a stalled host: the FIFO overflows, the driver resets it

    smbus.sim_fault = fault
    blocks = record(clock, drv, info, 10)
    stall["armed"] = True
    blocks += record(clock, drv, info, 10)
    assert sum(1 for b in blocks if b.lost) == 1 and sum(b.n for b in blocks) == 19 * round(info.poll_interval_s * 200)
    assert sim.sim_reset_tails == 0  # the driver never resets while a sensor writes
    assert_in_frame(drv, blocks)


def test_sim_async_reset_tail_cuts_the_frame_being_written():
    # the simulator's side: a reset with the routing on leaves the last 8 bytes (TEMP, GYRO) of a frame
    clock, sim, drv, _ = quirky("mpu6500", "async_reset_tail")
    drv.open()
    clock.sleep(0.05)
    sim.i2c_write(bytes([chip.REG_USER_CTRL, chip.USER_CTRL_FIFO_EN | chip.USER_CTRL_FIFO_RST]))
    assert len(sim.fifo) == 8 and sim.sim_reset_tails == 1
    sim.i2c_write(bytes([chip.REG_FIFO_EN, 0]))
    sim.i2c_write(bytes([chip.REG_USER_CTRL, chip.USER_CTRL_FIFO_RST]))
    assert len(sim.fifo) == 0 and sim.sim_reset_tails == 1  # nothing was being written


@pytest.mark.parametrize("leftovers,opens", [(2, True), (3, False)])
def test_fifo_reset_repeated_until_empty(leftovers, opens):
    # the check after every reset: with no sensor routed the FIFO must read empty; bytes left are
    # reset again (up to three tries), then a DeviceError - never frames read out of step
    clock, sim, drv, _ = quirky("mpu6500")
    on_write, left = sim.on_write, {"n": leftovers}

    def leave_bytes(reg, value):
        on_write(reg, value)
        if reg == chip.REG_USER_CTRL and value & chip.USER_CTRL_FIFO_RST and left["n"]:
            left["n"] -= 1
            sim.fifo += bytes(6)

    sim.on_write = leave_bytes
    if not opens:
        with pytest.raises(DeviceError, match=r"FIFO holds 6 bytes after 3 resets"):
            drv.open()
        return
    info = drv.open()
    assert_in_frame(drv, record(clock, drv, info, 5))


def test_fifo_reset_order_routing_off_first():
    # Linux inv_mpu6050_prepare_fifo: FIFO_EN (0x23) 0, USER_CTRL 0, FIFO_RST, FIFO_EN routing, USER_CTRL.FIFO_EN
    clock, sim, drv, _ = quirky("mpu9150")
    drv.open()
    writes = []
    on_write = sim.on_write

    def log(reg, value):
        if reg in (chip.REG_FIFO_EN, chip.REG_USER_CTRL):
            writes.append((reg, value))
        on_write(reg, value)

    sim.on_write = log
    clock.sleep(2.0)
    assert drv.read_block().lost == -1
    assert writes == [(0x23, 0), (0x6A, 0), (0x6A, chip.USER_CTRL_FIFO_RST), (0x23, chip.FIFO_EN_FRAME),
                      (0x6A, chip.USER_CTRL_FIFO_EN)]  # fmt: skip


def test_writes_lost_while_waking():
    # Linux inv_mpu6050_set_power_itg waits 5-10 ms after clearing SLEEP; a chip that loses writes in
    # that time made the driver's read-back fail at open (before: "configuration read back" DeviceError)
    clock, sim, drv, _ = quirky("mpu9150", "wake_write_loss", settings={"rate_hz": 500, "gyro_range_dps": 250})
    info = drv.open()
    assert sim.sim_ignored_writes == 0 and sim.regs[chip.REG_SMPLRT_DIV] == 1
    assert_in_frame(drv, record(clock, drv, info, 5))


def test_sim_wake_write_loss():
    clock, sim, drv, _ = quirky("mpu9150", "wake_write_loss")
    sim.i2c_write(bytes([chip.REG_PWR_MGMT_1, 0x00]))  # wake
    sim.i2c_write(bytes([chip.REG_SMPLRT_DIV, 4]))
    assert sim.regs[chip.REG_SMPLRT_DIV] == 0 and sim.sim_ignored_writes == 1
    clock.sleep(0.005)
    sim.i2c_write(bytes([chip.REG_SMPLRT_DIV, 4]))
    assert sim.regs[chip.REG_SMPLRT_DIV] == 4


def test_mpu9150_switches_to_the_gyro_pll_once_the_gyro_runs():
    # Linux inv_mpu6050_switch_engine: the clock may take the gyro as reference only once it runs;
    # before, the driver woke the chip straight onto the gyro PLL
    clock, sim, drv, _ = quirky("mpu9150")
    power = []
    on_write = sim.on_write

    def log(reg, value):
        if reg == chip.REG_PWR_MGMT_1:
            power.append((clock.now_ns(), value))
        on_write(reg, value)

    sim.on_write = log
    drv.open()
    assert [v for _, v in power] == [chip.PWR1_DEVICE_RESET, 0x00, 0x01]
    assert power[2][0] - power[1][0] >= chip.STARTUP_WAIT_S * 1e9
    assert sim.sim_pll_without_gyro == 0 and sim.regs[chip.REG_PWR_MGMT_1] == 0x01


def test_sim_counts_a_pll_switch_before_the_gyro_runs():
    clock, sim, drv, _ = quirky("mpu9150")
    sim.i2c_write(bytes([chip.REG_PWR_MGMT_1, 0x01]))  # wake straight onto the gyro PLL
    assert sim.sim_pll_without_gyro == 1
    clock.sleep(0.1)
    sim.i2c_write(bytes([chip.REG_PWR_MGMT_1, 0x00]))
    clock.sleep(0.1)
    sim.i2c_write(bytes([chip.REG_PWR_MGMT_1, 0x01]))  # the gyro has run 100 ms
    assert sim.sim_pll_without_gyro == 1


def test_dsp3000_trailing_blanks_are_parsed():
    # blanks and tabs after the status word, before CR LF (the ROS drivers split on whitespace);
    # before, every such line was counted as lost
    assert kvh.parse_line(b"   1.000000   1  \t ") == (1_000_000, 1)
    assert kvh.parse_line(b"   1.000000   1 x") is None
    clock = VirtualClock()
    sim = DSP3000Sim(clock, lambda fs: ConstantSource(fs, [0.01]), quirks=frozenset({"trailing_blanks"}))
    url = register("fog-blanks", sim)
    try:
        port = SerialPort("serial:/dev/ttyS0", baud_default=38400, sim_url=url)
        drv = kvh.KVHDSP3000(port, {}, sleep=clock.sleep)
        info = drv.open()
        blocks = record(clock, drv, info, 10)
        assert sum(b.lost for b in blocks) == 0 and sum(b.n for b in blocks) >= 195
        assert sim.tail and not sim.tail.strip(" \t")  # the lines did carry blanks
    finally:
        unregister("fog-blanks")


def test_quirks_key_checked(tmp_path):
    p = tmp_path / "lab.toml"
    base = '[[device]]\nname = "imu"\ndriver = "mpu6500"\nbus = "i2c:1"\n[device.sim]\n'
    p.write_text(base + 'quirks = ["stuck_overflow_bit", "async_reset_tail"]\n')
    cfg = load_config(p)
    assert cfg.devices[0].sim["quirks"] == ["stuck_overflow_bit", "async_reset_tail"]
    p.write_text(base + 'quirks = ["sticky"]\n')
    with pytest.raises(ConfigError, match=r"sim.quirks.*quirk names from.*'sticky' is none of them"):
        load_config(p)
    clock = VirtualClock()
    settings = MPU6500Driver.check_settings({})
    sim, _ = make_simulator("mpu6500", clock, settings, {"quirks": ["stuck_overflow_bit"]}, 1)
    assert sim.quirks == {"stuck_overflow_bit"}
    with pytest.raises(SettingError, match=r"'trailing_blanks' is not a quirk of driver 'mpu6500'"):
        make_simulator("mpu6500", clock, settings, {"quirks": ["trailing_blanks"]}, 1)


@pytest.mark.parametrize("driver", ["mpu9150", "mpu6500"])
def test_fifo_enabled_once_the_temperature_is_valid(driver):
    # Linux INV_MPU6050_TEMP_UP_TIME: 100 ms after power-up before the temperature is valid; every FIFO
    # frame carries it, so the routing goes on no sooner than 100 ms after the wake-up write
    clock, sim, drv, _ = quirky(driver)
    times = {}
    on_write = sim.on_write

    def log(reg, value):
        if reg == chip.REG_PWR_MGMT_1 and value == 0:
            times["wake"] = clock.now_ns()
        if reg == chip.REG_FIFO_EN and value:
            times["fifo"] = clock.now_ns()
        on_write(reg, value)

    sim.on_write = log
    drv.open()
    assert times["fifo"] - times["wake"] >= 0.100e9


def test_capture_with_every_invensense_quirk_records_every_sample(tmp_path):
    # end to end through the station: 20 s of both chips showing all three quirks, every sample period
    # stamped and written, no gap, and the recorded gravity and temperature those of whole frames
    from imustation.acquisition import capture
    from imustation.acquisition.config import parse_config
    from imustation.runfile import open_run

    quirks = ["stuck_overflow_bit", "async_reset_tail", "wake_write_loss"]
    devices = [
        {"name": "m9", "driver": "mpu9150", "bus": "i2c:2", "sim": {"quirks": quirks}},
        {"name": "m65", "driver": "mpu6500", "bus": "i2c:2", "address": 0x69, "sim": {"quirks": quirks}},
    ]
    cfg = parse_config({"station": {"seed": 3}, "device": devices})
    out = tmp_path / "quirks.h5"
    summary = capture(cfg, out, 20.0, simulate=True)
    with open_run(out) as run:
        assert run.events() == []
        for name in ("m9", "m65"):
            dev = run.devices[name]
            t = run.read(name, "t")
            assert summary.samples[name] == dev.n >= 20.0 * 200 - 0.4 * 73 - 60
            assert np.all(np.diff(t) == 1e9 / 200)
            accel = run.read(name, "accel").astype(float) * dev.channels["accel"].scale
            assert np.abs(np.median(accel[:, 2]) - G0) < 0.05 * G0  # +1 g on z: the accelerometer bytes
            assert np.abs(accel[:, :2]).max() < 0.2 * G0  # where they belong in every row
