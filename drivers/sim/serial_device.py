"""Base of serial device simulators (byte streams on the station clock)."""

from __future__ import annotations

from imustation.clock import Clock
from imustation.drivers.sim.faults import FaultPlan


class SerialDeviceSim:
    """A device at the far end of a simulated serial line.

    ``produce()`` returns the bytes the device has transmitted since the last
    call (on the station clock); ``receive(data)`` takes the host's bytes.
    ``baud`` is the device's fixed line rate, or ``None`` when it follows the
    port (a device configured to the rate the config names).
    """

    baud: int | None = None

    def __init__(self, clock: Clock, plan: FaultPlan | None = None):
        self.clock = clock
        self.plan = plan

    def unplugged(self) -> bool:
        return self.plan is not None and self.plan.active("disconnect")

    def produce(self) -> bytes:
        raise NotImplementedError

    def receive(self, data: bytes) -> None:
        raise NotImplementedError
