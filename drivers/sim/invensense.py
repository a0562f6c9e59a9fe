"""Byte-level simulator of the InvenSense MPU-6050-family chips (MPU-9150, MPU-6500).

Behaviour follows ``shared/reference/sensors.md`` §2-§3, with the chip
differences taken from the driver's :class:`~imustation.drivers.invensense.Variant`
rows: WHO_AM_I, a real byte FIFO of the variant's size that overflows (oldest
bytes lost and FIFO_OFLOW_INT set; on the MPU-6500 with CONFIG.FIFO_MODE = 1 new
bytes are dropped instead), FIFO_COUNT, FIFO_R_W as a non-incrementing port that
repeats the last byte when empty (§2.5 [I2CDEV]), INT_STATUS cleared on read,
DEVICE_RESET, sleep (no samples while SLEEP is set or the clock is stopped),
big-endian data registers, sample rate internal/(1+SMPLRT_DIV) with the
accelerometer held at its 1 kHz output rate above that (§2.2).
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
_READ_ONLY = frozenset(
    {chip.REG_WHO_AM_I, chip.REG_INT_STATUS, chip.REG_FIFO_COUNT_H, chip.REG_FIFO_COUNT_H + 1}
    | set(range(chip.REG_ACCEL_XOUT_H, chip.REG_ACCEL_XOUT_H + 14))
)
#: registers whose write changes the sampling (timing restarts)
_TIMING = frozenset({chip.REG_SMPLRT_DIV, chip.DLPF_CFG.reg, chip.GYRO_FS_SEL.reg, chip.REG_PWR_MGMT_1})
#: the MPU-6500's fastest internal rate (FCHOICE_B != 00), §3 [CR]
FCHOICE_INTERNAL_HZ = 32000.0


class InvenSenseSim(RegisterFileChip):
    """An MPU-9150 or MPU-6500 on a simulated I2C bus.

    Parameters
    ----------
    variant : the chip row (:data:`imustation.drivers.invensense.VARIANTS`).
    clock : the station clock (virtual in simulation).
    gyro_factory, accel_factory : ``fs_hz -> SignalSource`` giving X/Y/Z rate
        (rad/s; its temperature is the die temperature) and specific force (m/s^2).
    plan : fault plan (``reset``, ``stuck_fifo`` act on the chip).
    """

    NO_INCREMENT = frozenset({chip.REG_FIFO_R_W})

    def __init__(
        self,
        variant: chip.Variant,
        clock: Clock,
        gyro_factory: Callable[[float], SignalSource],
        accel_factory: Callable[[float], SignalSource],
        plan: FaultPlan | None = None,
    ):
        super().__init__()
        self.variant = variant
        self.clock = clock
        self.plan = plan
        self.gyro_factory, self.accel_factory = gyro_factory, accel_factory
        self.gyro_src: SignalSource | None = None
        self.accel_src: SignalSource | None = None
        self.sim_resets = 0
        #: samples taken since construction (test back door)
        self.sim_produced = 0
        self._power_on()

    # -- state ----------------------------------------------------------------------
    def _power_on(self) -> None:
        self.regs[:] = bytes(256)
        self.regs[chip.REG_WHO_AM_I] = self.variant.who_am_i
        self.regs[chip.REG_PWR_MGMT_1] = self.variant.por_pwr_mgmt_1
        self.fifo = bytearray()
        self.int_status = 0
        self.last_fifo_byte = 0
        self._restart_timing()

    def _restart_timing(self) -> None:
        self.t_start_ns = self.clock.now_ns()
        self.produced = 0
        self.latest = np.zeros(7, dtype=np.int16)
        self.accel_drawn, self.accel_last = 0, np.zeros(3)
        # the registers these depend on are _TIMING registers, whose writes come here
        rate = self._rate = self.rate_hz
        self._running = self.running
        gyro_filter = self._gyro_filter()
        if not fits(self.gyro_src, rate, gyro_filter):
            self.gyro_src = with_filter(self.gyro_factory(rate), gyro_filter)
        self._check_accel_source()

    def _gyro_filter(self) -> filters.ChipFilter:
        fchoice_b = (
            chip.GYRO_FCHOICE_B.decode(self.regs[chip.GYRO_FCHOICE_B.reg]) if self.variant.has_accel_config2 else 0
        )
        dlpf = chip.DLPF_CFG.decode(self.regs[chip.DLPF_CFG.reg])
        return filters.invensense_gyro(self.variant.driver, dlpf, self.regs[chip.REG_SMPLRT_DIV], fchoice_b)

    def _check_accel_source(self) -> None:
        """The accelerometer source for its output rate and filter (the MPU-6500's ACCEL_CONFIG2
        is no timing register: a write there takes effect at the next sample)."""
        accel_fs = min(self._rate, chip.ACCEL_OUTPUT_HZ)
        if self.variant.has_accel_config2:
            reg = self.regs[chip.A_DLPF_CFG.reg]
            code, bypass = chip.A_DLPF_CFG.decode(reg), chip.A_FCHOICE_B.decode(reg)
        else:
            code, bypass = chip.DLPF_CFG.decode(self.regs[chip.DLPF_CFG.reg]), 0
        accel_filter = filters.invensense_accel(self.variant.driver, code, accel_fs, bypass)
        if not fits(self.accel_src, accel_fs, accel_filter):
            self.accel_src = with_filter(self.accel_factory(accel_fs), accel_filter)

    @property
    def internal_hz(self) -> float:
        if self.variant.has_accel_config2 and chip.GYRO_FCHOICE_B.decode(self.regs[chip.GYRO_FCHOICE_B.reg]):
            return FCHOICE_INTERNAL_HZ
        code = chip.DLPF_CFG.decode(self.regs[chip.DLPF_CFG.reg])
        return 8000.0 if code in (0, 7) else 1000.0  # §2.2 [I2CDEV]

    @property
    def rate_hz(self) -> float:
        return self.internal_hz / (1 + self.regs[chip.REG_SMPLRT_DIV])

    @property
    def running(self) -> bool:
        pwr = self.regs[chip.REG_PWR_MGMT_1]
        return not pwr & chip.PWR1_SLEEP and chip.CLKSEL.decode(pwr) != chip.CLKSEL_STOP

    def _scales(self) -> tuple[float, float]:
        g = chip.GYRO_FS_SEL.decode(self.regs[chip.GYRO_FS_SEL.reg])
        a = chip.ACCEL_FS_SEL.decode(self.regs[chip.ACCEL_FS_SEL.reg])
        return chip.GYRO_RANGES[g].scale, chip.ACCEL_RANGES[a].scale

    def _accel(self, n: int) -> np.ndarray:
        """Accelerometer values for the next ``n`` samples (held at 1 kHz above 1 kHz)."""
        self._check_accel_source()
        assert self.accel_src is not None
        rate = self._rate
        if rate <= chip.ACCEL_OUTPUT_HZ:
            return self.accel_src.next(n)
        k = np.arange(self.produced, self.produced + n)
        idx = np.floor(k * chip.ACCEL_OUTPUT_HZ / rate).astype(np.int64)
        fresh = self.accel_src.next(int(idx[-1]) + 1 - self.accel_drawn)
        pool = np.vstack([self.accel_last[None, :], fresh])  # row 0 = accel sample accel_drawn - 1
        out = pool[idx - (self.accel_drawn - 1)]
        self.accel_drawn += len(fresh)
        self.accel_last = pool[-1]
        return out

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
        self.int_status |= chip.INT_DATA_RDY
        if self.plan is not None and self.plan.active("stuck_fifo"):
            return
        if not self.regs[chip.REG_USER_CTRL] & chip.USER_CTRL_FIFO_EN:
            return
        enabled = self.regs[chip.REG_FIFO_EN]
        cols = [c for bit, cs in _FIFO_COLUMNS if enabled & bit for c in cs]
        if not cols:
            return
        cap = self.variant.fifo_bytes
        fit = cap // (2 * len(cols)) + 1  # rows beyond a FIFO-full cannot survive
        if len(self.fifo) + n * 2 * len(cols) > cap:
            self.int_status |= chip.INT_FIFO_OFLOW
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
        self.regs[chip.REG_FIFO_COUNT_H : chip.REG_FIFO_COUNT_H + 2] = len(self.fifo).to_bytes(2, "big")

    def on_read(self, reg: int) -> int:
        value = self.regs[reg]
        if reg == chip.REG_INT_STATUS:
            self.int_status = 0  # cleared by reading [RM6050]
        return value

    def read_stream(self, reg: int, n: int) -> bytes:
        out = bytearray(self.fifo[:n])
        del self.fifo[:n]
        if out:
            self.last_fifo_byte = out[-1]
        out += bytes([self.last_fifo_byte]) * (n - len(out))  # empty FIFO repeats the last byte, §2.5
        return bytes(out)

    def on_write(self, reg: int, value: int) -> None:
        if reg in _READ_ONLY:
            return
        if reg == chip.REG_PWR_MGMT_1 and value & chip.PWR1_DEVICE_RESET:
            self.sim_resets += 1
            self._power_on()
            return
        self._advance()
        if reg == chip.REG_USER_CTRL:
            if value & chip.USER_CTRL_FIFO_RST:
                self.fifo.clear()
                self.int_status &= ~chip.INT_FIFO_OFLOW
            value &= ~(chip.USER_CTRL_FIFO_RST | 0x01)  # FIFO_RST and SIG_COND_RST clear themselves
        self.regs[reg] = value
        if reg in _TIMING:
            self._restart_timing()
