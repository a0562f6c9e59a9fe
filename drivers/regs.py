"""Register bit-field descriptors: a driver's register map reads like the datasheet.

``Field(reg, lsb, width)`` names a bit field once; drivers call
``field.encode(value)`` / ``field.decode(byte)`` or the read-modify-write helper
:func:`write_field`, so no shifting or masking is scattered through driver code.
"""

from __future__ import annotations

from dataclasses import dataclass

from imustation.drivers.bus.base import RegisterDevice


@dataclass(frozen=True)
class Field:
    """Bits ``lsb .. lsb+width-1`` of the 8-bit register ``reg``."""

    reg: int
    lsb: int = 0
    width: int = 8

    @property
    def mask(self) -> int:
        return ((1 << self.width) - 1) << self.lsb

    def encode(self, value: int) -> int:
        if not 0 <= value < (1 << self.width):
            raise ValueError(f"value {value} does not fit {self.width} bits of reg 0x{self.reg:02X}")
        return value << self.lsb

    def decode(self, byte: int) -> int:
        return (byte & self.mask) >> self.lsb


def write_field(dev: RegisterDevice, field: Field, value: int) -> None:
    """Read-modify-write ``field`` (a full-width field is written directly)."""
    if field.width == 8:
        dev.write(field.reg, bytes([field.encode(value)]))
    else:
        dev.update_bits(field.reg, field.mask, field.encode(value))
