"""I2C bus through smbus2 (``i2c:N`` -> ``/dev/i2c-N``).

:class:`I2CBus` wraps any object with smbus2's ``SMBus`` interface: the real
``smbus2.SMBus`` or the simulated :class:`imustation.drivers.sim.i2c.SimSMBus`.
Register reads use a combined write-then-read with repeated start
(``i2c_rdwr``), so bursts are not limited to SMBus's 32 bytes and the register
pointer cannot be disturbed between the two messages.

Linux reports a NACK as ENXIO or EREMOTEIO and a bus fault as EIO or ETIMEDOUT;
these are retried a bounded number of times, then raised as typed errors with
the bus, address and register in the message.
"""

from __future__ import annotations

import errno
from typing import Any

from smbus2 import i2c_msg

from imustation.drivers.bus.url import parse_bus_url
from imustation.errors import BusClosed, BusError, BusTimeout, NackError

_NACK = {errno.ENXIO, errno.EREMOTEIO}
_RETRY = _NACK | {errno.EIO, errno.EAGAIN, errno.ETIMEDOUT}
_GONE = {errno.ENODEV, errno.EBADF, errno.ENOENT}

#: attempts per transaction before an error is raised
DEFAULT_RETRIES = 3


class I2CBus:
    """An I2C adapter; :meth:`device` gives the register view of one address."""

    def __init__(self, smbus: Any, url: str, *, retries: int = DEFAULT_RETRIES):
        self._smbus = smbus
        self.url = url
        self.retries = int(retries)
        #: transactions that needed a retry (a health figure for the status line)
        self.retried = 0

    def device(self, address: int) -> I2CDevice:
        return I2CDevice(self, address)

    def _transfer(self, address: int, reg: int, msgs: list, what: str) -> None:
        last: OSError | None = None
        for _attempt in range(self.retries):
            try:
                self._smbus.i2c_rdwr(*msgs)
                return
            except OSError as exc:
                last = exc
                if exc.errno in _GONE:
                    raise BusClosed(f"{self.url}@0x{address:02X}: bus gone during {what}: {exc}") from exc
                if exc.errno not in _RETRY:
                    break
                self.retried += 1
        assert last is not None
        where = f"{self.url}@0x{address:02X} reg 0x{reg:02X}"
        if last.errno in _NACK:
            raise NackError(f"{where}: no acknowledge during {what} ({self.retries} tries)") from last
        if last.errno == errno.ETIMEDOUT:
            raise BusTimeout(f"{where}: timeout during {what}") from last
        raise BusError(f"{where}: {what} failed: {last}") from last

    def read_reg(self, address: int, reg: int, n: int) -> bytes:
        wr = i2c_msg.write(address, [reg])
        rd = i2c_msg.read(address, n)
        self._transfer(address, reg, [wr, rd], f"read of {n} bytes")
        return bytes(rd)

    def write_reg(self, address: int, reg: int, data: bytes) -> None:
        msg = i2c_msg.write(address, bytes([reg]) + bytes(data))
        self._transfer(address, reg, [msg], f"write of {len(data)} bytes")

    def close(self) -> None:
        self._smbus.close()


class I2CDevice:
    """Register view of one 7-bit address on an :class:`I2CBus`."""

    def __init__(self, bus: I2CBus, address: int):
        if not 0x03 <= address <= 0x77:
            raise ValueError(f"I2C address 0x{address:02X} outside 0x03..0x77")
        self.bus = bus
        self.address = address
        self.where = f"{bus.url}@0x{address:02X}"

    def read(self, reg: int, n: int) -> bytes:
        return self.bus.read_reg(self.address, reg, n)

    def write(self, reg: int, data: bytes) -> None:
        self.bus.write_reg(self.address, reg, data)

    def update_bits(self, reg: int, mask: int, value: int) -> None:
        old = self.read(reg, 1)[0]
        new = (old & ~mask) | (value & mask)
        if new != old:
            self.write(reg, bytes([new]))


def open_i2c(url: str) -> I2CBus:
    """Open a real I2C adapter from ``i2c:N``."""
    parsed = parse_bus_url(url, ("i2c",))
    try:
        number = int(parsed.target)
    except ValueError:
        raise BusError(f"bus {url!r}: expected i2c:N with N the adapter number (/dev/i2c-N)") from None
    from smbus2 import SMBus

    try:
        smbus = SMBus(number)
    except (FileNotFoundError, PermissionError, OSError) as exc:
        raise BusClosed(f"{url}: cannot open /dev/i2c-{number}: {exc.strerror or exc}") from exc
    return I2CBus(smbus, url, retries=int(parsed.params.get("retries", DEFAULT_RETRIES)))
