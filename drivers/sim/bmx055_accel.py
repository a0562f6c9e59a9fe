"""Byte-level simulator of the BMX055 accelerometer die (BMA2x2, chip id 0xFA).

Behaviour follows ``docs/reference/sensors.md`` §1.5-§1.7: 12-bit values
left-justified in LSB/MSB pairs with a ``new_data`` flag in bit 0 of the LSB
(set when the axis is updated, cleared when the pair is read), soft reset by
0xB6 to 0x14, 32-frame FIFO with overrun flag, FIFO_DATA (0x3F) as a
non-incrementing data port, s8 temperature (23 degC + 0.5 K/LSB).

Assumptions (not in docs/reference/sensors.md, Bosch BMA2x2 reset values): power-on PMU_RANGE
0x03 (+-2 g), PMU_BW 0x0F, everything else 0; PMU_BW codes below 0x08 act as
0x08 and above 0x0F as 0x0F (§1.7 "commonly documented as clamped"); FIFO
frames carry ``new_data`` = 0; an empty FIFO reads as zeros. A burst read is one
snapshot (the MSB shadowing of §1.1 is therefore implicit).

Strict where the data sheet is (docs/reference/conformance-bmx055.md): for 1.8 ms
after a soft reset the registers take no writes; samples only in normal mode; in
deep-suspend only PMU_LPW and the soft reset take writes; read-only registers
(chip id, data, temperature, interrupt and FIFO status) ignore writes.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imustation.clock import Clock
from imustation.drivers import bmx055_accel as chip
from imustation.drivers.sim import filters
from imustation.drivers.sim.faults import FaultPlan
from imustation.drivers.sim.regfile import RegisterFileChip
from imustation.drivers.sim.sources import SignalSource, fits, with_filter

POR_RANGE_CODE = 0x03
POR_BW_CODE = 0x0F
#: after the soft reset the registers take no writes for this long (BMA2x2 data sheets, as
#: Linux bmc150-accel quotes them: "A delay of 1.8ms after reset is required")
SOFTRESET_STARTUP_S = 0.0018
#: PMU_LPW bits 7:5 of deep-suspend
LPW_DEEP_SUSPEND = 0x20
_BW_MIN, _BW_MAX = chip.BW_TABLE[0].code, chip.BW_TABLE[-1].code
_DATA = range(chip.REG_ACCD_X_LSB, chip.REG_ACCD_X_LSB + 6)
#: temperature, interrupt status 0..3, FIFO status: read-only
_STATUS = frozenset({chip.REG_TEMP, 0x09, 0x0A, 0x0B, 0x0C, chip.REG_FIFO_STATUS})
#: 12-bit signed range of the counts
_MIN12, _MAX12 = -2048, 2047


class BMA2x2Sim(RegisterFileChip):
    """BMX055 accelerometer die on a simulated I2C bus.

    Parameters
    ----------
    clock : the station clock (virtual in simulation).
    source_factory : ``fs_hz -> SignalSource`` giving X/Y/Z specific force in
        m/s^2 (gravity included); called when the chip starts producing at a (new) ODR.
    plan : fault plan (``reset``, ``stuck_fifo`` act on the chip).
    """

    NO_INCREMENT = frozenset({chip.REG_FIFO_DATA})

    def __init__(self, clock: Clock, source_factory: Callable[[float], SignalSource], plan: FaultPlan | None = None):
        super().__init__()
        self.clock = clock
        self.plan = plan
        self.source_factory = source_factory
        self.source: SignalSource | None = None
        self.sim_resets = 0
        #: samples drawn since power-on (test back door)
        self.sim_produced = 0
        #: writes ignored (starting after a reset, or in deep suspend) (test back door)
        self.sim_ignored_writes = 0
        self._power_on()
        self.ready_ns = self.clock.now_ns()  # powered up long before the station opens it

    # -- state ------------------------------------------------------------------------
    def _power_on(self) -> None:
        self.regs[:] = bytes(256)
        self.regs[chip.REG_CHIP_ID] = chip.CHIP_ID_VALUE
        self.regs[chip.REG_PMU_RANGE] = POR_RANGE_CODE
        self.regs[chip.PMU_BW.reg] = POR_BW_CODE
        self.fifo = bytearray()
        self.overrun = False
        self.new = np.zeros(3, dtype=bool)
        self.ready_ns = self.clock.now_ns() + int(SOFTRESET_STARTUP_S * 1e9)
        self._restart_timing()

    def _restart_timing(self) -> None:
        self.t_start_ns = self.clock.now_ns()
        self.produced = 0
        self.latest = np.zeros(3, dtype=np.int16)
        odr = self.odr_hz
        out_filter = filters.bma2x2(min(max(chip.PMU_BW.decode(self.regs[chip.PMU_BW.reg]), _BW_MIN), _BW_MAX))
        if not fits(self.source, odr, out_filter):
            self.source = with_filter(self.source_factory(odr), out_filter)

    @property
    def odr_hz(self) -> float:
        code = min(max(chip.PMU_BW.decode(self.regs[chip.PMU_BW.reg]), _BW_MIN), _BW_MAX)
        return next(r.odr_hz for r in chip.BW_TABLE if r.code == code)

    @property
    def scale(self) -> float:
        code = self.regs[chip.REG_PMU_RANGE]
        row = next((r for r in chip.RANGE_TABLE if r.code == code), chip.RANGE_TABLE[0])
        return row.scale

    @property
    def fifo_mode(self) -> int:
        return chip.FIFO_MODE.decode(self.regs[chip.FIFO_MODE.reg])

    @property
    def normal_mode(self) -> bool:
        return self.regs[chip.REG_PMU_LPW] >> 5 == 0

    def _advance(self) -> None:
        """Draw every sample due by now; update data registers and the FIFO.

        Faults: ``reset`` is a power-on reset; during ``stuck_fifo`` the sensor
        goes on (data registers, ``new_data``) but the FIFO receives nothing.
        """
        if self.plan is not None and self.plan.fire("reset"):
            self.sim_resets += 1
            self._power_on()
            return
        if not self.normal_mode:
            self._restart_timing()
            return
        due = (self.clock.now_ns() - self.t_start_ns) * self.odr_hz / 1e9
        n = int(due) - self.produced
        if n <= 0:
            return
        assert self.source is not None
        values = self.source.next(n)
        counts = np.clip(np.rint(values / self.scale), _MIN12, _MAX12).astype(np.int16)
        self.produced += n
        self.sim_produced += n
        self.latest = counts[-1]
        self.new[:] = True
        if self.plan is not None and self.plan.active("stuck_fifo"):
            return
        mode = self.fifo_mode
        if mode == chip.FIFO_MODE_BYPASS:
            return
        depth = chip.FIFO_DEPTH_FRAMES * chip.FIFO_FRAME_BYTES
        frames = (counts[-chip.FIFO_DEPTH_FRAMES :].astype("<i2") << 4).astype("<i2").tobytes()
        if len(self.fifo) + n * chip.FIFO_FRAME_BYTES > depth:
            self.overrun = True
        if mode == chip.FIFO_MODE_STREAM:  # keep the newest frames
            self.fifo += frames
            del self.fifo[: max(0, len(self.fifo) - depth)]
        else:  # FIFO mode: stop when full
            self.fifo += frames[: max(0, depth - len(self.fifo))]

    # -- register hooks ----------------------------------------------------------------
    def before_read(self, reg: int, n: int) -> None:
        self._advance()
        raw = (self.latest.astype("<i2") << 4).astype("<i2") | self.new.astype("<i2")
        self.regs[chip.REG_ACCD_X_LSB : chip.REG_ACCD_X_LSB + 6] = raw.astype("<i2").tobytes()
        t_s = (self.clock.now_ns() - self.t_start_ns) / 1e9
        assert self.source is not None
        temp = self.source.temperature(t_s)
        raw_t = int(np.clip(round((temp - chip.TEMP_OFFSET_C) / chip.TEMP_SCALE_C), -128, 127))
        self.regs[chip.REG_TEMP] = raw_t & 0xFF
        frames = len(self.fifo) // chip.FIFO_FRAME_BYTES
        self.regs[chip.REG_FIFO_STATUS] = (0x80 if self.overrun else 0) | min(frames, 0x7F)

    def on_read(self, reg: int) -> int:
        value = self.regs[reg]
        if reg in _DATA:
            # reading either byte of an axis clears its new_data flag (kept in this read's LSB)
            axis = (reg - chip.REG_ACCD_X_LSB) // 2
            self.new[axis] = False
            self.regs[chip.REG_ACCD_X_LSB + 2 * axis] &= 0xFE
        return value

    def read_stream(self, reg: int, n: int) -> bytes:
        out = bytes(self.fifo[:n])
        del self.fifo[:n]
        return out + bytes(n - len(out))

    def on_write(self, reg: int, value: int) -> None:
        if reg == chip.REG_SOFTRESET:
            if value == chip.SOFTRESET_CMD:
                self.sim_resets += 1
                self._power_on()
            return
        if reg == chip.REG_CHIP_ID or reg in _DATA or reg in _STATUS:
            return  # read-only
        deep_suspend = self.regs[chip.REG_PMU_LPW] >> 5 == LPW_DEEP_SUSPEND >> 5
        if self.clock.now_ns() < self.ready_ns or (deep_suspend and reg != chip.REG_PMU_LPW):
            self.sim_ignored_writes += 1  # starting after the soft reset, or in deep suspend
            return
        self._advance()
        self.regs[reg] = value
        if reg in (chip.PMU_BW.reg, chip.REG_PMU_RANGE, chip.REG_PMU_LPW):
            self._restart_timing()
        elif reg == chip.FIFO_MODE.reg:
            # writing FIFO_CONFIG_1 clears the FIFO and its overrun flag
            self.fifo.clear()
            self.overrun = False
