"""Clocks: the host monotonic clock, and a virtual clock for simulated captures.

Both give nanoseconds since an arbitrary origin and a ``sleep(seconds)``. A
simulated capture runs on :class:`VirtualClock`, whose ``sleep`` only advances
the time, so hours of data are produced as fast as the machine allows; chip
simulators read the same clock to know how many samples are due.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    def now_ns(self) -> int: ...

    def sleep(self, seconds: float) -> None: ...


class MonotonicClock:
    """Host monotonic clock (``time.monotonic_ns``)."""

    virtual = False

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class VirtualClock:
    """A clock that advances only when someone sleeps on it."""

    virtual = True

    def __init__(self, start_ns: int = 0):
        self._now = int(start_ns)

    def now_ns(self) -> int:
        return self._now

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._now += int(round(seconds * 1e9))

    def advance_to(self, t_ns: int) -> None:
        self._now = max(self._now, int(t_ns))
