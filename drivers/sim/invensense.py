"""Byte-level simulator of the InvenSense MPU-6050-family chips (MPU-9150, MPU-6500).

Behaviour follows ``docs/reference/sensors.md`` §2-§3, with the chip
differences taken from the driver's :class:`~imustation.drivers.invensense.Variant`
rows: WHO_AM_I, a real byte FIFO of the variant's size that overflows (oldest
bytes lost and FIFO_OFLOW_INT set; on the MPU-6500 with CONFIG.FIFO_MODE = 1 new
bytes are dropped instead), FIFO_COUNT, FIFO_R_W as a non-incrementing port that
repeats the last byte when empty (§2.5 [I2CDEV]), INT_STATUS cleared on read,
DEVICE_RESET, sleep (no samples while SLEEP is set or the clock is stopped),
big-endian data registers, sample rate internal/(1+SMPLRT_DIV) with the
accelerometer held at its 1 kHz output rate above that (§2.2).

Strict where the register maps are (docs/reference/conformance-invensense.md
lists each rule, its source and the test that checks it):

* FIFO_RST on the MPU-6050 register set resets the FIFO only while
  USER_CTRL.FIFO_EN is 0 (RM-MPU-6000A rev 4.2, Register 106); the MPU-6500's
  FIFO_RST is an asynchronous reset (RM-MPU-6500A rev 2.1, Register 106). A
  reset the map does not document does nothing.
* USER_CTRL.FIFO_EN = 0: the MPU-6050's FIFO takes no data and cannot be read;
  the MPU-6500's only stops serial access (its writes follow the FIFO_EN
  register).
* The sample rate is the one the chip runs at: SMPLRT_DIV divides the 1 kHz
  (or, MPU-6050 with DLPF_CFG 0/7, 8 kHz) gyro output rate; on the MPU-6500 it
  is ignored unless FCHOICE_B = 00 and 0 < DLPF_CFG < 7 (8 kHz with DLPF_CFG 0
  or 7, 32 kHz with FCHOICE_B != 00).
* For ``REGISTER_STARTUP_S`` after DEVICE_RESET the registers take no writes.
* FIFO_COUNT_H latches both count bytes; read-only registers ignore writes;
  interrupt status bits are set only for enabled sources and cleared only by
  reading INT_STATUS.

Field quirks the register maps leave out, shown when named (``quirks``,
:mod:`imustation.drivers.sim.quirks`; "Field quirks" in the conformance table):
``stuck_overflow_bit`` (FIFO_OFLOW_INT always reads 1), ``async_reset_tail`` (a
FIFO reset while FIFO_EN routes sensors leaves the tail of the frame being
written), ``wake_write_loss`` (writes lost for 5 ms after SLEEP is cleared). A
switch of the MPU-6050 set to a gyro PLL before its gyro has run is counted
(``sim_pll_without_gyro``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imustation.clock import Clock
from imustation.drivers import invensense as chip
from imustation.drivers.sim import filters
from imustation.drivers.sim.faults import FaultPlan
from imustation.drivers.sim.regfile import RegisterFileChip
from imustation.drivers.sim.sources import SignalSource, fits, with_filter

#: FIFO_EN bit -> column of the (accel xyz, temp, gyro xyz) sample row, in FIFO write order
_FIFO_COLUMNS = ((chip.FIFO_EN_ACCEL, (0, 1, 2)), (chip.FIFO_EN_TEMP, (3,)), (chip.FIFO_EN_XG, (4,)),
                 (chip.FIFO_EN_YG, (5,)), (chip.FIFO_EN_ZG, (6,)))  # fmt: skip
#: sensor data 0x3B..0x48 and EXT_SENS_DATA 0x49..0x60 are read-only (both maps, section 3)
_READ_ONLY = frozenset(
    {chip.REG_WHO_AM_I, chip.REG_INT_STATUS, chip.REG_FIFO_COUNT_H, chip.REG_FIFO_COUNT_H + 1}
    | set(range(chip.REG_ACCEL_XOUT_H, 0x61))
)
#: registers whose write changes the sampling (timing restarts)
_TIMING = frozenset(
    {chip.REG_SMPLRT_DIV, chip.DLPF_CFG.reg, chip.GYRO_FS_SEL.reg, chip.A_FCHOICE_B.reg, chip.REG_PWR_MGMT_1}
)
#: USER_CTRL bits that clear themselves after the reset they trigger (both maps, Register 106)
_USER_CTRL_SELF_CLEARING = chip.USER_CTRL_FIFO_RST | 0x02 | 0x01  # FIFO_RST, I2C_MST_RST, SIG_COND_RST
#: the MPU-6500's gyro rate with FCHOICE_B != 00 (RM-MPU-6500A Register 26 table)
FCHOICE_INTERNAL_HZ = 32000.0
#: the MPU-6500's accelerometer rate with ACCEL_FCHOICE_B = 1 (RM-MPU-6500A Register 29 table)
ACCEL_FCHOICE_HZ = 4000.0
#: after DEVICE_RESET the registers take no writes for this long: the 100 ms wait of the
#: reset sequence (RM-MPU-6000A rev 4.2, Register 107 note), used for both chips
REGISTER_STARTUP_S = 0.100
#: quirk ``wake_write_loss``: writes are lost this long after SLEEP is cleared (Linux
#: inv_mpu6050 waits INV_MPU6050_REG_UP_TIME_MIN..MAX = 5..10 ms before writing again)
WAKE_S = 0.005
#: gyro start-up time before it can be the clock's PLL reference (Linux inv_mpu_iio.h:
#: INV_MPU6050_GYRO_STARTUP_TIME 60 ms, INV_MPU6500_GYRO_STARTUP_TIME 70 ms)
GYRO_START_S = {"mpu9150": 0.060, "mpu6500": 0.070}
#: PWR_MGMT_2 gyro standby bits (Register 108, both maps)
PWR2_GYRO_STANDBY = 0x07


class InvenSenseSim(RegisterFileChip):
    """An MPU-9150 or MPU-6500 on a simulated I2C bus.

    Parameters
    ----------
    variant : the chip row (:data:`imustation.drivers.invensense.VARIANTS`).
    clock : the station clock (virtual in simulation).
    gyro_factory, accel_factory : ``fs_hz -> SignalSource`` giving X/Y/Z rate
        (rad/s; its temperature is the die temperature) and specific force (m/s^2).
    plan : fault plan (``reset``, ``stuck_fifo`` act on the chip).
    quirks : field quirks to show (:data:`imustation.drivers.sim.quirks.QUIRKS`):
        ``stuck_overflow_bit``, ``async_reset_tail``, ``wake_write_loss``.
    """

    NO_INCREMENT = frozenset({chip.REG_FIFO_R_W})

    def __init__(
        self,
        variant: chip.Variant,
        clock: Clock,
        gyro_factory: Callable[[float], SignalSource],
        accel_factory: Callable[[float], SignalSource],
        plan: FaultPlan | None = None,
        quirks: frozenset[str] = frozenset(),
    ):
        super().__init__()
        self.variant = variant
        self.quirks = frozenset(quirks)
        #: CLKSEL set to a gyro PLL before the gyro ran its start-up time (test back door)
        self.sim_pll_without_gyro = 0
        #: FIFO resets that left the tail of a frame at the FIFO head (test back door)
        self.sim_reset_tails = 0
        self.clock = clock
        self.plan = plan
        self.gyro_factory, self.accel_factory = gyro_factory, accel_factory
        self.gyro_src: SignalSource | None = None
        self.accel_src: SignalSource | None = None
        self.sim_resets = 0
        #: samples taken since construction (test back door)
        self.sim_produced = 0
        #: writes ignored because the registers were not ready after a reset (test back door)
        self.sim_ignored_writes = 0
        self._power_on()
        self.ready_ns = self.clock.now_ns()  # powered up long before the station opens it

    # -- state ----------------------------------------------------------------------
    def _power_on(self) -> None:
        self.regs[:] = bytes(256)
        self.regs[chip.REG_WHO_AM_I] = self.variant.who_am_i
        self.regs[chip.REG_PWR_MGMT_1] = self.variant.por_pwr_mgmt_1
        self.fifo = bytearray()
        self.int_status = 0
        self.last_fifo_byte = 0
        self.count_latch = 0
        self.ready_ns = self.clock.now_ns() + int(REGISTER_STARTUP_S * 1e9)
        self.wake_until_ns = 0
        self.gyro_on_ns: int | None = None
        self._track_gyro()
        self._restart_timing()

    def _track_gyro(self) -> None:
        """Note when the gyro started (awake, not in standby), or that it stopped."""
        on = self.running and not self.regs[chip.REG_PWR_MGMT_2] & PWR2_GYRO_STANDBY
        if not on:
            self.gyro_on_ns = None
        elif self.gyro_on_ns is None:
            self.gyro_on_ns = self.clock.now_ns()

    def _restart_timing(self) -> None:
        self.t_start_ns = self.clock.now_ns()
        self.produced = 0
        self.latest = np.zeros(7, dtype=np.int16)
        self.accel_drawn, self.accel_last = 0, np.zeros(3)
        # the registers these depend on are _TIMING registers, whose writes come here
        rate = self._rate = self.rate_hz
        self._accel_hz = self.accel_output_hz
        self._running = self.running
        gyro_filter = self._gyro_filter()
        if not fits(self.gyro_src, rate, gyro_filter):
            self.gyro_src = with_filter(self.gyro_factory(rate), gyro_filter)
        self._check_accel_source()

    def _gyro_filter(self) -> filters.ChipFilter:
        dlpf = chip.DLPF_CFG.decode(self.regs[chip.DLPF_CFG.reg])
        return filters.invensense_gyro(self.variant.driver, dlpf, self.regs[chip.REG_SMPLRT_DIV], self._fchoice_b)

    def _check_accel_source(self) -> None:
        """The accelerometer source for its output rate and filter (the MPU-6500's ACCEL_CONFIG2
        is no timing register: a write there takes effect at the next sample)."""
        accel_fs = min(self._rate, self._accel_hz)
        if self.variant.has_accel_config2:
            reg = self.regs[chip.A_DLPF_CFG.reg]
            code, bypass = chip.A_DLPF_CFG.decode(reg), chip.A_FCHOICE_B.decode(reg)
        else:
            code, bypass = chip.DLPF_CFG.decode(self.regs[chip.DLPF_CFG.reg]), 0
        accel_filter = filters.invensense_accel(self.variant.driver, code, accel_fs, bypass)
        if not fits(self.accel_src, accel_fs, accel_filter):
            self.accel_src = with_filter(self.accel_factory(accel_fs), accel_filter)

    @property
    def _fchoice_b(self) -> int:
        return chip.GYRO_FCHOICE_B.decode(self.regs[chip.GYRO_FCHOICE_B.reg]) if self.variant.has_accel_config2 else 0

    @property
    def internal_hz(self) -> float:
        """Gyroscope output rate before SMPLRT_DIV, Hz."""
        if self._fchoice_b:
            return FCHOICE_INTERNAL_HZ
        code = chip.DLPF_CFG.decode(self.regs[chip.DLPF_CFG.reg])
        return 8000.0 if code in (0, 7) else 1000.0

    @property
    def rate_hz(self) -> float:
        """The sample rate the chip runs at (FIFO and data registers), Hz."""
        code = chip.DLPF_CFG.decode(self.regs[chip.DLPF_CFG.reg])
        if self.variant.has_accel_config2 and (self._fchoice_b or code in (0, 7)):
            # MPU-6500 Register 25: SMPLRT_DIV only for FCHOICE_B = 00 and 0 < DLPF_CFG < 7
            return self.internal_hz
        return self.internal_hz / (1 + self.regs[chip.REG_SMPLRT_DIV])

    @property
    def accel_output_hz(self) -> float:
        """Accelerometer output rate: 1 kHz (MPU-6500 with ACCEL_FCHOICE_B = 1: 4 kHz)."""
        if self.variant.has_accel_config2 and chip.A_FCHOICE_B.decode(self.regs[chip.A_FCHOICE_B.reg]):
            return ACCEL_FCHOICE_HZ
        return chip.ACCEL_OUTPUT_HZ

    @property
    def running(self) -> bool:
        pwr = self.regs[chip.REG_PWR_MGMT_1]
        return not pwr & chip.PWR1_SLEEP and chip.CLKSEL.decode(pwr) != chip.CLKSEL_STOP

    @property
    def _fifo_takes_data(self) -> bool:
        if self.variant.fifo_rst_needs_disable:  # MPU-6050 set: a disabled FIFO cannot be written
            return bool(self.regs[chip.REG_USER_CTRL] & chip.USER_CTRL_FIFO_EN)
        return True  # MPU-6500: the FIFO_EN register alone decides what is written

    @property
    def _fifo_readable(self) -> bool:
        return bool(self.regs[chip.REG_USER_CTRL] & chip.USER_CTRL_FIFO_EN)

    def _scales(self) -> tuple[float, float]:
        g = chip.GYRO_FS_SEL.decode(self.regs[chip.GYRO_FS_SEL.reg])
        a = chip.ACCEL_FS_SEL.decode(self.regs[chip.ACCEL_FS_SEL.reg])
        return chip.GYRO_RANGES[g].scale, chip.ACCEL_RANGES[a].scale

    def _accel(self, n: int) -> np.ndarray:
        """Accelerometer values for the next ``n`` samples (held at its output rate above it)."""
        self._check_accel_source()
        assert self.accel_src is not None
        rate = self._rate
        if rate <= self._accel_hz:
            return self.accel_src.next(n)
        k = np.arange(self.produced, self.produced + n)
        idx = np.floor(k * self._accel_hz / rate).astype(np.int64)
        fresh = self.accel_src.next(int(idx[-1]) + 1 - self.accel_drawn)
        pool = np.vstack([self.accel_last[None, :], fresh])  # row 0 = accel sample accel_drawn - 1
        out = pool[idx - (self.accel_drawn - 1)]
        self.accel_drawn += len(fresh)
        self.accel_last = pool[-1]
        return out

    def _raise(self, flag: int) -> None:
        """Set an interrupt status bit if its source is enabled (same bit in INT_ENABLE)."""
        self.int_status |= flag & self.regs[chip.REG_INT_ENABLE]

    def _advance(self) -> None:
        """Take every sample due by now; data registers, DATA_RDY and FIFO.

        Faults: ``reset`` is a power-on reset; during ``stuck_fifo`` the sensor goes
        on (data registers, DATA_RDY_INT) but the FIFO receives nothing.
        """
        if self.plan is not None and self.plan.fire("reset"):
            self.sim_resets += 1
            self._power_on()
            return
        if not self._running:
            self._restart_timing()
            return
        rate = self._rate
        n = int((self.clock.now_ns() - self.t_start_ns) * rate / 1e9) - self.produced
        if n <= 0:
            return
        assert self.gyro_src is not None
        gyro_scale, accel_scale = self._scales()
        rows = np.empty((n, 7))
        rows[:, 0:3] = self._accel(n) / accel_scale
        # the die temperature changes slowly: one value per burst of samples
        temp_c = self.gyro_src.temperature((self.produced + n) / rate)
        rows[:, 3] = (temp_c - self.variant.temp_offset_c) * self.variant.temp_lsb_per_c
        rows[:, 4:7] = self.gyro_src.next(n) / gyro_scale
        counts = np.clip(np.rint(rows), -32768, 32767).astype(np.int16)
        self.produced += n
        self.sim_produced += n
        self.latest = counts[-1]
        self._raise(chip.INT_DATA_RDY)
        if self.plan is not None and self.plan.active("stuck_fifo"):
            return
        if not self._fifo_takes_data:
            return
        enabled = self.regs[chip.REG_FIFO_EN]
        cols = [c for bit, cs in _FIFO_COLUMNS if enabled & bit for c in cs]
        if not cols:
            return
        cap = self.variant.fifo_bytes
        fit = cap // (2 * len(cols)) + 1  # rows beyond a FIFO-full cannot survive
        if len(self.fifo) + n * 2 * len(cols) > cap:
            self._raise(chip.INT_FIFO_OFLOW)
        if self.variant.has_accel_config2 and chip.CONFIG_FIFO_MODE.decode(self.regs[chip.CONFIG_FIFO_MODE.reg]):
            # MPU-6500 FIFO_MODE = 1: when full, further writes are dropped (§3 [PX4-6500])
            self.fifo += counts[:fit, cols].astype(">i2").tobytes()[: max(0, cap - len(self.fifo))]
        else:
            # oldest data lost on overflow (§2.5 [I2CDEV])
            self.fifo += counts[-fit:, cols].astype(">i2").tobytes()
            del self.fifo[: max(0, len(self.fifo) - cap)]

    # -- register hooks ----------------------------------------------------------------
    def before_read(self, reg: int, n: int) -> None:
        self._advance()
        self.regs[chip.REG_ACCEL_XOUT_H : chip.REG_ACCEL_XOUT_H + 14] = self.latest.astype(">i2").tobytes()
        self.regs[chip.REG_INT_STATUS] = self.int_status

    def on_read(self, reg: int) -> int:
        if reg == chip.REG_INT_STATUS:
            value, self.int_status = self.int_status, 0  # cleared by reading INT_STATUS (Register 58)
            if "stuck_overflow_bit" in self.quirks:
                value |= chip.INT_FIFO_OFLOW
            return value
        if reg == chip.REG_FIFO_COUNT_H:
            # reading FIFO_COUNT_H latches both count bytes (Registers 114/115, both maps)
            self.count_latch = len(self.fifo)
            return self.count_latch >> 8
        if reg == chip.REG_FIFO_COUNT_H + 1:
            return self.count_latch & 0xFF
        return self.regs[reg]

    def read_stream(self, reg: int, n: int) -> bytes:
        if not self._fifo_readable:
            # a disabled FIFO cannot be read (Register 106): the port gives nothing new
            return bytes([self.last_fifo_byte]) * n
        out = bytearray(self.fifo[:n])
        del self.fifo[:n]
        if out:
            self.last_fifo_byte = out[-1]
        out += bytes([self.last_fifo_byte]) * (n - len(out))  # empty FIFO repeats the last byte, §2.5
        return bytes(out)

    def on_write(self, reg: int, value: int) -> None:
        if reg in _READ_ONLY:
            return
        now = self.clock.now_ns()
        if now < self.ready_ns or now < self.wake_until_ns:
            self.sim_ignored_writes += 1  # still starting up after DEVICE_RESET, or waking
            return
        if reg == chip.REG_PWR_MGMT_1 and value & chip.PWR1_DEVICE_RESET:
            self.sim_resets += 1
            self._power_on()
            return
        self._advance()
        if reg == chip.REG_USER_CTRL:
            if value & chip.USER_CTRL_FIFO_RST and self._fifo_reset_takes(value):
                self.fifo.clear()
                self._cut_frame_tail()
            value &= ~_USER_CTRL_SELF_CLEARING & 0xFF
        if reg == chip.REG_PWR_MGMT_1:
            self._check_clock_source(value)
            if self.regs[reg] & chip.PWR1_SLEEP and not value & chip.PWR1_SLEEP and "wake_write_loss" in self.quirks:
                self.wake_until_ns = now + int(WAKE_S * 1e9)
        self.regs[reg] = value
        if reg in _TIMING:
            self._restart_timing()
        if reg in (chip.REG_PWR_MGMT_1, chip.REG_PWR_MGMT_2):
            self._track_gyro()

    def _check_clock_source(self, value: int) -> None:
        """Count a switch to a gyro PLL (CLKSEL 1..3) before the gyro has started (MPU-6050 set only).

        Linux inv_mpu6050 (``inv_mpu6050_switch_engine``): the clock may take the gyro as its
        reference only once the gyro runs; until then it must be the internal oscillator. What
        the chip does otherwise is not documented, so it is counted, not modelled.
        """
        if not self.variant.pll_needs_running_gyro or not 1 <= chip.CLKSEL.decode(value) <= 3:
            return
        if 1 <= chip.CLKSEL.decode(self.regs[chip.REG_PWR_MGMT_1]) <= 3:
            return  # already on it
        started = self.gyro_on_ns
        if started is None or self.clock.now_ns() - started < GYRO_START_S[self.variant.driver] * 1e9:
            self.sim_pll_without_gyro += 1

    def _cut_frame_tail(self) -> None:
        """Quirk ``async_reset_tail``: a reset while sensors write into the FIFO leaves the tail
        of the frame being written (all but its first sensor block) at the head of the FIFO."""
        if "async_reset_tail" not in self.quirks or not self._running or not self._fifo_takes_data:
            return
        enabled = self.regs[chip.REG_FIFO_EN]
        blocks = [cs for bit, cs in _FIFO_COLUMNS if enabled & bit]
        if len(blocks) < 2:
            return
        frame = self.latest[[c for cs in blocks for c in cs]].astype(">i2").tobytes()
        self.fifo += frame[2 * len(blocks[0]) :]
        self.sim_reset_tails += 1

    def _fifo_reset_takes(self, value: int) -> bool:
        """Whether a USER_CTRL write with FIFO_RST set resets the FIFO.

        MPU-6050 set: only "while FIFO_EN equals 0" (RM-MPU-6000A rev 4.2, Register
        106). Whether a write that clears FIFO_EN and sets FIFO_RST at once counts
        is not said; the safe reading is taken: FIFO_EN must already be 0 and stay 0.
        MPU-6500: "Reset is asynchronous" (RM-MPU-6500A rev 2.1, Register 106).
        """
        if not self.variant.fifo_rst_needs_disable:
            return True
        was_enabled = self.regs[chip.REG_USER_CTRL] & chip.USER_CTRL_FIFO_EN
        return not was_enabled and not value & chip.USER_CTRL_FIFO_EN
