"""The register-access seam between chip drivers and buses (regmap-like)."""

from __future__ import annotations

from typing import Protocol


class RegisterDevice(Protocol):
    """One addressed chip on a bus, seen as 8-bit registers.

    ``where`` names the device for messages (``"i2c:1@0x68"``).
    """

    where: str

    def read(self, reg: int, n: int) -> bytes:
        """Read ``n`` bytes starting at ``reg`` (one burst, auto-increment as the chip does)."""
        ...

    def write(self, reg: int, data: bytes) -> None:
        """Write ``data`` starting at ``reg`` in one transaction."""
        ...

    def update_bits(self, reg: int, mask: int, value: int) -> None:
        """Read-modify-write the bits of ``mask`` in ``reg``."""
        ...
