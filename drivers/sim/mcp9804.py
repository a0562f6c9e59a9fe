"""Byte-level simulator of the MCP9804 thermometer (docs/reference/sensors.md §7).

A register-pointer chip with 16-bit registers (MSB first) and the 8-bit
resolution register. Conversions complete every t_conv of the selected
resolution (30/65/130/250 ms); T_A holds the last completed one, truncated to
the resolution, with the three comparator flags computed against T_CRIT /
T_UPPER / T_LOWER (all 0 degC at power-on, so a warm room reads with the
>= T_CRIT and > T_UPPER flags set, as in §7's worked example ``C1 90``).
Shutdown (CONFIG bit 8) stops conversions; T_A keeps its last value.

Assumptions (UNCONFIRMED, not in docs/reference/sensors.md): a pointer with bits 7:4 set is
ignored (the pointer keeps its value); reading more bytes than a register has
repeats its bytes; T_A reads 0x0000 until the first conversion completes.

Strict where the data sheet is (docs/reference/conformance-mcp9804.md): T_A, the
capability and the id registers ignore writes; CONFIG's T_CRIT lock (bit 7) and
window lock (bit 6) stay set until a reset and freeze T_CRIT / T_UPPER and
T_LOWER; SHDN cannot be set while a lock bit is set (MCP9804 data sheet DS22203C,
Register 5-2).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from imustation.clock import Clock
from imustation.drivers import mcp9804 as chip
from imustation.drivers.sim.faults import FaultPlan

PTR_T_UPPER, PTR_T_LOWER, PTR_T_CRIT = 0x02, 0x03, 0x04  # §7
CAPABILITY_POR = 0x001F  # §7 Table 5-1
DEVICE_POR = 0x0201  # §7 Table 5-3
RESOLUTION_POR = 0x03  # 0.0625 degC, §7 Register 5-7
#: limit registers: bit 12 sign, bits 11:2 value (0.25 degC); other bits read 0, §7
LIMIT_MASK = 0x1FFC
_WRITABLE16 = (chip.PTR_CONFIG, PTR_T_UPPER, PTR_T_LOWER, PTR_T_CRIT)
#: CONFIG lock bits (Register 5-2): set once, cleared only by a reset
CONFIG_CRIT_LOCK, CONFIG_WIN_LOCK = 1 << 7, 1 << 6


def _s13(word: int) -> int:
    value = word & 0x1FFF
    return value - 0x2000 if value & 0x1000 else value


class MCP9804Sim:
    """An MCP9804 on a simulated I2C bus.

    Parameters
    ----------
    clock : the station clock.
    temperature : ``t_s -> degC``, the ambient temperature at time ``t_s`` (s since creation).
    plan : fault plan (``reset`` acts on the chip; bus faults act on the bus).
    """

    def __init__(self, clock: Clock, temperature: Callable[[float], float], plan: FaultPlan | None = None):
        self.clock = clock
        self.temperature = temperature
        self.plan = plan
        self.t0_ns = clock.now_ns()
        self.sim_resets = 0
        self._power_on()

    def _power_on(self) -> None:
        self.pointer = 0
        self.regs16 = {
            0x00: CAPABILITY_POR,
            chip.PTR_CONFIG: 0,
            PTR_T_UPPER: 0,
            PTR_T_LOWER: 0,
            PTR_T_CRIT: 0,
            chip.PTR_MANUFACTURER: chip.MANUFACTURER_ID,
            chip.PTR_DEVICE: DEVICE_POR,
        }
        self.resolution = RESOLUTION_POR
        self.ta_raw = 0  # 13-bit value, no conversion yet
        self._start_conversions()

    def _start_conversions(self) -> None:
        self.conv_start_ns = self.clock.now_ns()
        self.conversions = 0

    @property
    def conversion_s(self) -> float:
        return next(r.conversion_s for r in chip.RESOLUTION_TABLE if r.code == self.resolution & chip.RESOLUTION_MASK)

    def _advance(self) -> None:
        if self.plan is not None and self.plan.fire("reset"):
            self.sim_resets += 1
            self._power_on()
            return
        if self.regs16[chip.PTR_CONFIG] & chip.CONFIG_SHDN:
            return
        done = int((self.clock.now_ns() - self.conv_start_ns) / 1e9 / self.conversion_s)
        if done > self.conversions:
            self.conversions = done
            t_end_ns = self.conv_start_ns + done * self.conversion_s * 1e9
            celsius = self.temperature((t_end_ns - self.t0_ns) / 1e9)
            row = next(r for r in chip.RESOLUTION_TABLE if r.code == self.resolution & chip.RESOLUTION_MASK)
            # lower resolutions leave the low bits 0 (§7): truncate to the resolution step
            steps = math.floor(celsius / row.resolution_c)
            self.ta_raw = int(round(steps * row.resolution_c / chip.TA_LSB_C))

    def _ta_word(self) -> int:
        t = self.ta_raw
        word = t & 0x1FFF
        if t >= _s13(self.regs16[PTR_T_CRIT]):
            word |= chip.TA_FLAG_CRIT
        if t > _s13(self.regs16[PTR_T_UPPER]):
            word |= chip.TA_FLAG_UPPER
        if t < _s13(self.regs16[PTR_T_LOWER]):
            word |= chip.TA_FLAG_LOWER
        return word

    # -- wire protocol ------------------------------------------------------------
    def i2c_write(self, data: bytes) -> None:
        if not data:
            return
        if data[0] & ~chip.POINTER_MASK & 0xFF:
            return
        self._advance()
        self.pointer = data[0]
        payload = data[1:]
        if not payload:
            return
        if self.pointer == chip.PTR_RESOLUTION:
            self.resolution = payload[0] & chip.RESOLUTION_MASK
            self._start_conversions()
        elif self.pointer in _WRITABLE16 and len(payload) >= 2:
            word = (payload[0] << 8) | payload[1]
            config = self.regs16[chip.PTR_CONFIG]
            if self.pointer == PTR_T_CRIT and config & CONFIG_CRIT_LOCK:
                return  # locked until a reset
            if self.pointer in (PTR_T_UPPER, PTR_T_LOWER) and config & CONFIG_WIN_LOCK:
                return
            if self.pointer != chip.PTR_CONFIG:
                word &= LIMIT_MASK
            else:
                word |= config & (CONFIG_CRIT_LOCK | CONFIG_WIN_LOCK)  # a lock bit cannot be cleared
                if word & (CONFIG_CRIT_LOCK | CONFIG_WIN_LOCK) and not config & chip.CONFIG_SHDN:
                    word &= ~chip.CONFIG_SHDN  # shutdown cannot be entered while a lock bit is set
                if (config ^ word) & chip.CONFIG_SHDN and not word & chip.CONFIG_SHDN:
                    self._start_conversions()  # leaving shutdown starts converting again
            self.regs16[self.pointer] = word

    def i2c_read(self, n: int) -> bytes:
        self._advance()
        if self.pointer == chip.PTR_RESOLUTION:
            reg = bytes([self.resolution])
        elif self.pointer == chip.PTR_T_A:
            reg = self._ta_word().to_bytes(2, "big")
        else:
            reg = self.regs16.get(self.pointer, 0).to_bytes(2, "big")
        return (reg * (n // len(reg) + 1))[:n]
