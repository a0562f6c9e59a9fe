"""Microchip MCP9804 ambient thermometer (JC-42.4-style registers), I2C.

Register map and worked examples: ``docs/reference/sensors.md`` §7 (sources
there: Microchip DS22203C [MCP-DS], Linux ``jc42.c`` [L-JC42]). A thermometer,
not a streaming device: the station polls :meth:`MCP9804.read_celsius` at
``rate_hz`` (the paper records three of them at 1 Hz with 0.0625 degC
resolution, §IV-A).

Protocol: every access first writes the register pointer (bits 3:0; bits 7:4
zero); a read then returns the register MSB first after a repeated START.
:meth:`RegisterDevice.read` does exactly this (write pointer, read n bytes), so
the 16-bit registers are ``read(ptr, 2)`` and the 8-bit resolution register
``read(RESOLUTION, 1)``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from imustation.drivers.base import Setting, Sleep, check_settings
from imustation.drivers.bus.base import RegisterDevice
from imustation.errors import DeviceError, SettingError

# --- registers (docs/reference/sensors.md §7, [MCP-DS] Table 5-1) -----------------
PTR_CONFIG = 0x01  # bit8 SHDN, §7 Register 5-2
CONFIG_SHDN = 1 << 8
PTR_T_A = 0x05  # ambient temperature, 16 bits, read-only
PTR_MANUFACTURER = 0x06
MANUFACTURER_ID = 0x0054  # §7 [MCP-DS][L-JC42]
PTR_DEVICE = 0x07  # device id (upper byte) / revision (lower byte)
DEVICE_ID = 0x02  # upper byte 0x02; POR 0x0201, §7 Table 5-3 (Linux matches 0x0200 mask 0xFFFC)
PTR_RESOLUTION = 0x08  # 8 bits, bits1:0, §7 Register 5-7
POINTER_MASK = 0x0F  # pointer bits 3:0; bits 7:4 must be 0, §7 Register 5-1

# T_A register, §7 Register 5-4
TA_FLAG_CRIT = 1 << 15  # T_A >= T_CRIT
TA_FLAG_UPPER = 1 << 14  # T_A > T_UPPER
TA_FLAG_LOWER = 1 << 13  # T_A < T_LOWER
TA_VALUE_BITS = 13  # bits 12:0: two's complement, bit 12 sign
TA_LSB_C = 0.0625


@dataclass(frozen=True)
class ResolutionRow:
    code: int
    resolution_c: float
    conversion_s: float  # t_conv, §7 Register 5-7


#: Resolution register 0x08 bits 1:0, docs/reference/sensors.md §7 [MCP-DS]
RESOLUTION_TABLE: tuple[ResolutionRow, ...] = (
    ResolutionRow(0b00, 0.5, 0.030),
    ResolutionRow(0b01, 0.25, 0.065),
    ResolutionRow(0b10, 0.125, 0.130),
    ResolutionRow(0b11, 0.0625, 0.250),
)
RESOLUTION_MASK = 0x03

#: highest polling rate accepted: one fresh conversion per read at 0.0625 degC (250 ms)
MAX_RATE_HZ = 4.0


@dataclass(frozen=True)
class Reading:
    """A decoded T_A register: temperature and the three comparator flags."""

    celsius: float
    crit: bool
    upper: bool
    lower: bool


def decode_ta(msb: int, lsb: int) -> Reading:
    """Two T_A bytes (MSB first) -> :class:`Reading` (§7: 13-bit two's complement x 0.0625 degC)."""
    word = (msb << 8) | lsb
    value = word & ((1 << TA_VALUE_BITS) - 1)
    if value & (1 << (TA_VALUE_BITS - 1)):
        value -= 1 << TA_VALUE_BITS
    return Reading(value * TA_LSB_C, bool(word & TA_FLAG_CRIT), bool(word & TA_FLAG_UPPER), bool(word & TA_FLAG_LOWER))


def encode_ta(celsius: float, *, crit: bool = False, upper: bool = False, lower: bool = False) -> bytes:
    """Inverse of :func:`decode_ta` (value truncated toward minus infinity to 0.0625 degC)."""
    value = math.floor(celsius / TA_LSB_C) & ((1 << TA_VALUE_BITS) - 1)
    word = value | (TA_FLAG_CRIT if crit else 0) | (TA_FLAG_UPPER if upper else 0) | (TA_FLAG_LOWER if lower else 0)
    return word.to_bytes(2, "big")


def resolution_row(resolution_c: float) -> ResolutionRow:
    for row in RESOLUTION_TABLE:
        if row.resolution_c == resolution_c:
            return row
    raise ValueError(f"no resolution code for {resolution_c} degC")


class MCP9804:
    """One MCP9804 thermometer.

    Parameters
    ----------
    regs : register device at the thermometer's address (0x18..0x1F).
    settings : validated by :meth:`check_settings`: ``rate_hz`` (polling rate,
        Hz, for the station) and ``resolution_c`` (degC).
    sleep : delay function (the station's clock, virtual in simulation).
    """

    name: ClassVar[str] = "mcp9804"
    bus_kind: ClassVar[str] = "i2c"
    default_address: ClassVar[int] = 0x18  # A2..A0 = 000, §7 [MCP-DS] Table 3-2
    SETTINGS: ClassVar[tuple[Setting, ...]] = (
        Setting("rate_hz", 1.0, None, f"readings per second, > 0 and <= {MAX_RATE_HZ:g}"),
        Setting("resolution_c", 0.0625, tuple(r.resolution_c for r in RESOLUTION_TABLE), "resolution, degC"),
    )

    def __init__(self, regs: RegisterDevice, settings: Mapping[str, Any], *, sleep: Sleep = time.sleep):
        self.regs = regs
        self.settings = self.check_settings(settings)
        self._sleep = sleep
        self._res = resolution_row(self.settings["resolution_c"])

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        out = check_settings(cls.name, cls.SETTINGS, settings)
        rate = out["rate_hz"]
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate <= MAX_RATE_HZ:
            raise SettingError(
                f"rate_hz = {rate!r}: driver 'mcp9804' allows a number of Hz > 0 and <= {MAX_RATE_HZ:g} "
                "(one conversion takes 250 ms at 0.0625 degC)"
            )
        out["rate_hz"] = float(rate)
        return out

    def _read16(self, ptr: int) -> int:
        return int.from_bytes(self.regs.read(ptr, 2), "big")

    def open(self) -> str:
        """Check the ids, leave shutdown, set the resolution; return the identity string."""
        manufacturer = self._read16(PTR_MANUFACTURER)
        device = self._read16(PTR_DEVICE)
        if manufacturer != MANUFACTURER_ID or device >> 8 != DEVICE_ID:
            raise DeviceError(
                f"{self.regs.where}: expected MCP9804 (manufacturer 0x{MANUFACTURER_ID:04X}, "
                f"device 0x{DEVICE_ID:02X}xx), "
                f"found manufacturer 0x{manufacturer:04X} device 0x{device:04X}"
                " - check the wiring, the address and the driver name"
            )
        config = self._read16(PTR_CONFIG)
        if config & CONFIG_SHDN:
            self.regs.write(PTR_CONFIG, (config & ~CONFIG_SHDN).to_bytes(2, "big"))
        self.regs.write(PTR_RESOLUTION, bytes([self._res.code]))
        self._check_resolution("read back")
        # the first conversion at the new resolution must complete before T_A is valid
        self._sleep(self._res.conversion_s)
        return f"manufacturer=0x{manufacturer:04X} device=0x{device:04X}"

    def _check_resolution(self, what: str) -> None:
        code = self.regs.read(PTR_RESOLUTION, 1)[0] & RESOLUTION_MASK
        if code != self._res.code:
            raise DeviceError(
                f"{self.regs.where}: resolution register {what} 0b{code:02b}, set 0b{self._res.code:02b}"
                + ("; chip reset?" if what == "lost" else "")
            )

    def read_reading(self) -> Reading:
        """T_A with its flags; raises :class:`DeviceError` if the resolution setting was lost."""
        self._check_resolution("lost")
        msb, lsb = self.regs.read(PTR_T_A, 2)
        return decode_ta(msb, lsb)

    def read_celsius(self) -> float:
        """Ambient temperature, degC (flags ignored)."""
        return self.read_reading().celsius

    def close(self) -> None:
        pass
