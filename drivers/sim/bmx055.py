"""Byte-level simulator of the BMX055 gyroscope die (BMG160 register set).

Behaviour follows ``docs/reference/sensors.md`` §1: CHIP_ID 0x0F, BW reads
back with the reserved bit 7 set, soft reset by 0xB6 to 0x14, 100-frame FIFO
with overrun flag in stream mode, FIFO_DATA (0x3F) as a non-incrementing data
port, little-endian s16 rates, s8 temperature (23 degC + 0.5 K/LSB).

Samples are produced on the station's clock at the configured ODR: each read
first draws every sample that became due since the last one from the signal
source, so a virtual clock gives hours of data in seconds.

Strict where the data sheet is (docs/reference/conformance-bmx055.md): for 30 ms
after a soft reset the registers take no writes; in suspend and deep-suspend
(LPM1) the chip samples nothing and takes no writes but LPM1 and the soft reset;
bypass mode collects nothing, FIFO mode stops when full, stream mode keeps the
newest frames; read-only registers (chip id, data, temperature, interrupt and
FIFO status, BW bit 7) ignore writes.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imustation.clock import Clock
from imustation.drivers import bmx055 as chip
from imustation.drivers.sim import filters
from imustation.drivers.sim.faults import FaultPlan
from imustation.drivers.sim.regfile import RegisterFileChip
from imustation.drivers.sim.sources import SignalSource, fits, with_filter

#: power-on BW code (datasheet reset value not in docs/reference/sensors.md; 0x00 = 2000 Hz/523 Hz assumed)
POR_BW_CODE = 0x00
BW_RESERVED_BIT = 0x80  # §1.3: "A mock reading back BW should return 0x80 | code"
#: after the soft reset the registers take no writes for this long (BMG160 data sheet, as
#: Linux bmg160_core quotes it: "A delay of 30ms after reset is required")
SOFTRESET_STARTUP_S = 0.030
#: LPM1 bits: suspend (bit 7), deep suspend (bit 5); 0x00 = normal
LPM1_SUSPEND, LPM1_DEEP_SUSPEND = 0x80, 0x20
#: chip id, rate data, temperature, interrupt status 0..3, FIFO status
_READ_ONLY = frozenset({chip.REG_CHIP_ID, *range(chip.REG_RATE_X_LSB, 0x0D), chip.REG_FIFO_STATUS})
#: FIFO_CONFIG_1 mode bits 7:6
FIFO_MODE_BYPASS, FIFO_MODE_FIFO = 0, 1


_ODR_BY_CODE = {r.code: float(r.odr_hz) for r in chip.ODR_TABLE}


class BMG160Sim(RegisterFileChip):
    """BMX055 gyro die on a simulated I2C bus.

    Parameters
    ----------
    clock : the station clock (virtual in simulation).
    source_factory : ``fs_hz -> SignalSource`` giving X/Y/Z rate in rad/s;
        called when the chip starts producing at a (new) ODR.
    """

    NO_INCREMENT = frozenset({chip.REG_FIFO_DATA})

    def __init__(self, clock: Clock, source_factory: Callable[[float], SignalSource], plan: FaultPlan | None = None):
        super().__init__()
        self.clock = clock
        self.plan = plan
        self.source_factory = source_factory
        self.source: SignalSource | None = None
        self.sim_resets = 0
        #: writes ignored (starting after a reset, or suspended) (test back door)
        self.sim_ignored_writes = 0
        self._power_on()
        self.ready_ns = self.clock.now_ns()  # powered up long before the station opens it

    # -- state ------------------------------------------------------------------------
    def _power_on(self) -> None:
        self.regs[:] = bytes(256)
        self.regs[chip.REG_CHIP_ID] = chip.CHIP_ID_VALUE
        self.regs[chip.BW.reg] = BW_RESERVED_BIT | POR_BW_CODE
        self.fifo = bytearray()
        self.overrun = False
        self.ready_ns = self.clock.now_ns() + int(SOFTRESET_STARTUP_S * 1e9)
        self._restart_timing()

    def _restart_timing(self) -> None:
        self.t_start_ns = self.clock.now_ns()
        self.produced = 0
        self.latest = np.zeros(3, dtype="<i2")
        odr = self.odr_hz
        out_filter = filters.bmg160(chip.BW.decode(self.regs[chip.BW.reg]))
        if not fits(self.source, odr, out_filter):
            self.source = with_filter(self.source_factory(odr), out_filter)

    @property
    def odr_hz(self) -> float:
        return _ODR_BY_CODE[chip.BW.decode(self.regs[chip.BW.reg])]

    @property
    def scale(self) -> float:
        code = chip.RANGE.decode(self.regs[chip.RANGE.reg])
        # codes 5-7 are reserved: taken as code 0 (behaviour UNCONFIRMED; the driver never writes them)
        return next((r.scale for r in chip.RANGE_TABLE if r.code == code), chip.RANGE_TABLE[0].scale)

    @property
    def suspended(self) -> bool:
        return bool(self.regs[chip.REG_LPM1] & (LPM1_SUSPEND | LPM1_DEEP_SUSPEND))

    @property
    def fifo_mode(self) -> int:
        return chip.FIFO_MODE.decode(self.regs[chip.FIFO_MODE.reg])

    def _advance(self) -> None:
        """Draw every sample due by now; push them into the FIFO (stream mode).

        Faults: ``reset`` is a power-on reset; during ``stuck_fifo`` samples are
        drawn (the noise goes on) but the FIFO receives none of them.
        """
        if self.plan is not None and self.plan.fire("reset"):
            self.sim_resets += 1
            self._power_on()
            return
        if self.suspended:
            self._restart_timing()  # no samples while suspended
            return
        due = (self.clock.now_ns() - self.t_start_ns) * self.odr_hz / 1e9
        n = int(due) - self.produced
        if n <= 0:
            return
        assert self.source is not None
        rates = self.source.next(n)
        # np.minimum/np.maximum: np.clip's Python wrapper costs more than the work on small blocks
        counts = np.minimum(np.maximum(np.rint(rates / self.scale), -32768.0), 32767.0).astype("<i2")
        self.produced += n
        self.latest = counts[-1]
        if self.plan is not None and self.plan.active("stuck_fifo"):
            return
        mode = self.fifo_mode
        if mode not in (FIFO_MODE_FIFO, chip.FIFO_MODE_STREAM):
            return  # bypass (or the reserved mode 3): the FIFO collects nothing
        depth = chip.FIFO_DEPTH_FRAMES * chip.FIFO_FRAME_BYTES
        if len(self.fifo) + n * chip.FIFO_FRAME_BYTES > depth:
            self.overrun = True
        if mode == chip.FIFO_MODE_STREAM:  # keep the newest frames
            self.fifo += counts[-chip.FIFO_DEPTH_FRAMES :].tobytes()
            del self.fifo[: max(0, len(self.fifo) - depth)]
        else:  # FIFO mode: stop when full
            self.fifo += counts[: chip.FIFO_DEPTH_FRAMES].tobytes()[: max(0, depth - len(self.fifo))]

    # -- register hooks ----------------------------------------------------------------
    def before_read(self, reg: int, n: int) -> None:
        self._advance()
        self.regs[chip.REG_RATE_X_LSB : chip.REG_RATE_X_LSB + 6] = self.latest.tobytes()
        t_s = (self.clock.now_ns() - self.t_start_ns) / 1e9
        assert self.source is not None
        temp = self.source.temperature(t_s)
        raw = min(127, max(-128, round((temp - chip.TEMP_OFFSET_C) / chip.TEMP_SCALE_C)))
        self.regs[chip.REG_TEMP] = raw & 0xFF
        frames = len(self.fifo) // chip.FIFO_FRAME_BYTES
        self.regs[chip.REG_FIFO_STATUS] = (0x80 if self.overrun else 0) | min(frames, 0x7F)

    def read_stream(self, reg: int, n: int) -> bytes:
        out = bytes(self.fifo[:n])
        del self.fifo[:n]
        return out + bytes(n - len(out))  # an empty FIFO reads as zeros (UNCONFIRMED)

    def on_write(self, reg: int, value: int) -> None:
        if reg == chip.REG_SOFTRESET:
            if value == chip.SOFTRESET_CMD:
                self.sim_resets += 1
                self._power_on()
            return
        if reg in _READ_ONLY:
            return
        if self.clock.now_ns() < self.ready_ns or (self.suspended and reg != chip.REG_LPM1):
            self.sim_ignored_writes += 1  # starting after the soft reset, or suspended
            return
        self._advance()
        if reg == chip.BW.reg:
            self.regs[reg] = BW_RESERVED_BIT | (value & 0x07)
            self._restart_timing()
            return
        self.regs[reg] = value
        if reg == chip.REG_LPM1:
            self._restart_timing()
        if reg == chip.FIFO_MODE.reg:
            # writing FIFO_CONFIG_1 clears the FIFO and its overrun flag
            self.fifo.clear()
            self.overrun = False
