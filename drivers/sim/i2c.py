"""A simulated I2C adapter with smbus2's interface.

:class:`SimSMBus` stands in for ``smbus2.SMBus`` under the real
:class:`imustation.drivers.bus.i2c.I2CBus`, so the bus code (message building,
retries, error mapping) runs unchanged in simulation. Chips attached at an
address implement :class:`I2CTarget`: they see the bytes of each message, as a
chip on the wire does.
"""

from __future__ import annotations

import ctypes
import errno
from typing import Protocol

from smbus2 import i2c_msg

from imustation.drivers.sim.faults import FaultPlan

I2C_M_RD = 0x0001


class I2CTarget(Protocol):
    def i2c_write(self, data: bytes) -> None:
        """A write message addressed to this chip (first byte: register pointer)."""
        ...

    def i2c_read(self, n: int) -> bytes:
        """A read message: return ``n`` bytes from the current pointer."""
        ...


class SimSMBus:
    """smbus2-compatible adapter whose targets are chip simulators.

    Faults: a :class:`~imustation.drivers.sim.faults.FaultPlan` attached with a
    target applies to transactions addressed to it: ``disconnect`` (every
    transfer NACKed while active), ``nack`` (one transfer NACKed), ``short_read``
    (one read fails with EIO), ``corrupt`` (one bit of one read flipped),
    ``stall`` (one transaction takes ``duration_s``: the clock advances), ``slow``
    (every transaction of the window takes ``delay_s``).
    ``sim_fault`` (if set) is called with ``(address, msgs)`` before each
    transfer and may raise ``OSError`` (ad-hoc faults in tests).
    """

    def __init__(self, targets: dict[int, I2CTarget] | None = None):
        self.targets: dict[int, I2CTarget] = dict(targets or {})
        self.plans: dict[int, FaultPlan] = {}
        self.sim_fault = None
        self.sim_transactions = 0
        self.closed = False

    def attach(self, address: int, target: I2CTarget, plan: FaultPlan | None = None) -> None:
        self.targets[address] = target
        if plan is not None:
            self.plans[address] = plan

    def _target(self, address: int) -> I2CTarget:
        if self.closed:
            raise OSError(errno.EBADF, "bus closed")
        try:
            return self.targets[address]
        except KeyError:
            raise OSError(errno.ENXIO, f"no device at 0x{address:02X}") from None

    def i2c_rdwr(self, *msgs: i2c_msg) -> None:
        self.sim_transactions += 1
        if self.sim_fault is not None:
            self.sim_fault(msgs[0].addr, msgs)
        plan = self.plans.get(msgs[0].addr)
        if plan is not None:
            if plan.active("disconnect") or plan.fire("nack"):
                raise OSError(errno.ENXIO, "no acknowledge")
            stall = plan.fire_duration("stall")
            if stall:
                plan.clock.sleep(stall)
            slow = plan.delay_s("slow")
            if slow:
                plan.clock.sleep(slow)
        for msg in msgs:
            target = self._target(msg.addr)
            if msg.flags & I2C_M_RD:
                data = target.i2c_read(msg.len)
                if plan is not None and plan.fire("short_read"):
                    raise OSError(errno.EIO, "short read")
                if plan is not None and msg.len and plan.fire("corrupt"):
                    data = bytearray(data)
                    data[len(data) // 2] ^= 0x10
                    data = bytes(data)
                if len(data) != msg.len:
                    raise OSError(errno.EIO, "short read")
                ctypes.memmove(msg.buf, data, msg.len)
            else:
                target.i2c_write(bytes(msg))

    # the SMBus block calls, for drivers or tools that use them
    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int, force=None) -> list[int]:
        wr, rd = i2c_msg.write(i2c_addr, [register]), i2c_msg.read(i2c_addr, length)
        self.i2c_rdwr(wr, rd)
        return list(rd)

    def write_i2c_block_data(self, i2c_addr: int, register: int, data, force=None) -> None:
        self.i2c_rdwr(i2c_msg.write(i2c_addr, [register, *data]))

    def close(self) -> None:
        self.closed = True
