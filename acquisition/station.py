"""The station: opens every configured device and records them into a run file.

One scheduler loop serves every device at its own poll interval (about 40 %
of its FIFO depth) on the station clock. With ``simulate=True`` every bus is
replaced by a simulated one carrying the chip's byte-level simulator, and the
clock is virtual: sleeping only advances time, so hours of data are recorded
as fast as the machine allows.
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imustation.acquisition.buses import BusFactory
from imustation.acquisition.config import DeviceConfig, StationConfig
from imustation.clock import Clock, MonotonicClock, VirtualClock
from imustation.drivers import DRIVERS, DriverInfo
from imustation.errors import BusError, DeviceError
from imustation.runfile import DeviceSpec, RunWriter

#: wall seconds between status reports
STATUS_INTERVAL_S = 1.0


@dataclass
class DeviceState:
    config: DeviceConfig
    driver: Any
    info: DriverInfo
    period_ns: float
    samples: int = 0
    lost: int = 0
    gaps: int = 0
    faults: int = 0
    last_t_ns: int | None = None
    temp_c: float = float("nan")
    failed: bool = False
    #: after a fault: the next block's loss is measured from time
    resync: bool = False
    failed_attempts: int = 0


@dataclass
class CaptureSummary:
    duration_s: float
    samples: dict[str, int]
    lost: dict[str, int]
    gaps: dict[str, int]
    wall_s: float
    stopped_early: bool = False
    events: list[str] = field(default_factory=list)


class Station:
    """Devices of a config, opened on real or simulated buses.

    Parameters
    ----------
    config : a validated :class:`StationConfig`.
    simulate : replace every bus and chip by its simulator (virtual clock).
    clock : override the clock (tests); default virtual when simulating.
    """

    def __init__(self, config: StationConfig, *, simulate: bool, clock: Clock | None = None):
        self.config = config
        self.simulate = simulate
        self.clock: Clock = clock or (VirtualClock() if simulate else MonotonicClock())
        self.buses = BusFactory(simulate=simulate, clock=self.clock, seed=config.seed)
        self.devices: dict[str, DeviceState] = {}
        self.t0 = 0

    def open(self) -> list[DeviceSpec]:
        """Identify and configure every device; return their run-file descriptions."""
        specs = []
        for dev in self.config.devices:
            driver_cls = DRIVERS[dev.driver]
            regs = self.buses.register_device(dev)
            driver = driver_cls(regs, dev.settings, sleep=self.clock.sleep)
            info = driver.open()
            self.devices[dev.name] = DeviceState(dev, driver, info, 1e9 / info.rate_hz)
            specs.append(
                DeviceSpec(
                    name=dev.name,
                    driver=dev.driver,
                    model=info.model,
                    bus=dev.bus + (f"@0x{dev.address:02X}" if dev.address is not None else ""),
                    identity=info.identity,
                    rate_hz=info.rate_hz,
                    settings=info.settings,
                    channels=info.channels,
                    has_counter=info.has_counter,
                )
            )
        return specs

    def close(self) -> None:
        for state in self.devices.values():
            try:
                state.driver.close()
            except Exception:  # noqa: BLE001 - closing must not mask the capture's outcome
                pass
        self.buses.close()

    # ------------------------------------------------------------------------------
    def run(
        self,
        writer: RunWriter,
        duration_s: float,
        *,
        on_status: Callable[[dict[str, Any]], None] | None = None,
        should_stop: Callable[[], bool] = lambda: False,
    ) -> CaptureSummary:
        """Record for ``duration_s`` seconds of station-clock time."""
        clock = self.clock
        t0 = self.t0 = clock.now_ns()
        end = t0 + int(duration_s * 1e9)
        queue: list[tuple[int, str]] = []
        for name, st in self.devices.items():
            heapq.heappush(queue, (t0 + int(st.info.poll_interval_s * 1e9), name))
        wall0 = time.monotonic()
        next_status = wall0 + STATUS_INTERVAL_S
        stopped = False
        while queue:
            due, name = heapq.heappop(queue)
            if due > end:
                break
            if should_stop():
                stopped = True
                break
            now = clock.now_ns()
            if due > now:
                clock.sleep((due - now) / 1e9)
            st = self.devices[name]
            self._poll(writer, st, t0)
            heapq.heappush(queue, (due + int(st.info.poll_interval_s * 1e9), name))
            if on_status is not None and time.monotonic() >= next_status:
                on_status(self.status(t0, duration_s, wall0))
                next_status = time.monotonic() + STATUS_INTERVAL_S
        if on_status is not None:
            on_status(self.status(t0, duration_s, wall0))
        return CaptureSummary(
            duration_s=(clock.now_ns() - t0) / 1e9,
            samples={n: s.samples for n, s in self.devices.items()},
            lost={n: s.lost for n, s in self.devices.items()},
            gaps={n: s.gaps for n, s in self.devices.items()},
            wall_s=time.monotonic() - wall0,
            stopped_early=stopped,
        )

    def _poll(self, writer: RunWriter, st: DeviceState, t0: int) -> None:
        name = st.config.name
        if st.failed:
            try:
                st.info = st.driver.open()
            except (BusError, DeviceError):
                st.failed_attempts += 1
                return
            writer.event(
                self.clock.now_ns() - t0,
                name,
                "reconnect",
                f"device re-initialised with the same settings after {st.failed_attempts} failed attempt(s)",
            )
            st.failed, st.failed_attempts, st.resync = False, 0, True
        try:
            block = st.driver.read_block()
        except (BusError, DeviceError) as exc:
            return self._fault(writer, st, t0, str(exc))
        k = block.n
        t_read = self.clock.now_ns() - t0
        if st.resync and not block.lost:
            block.lost, block.note = -1, "samples lost while the device was failing"
        st.resync = False
        if block.lost:
            lost = block.lost
            if lost < 0:
                # the chip cannot count them: samples expected since the last one, minus those read
                last = st.last_t_ns if st.last_t_ns is not None else 0
                lost = max(0, int(round((t_read - last) / st.period_ns)) - k)
            st.lost += lost
            st.gaps += 1
            kind = "overrun" if "overrun" in block.note.lower() else "gap"
            writer.event(t_read, name, kind, block.note or "samples lost", lost=lost)
        if k == 0:
            return
        # sample times: the last sample is the newest at read time, spaced by the ODR
        t = t_read - np.round(np.arange(k - 1, -1, -1) * st.period_ns).astype(np.int64)
        writer.append(name, t, block.channels, block.counter)
        st.samples += k
        st.last_t_ns = int(t[-1])
        if "temp" in block.channels:
            spec = next(c for c in st.info.channels if c.name == "temp")
            st.temp_c = float(block.channels["temp"][-1]) * spec.scale + spec.offset

    def _fault(self, writer: RunWriter, st: DeviceState, t0: int, why: str) -> None:
        """Log a device fault once; the device is re-opened at its next polls until it answers."""
        st.faults += 1
        st.failed = True
        st.failed_attempts = 0
        writer.event(self.clock.now_ns() - t0, st.config.name, "fault", why)

    def status(self, t0: int, duration_s: float, wall0: float) -> dict[str, Any]:
        elapsed = (self.clock.now_ns() - t0) / 1e9
        return {
            "elapsed_s": elapsed,
            "duration_s": duration_s,
            "wall_s": time.monotonic() - wall0,
            "devices": {
                name: {
                    "samples": st.samples,
                    "rate_hz": st.samples / elapsed if elapsed > 0 else 0.0,
                    "rate_cfg_hz": st.info.rate_hz,
                    "gaps": st.gaps,
                    "lost": st.lost,
                    "faults": st.faults,
                    "temp_c": st.temp_c,
                }
                for name, st in self.devices.items()
            },
        }
