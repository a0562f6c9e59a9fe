"""Register-file chip base for simulators of 8-bit-register I2C chips.

A write message sets the register pointer from its first byte and writes the
rest with auto-increment; a read message reads from the pointer with
auto-increment. Subclasses hook registers whose reads or writes have effects
(FIFO data, soft reset, latched MSBs).
"""

from __future__ import annotations


class RegisterFileChip:
    """256 bytes of registers with a pointer; override the ``on_*`` hooks."""

    #: registers whose address does not auto-increment on burst reads (FIFO data)
    NO_INCREMENT: frozenset[int] = frozenset()

    def __init__(self) -> None:
        self.regs = bytearray(256)
        self.pointer = 0

    # -- wire protocol ------------------------------------------------------------
    def i2c_write(self, data: bytes) -> None:
        if not data:
            return
        self.pointer = data[0]
        for byte in data[1:]:
            self.on_write(self.pointer, byte)
            self.pointer = (self.pointer + 1) & 0xFF

    def i2c_read(self, n: int) -> bytes:
        self.before_read(self.pointer, n)
        if self.pointer in self.NO_INCREMENT:
            out = self.read_stream(self.pointer, n)
        else:
            out = bytes(self.on_read(self.pointer + i & 0xFF) for i in range(n))
            self.pointer = (self.pointer + n) & 0xFF
        return out

    # -- hooks ------------------------------------------------------------------------
    def before_read(self, reg: int, n: int) -> None:
        """Called once per read message (refresh dynamic registers here)."""

    def on_read(self, reg: int) -> int:
        return self.regs[reg]

    def on_write(self, reg: int, value: int) -> None:
        self.regs[reg] = value

    def read_stream(self, reg: int, n: int) -> bytes:
        """Burst read of a non-incrementing register (a FIFO data port)."""
        return bytes(self.on_read(reg) for _ in range(n))
