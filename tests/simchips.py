"""Test helpers: deterministic signal sources and a driver wired to its simulator."""

from __future__ import annotations

import numpy as np

from imustation.clock import VirtualClock
from imustation.drivers.bus.i2c import I2CBus
from imustation.drivers.sim.i2c import SimSMBus


class ConstantSource:
    """3-axis constant value (SI) and a fixed temperature, for exact decode checks."""

    def __init__(self, fs_hz, value, temp_c=27.0):
        self.fs_hz = fs_hz
        self.value = np.asarray(value, dtype=float)
        self.temp_c = temp_c

    def next(self, n):
        return np.tile(self.value, (n, 1))

    def temperature(self, t_s):
        return self.temp_c


class RampSource(ConstantSource):
    """Sample i of the stream is ``step * (i + 1)`` on every axis (counts which samples arrive)."""

    def __init__(self, fs_hz, step, temp_c=27.0):
        super().__init__(fs_hz, [0.0, 0.0, 0.0], temp_c)
        self.step = step
        self.i = 0

    def next(self, n):
        k = np.arange(self.i + 1, self.i + n + 1, dtype=float)
        self.i += n
        return np.repeat((k * self.step)[:, None], 3, axis=1)


def wire(driver_cls, chip, settings=None, address=None, clock=None):
    """A driver on a simulated bus carrying ``chip``; returns (driver, smbus)."""
    address = address or driver_cls.default_address
    smbus = SimSMBus({address: chip})
    bus = I2CBus(smbus, "sim:test")
    clock = clock or chip.clock
    return driver_cls(bus.device(address), settings or {}, sleep=clock.sleep), smbus


def new_clock():
    return VirtualClock()


class BurstLog:
    """Which samples an ADIS16448 simulator served, burst by burst (the truth a capture's holes are checked
    against: the chip has no counter). Patches the simulator class through ``monkeypatch``; ``started``
    records the station's start (clock ns) of every capture."""

    def __init__(self, monkeypatch):
        from imustation.acquisition.station import Station
        from imustation.drivers.sim.adis16448 import ADIS16448Sim

        self.served: list[tuple[int, int]] = []  # (clock ns, sample index since the chip's last restart)
        self.started: list[int] = []
        burst, start = ADIS16448Sim._burst, Station.start

        def logged_burst(sim, n):
            row = sim._newest()
            self.served.append((sim.clock.now_ns(), row + sim._chunk_first if row >= 0 else -1))
            return burst(sim, n)

        def logged_start(station, sink):
            start(station, sink)
            self.started.append(station.t0)

        monkeypatch.setattr(ADIS16448Sim, "_burst", logged_burst)
        monkeypatch.setattr(Station, "start", logged_start)

    def holes(self) -> list[int]:
        """Samples made and never read, hole by hole, from the station's start (the sample its start
        dropped counts as read) - for one chip, without restarts."""
        (t0,) = self.started
        served = np.array(self.served, dtype=np.int64)
        first = max(int(np.searchsorted(served[:, 0], t0, side="right")) - 1, 0)
        index = served[first:, 1]
        distinct = index[np.concatenate(([True], np.diff(index) != 0))]
        steps = np.diff(distinct)
        return (steps[steps > 1] - 1).tolist()
