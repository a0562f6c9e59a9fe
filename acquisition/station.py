"""The station: opens every configured device and thermometer, and runs the capture loop.

Opening: each device's driver identifies and configures its chip (on a real or a
simulated bus) and reports it (:class:`OpenedDevice`); the run file's device
description is made from that report (:func:`~imustation.acquisition.recorder.run_file_device`).

Running: every device is polled at its own interval (about 40 % of its FIFO
depth; on the host clock also against its hold time), every thermometer at its
``rate_hz``, by one of the schedulers of :mod:`~imustation.acquisition.scheduler`
(a virtual-clock event queue in simulations and replays; on the host clock a
reader process per bus, :mod:`~imustation.acquisition.readers`, or reader
threads in this process where a capture asks for them). Times are
ns since the start of the run on the station clock. Each device's
:class:`~imustation.acquisition.timeline.Timeline` dates its samples and
accounts its losses, which are logged as events with their sample count (FIFO
overruns, resyncs and what a device without a FIFO missed measured from time,
counter jumps from the device counter); a device that stops answering is logged once as a fault and re-opened
at its polls until it answers; missed thermometer readings are logged at the
reconnect. With worker processes (:mod:`~imustation.acquisition.workers`) the
bus groups of other processes are opened and polled there, and this station
writes what they send.

Over 500 lines on purpose: opening a device and polling it share one piece of
state per device (driver, bus, timeline, re-open policy); the schedulers, sample
accounting, sinks and workers already live in their own modules.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np

from imustation.acquisition.buses import BusFactory
from imustation.acquisition.config import DeviceConfig, StationConfig, ThermometerConfig
from imustation.acquisition.modes import check_options
from imustation.acquisition.pollphase import PollPhase
from imustation.acquisition.readers import ReaderOptions
from imustation.acquisition.scheduler import DeadlineStats, Poller, run_deadline, run_threaded, run_virtual
from imustation.acquisition.sinks import Sink, tick_of
from imustation.acquisition.timeline import Timeline
from imustation.acquisition.workers import WorkerPool, bus_groups, partition
from imustation.clock import Clock, MonotonicClock, VirtualClock
from imustation.drivers import DRIVERS, THERMOMETER_DRIVERS, DriverInfo
from imustation.drivers.base import Block
from imustation.drivers.bus.trace import Trace, TraceWriter
from imustation.errors import BusError, DeviceError, DiskFullError
from imustation.status import DeviceStatus, ThermometerStatus, capture_status, finite

#: wall seconds between status reports (default)
STATUS_INTERVAL_S = 1.0
#: a thermometer's poll rate when its config gives none, Hz
DEFAULT_THERMOMETER_RATE_HZ = 1.0
#: FIFO drivers poll at about this fill (drivers' ``poll_interval_s``): their FIFO holds the samples of
#: about 1/this intervals, the hold time of a device whose driver reports no finite ``buffer_s``
FIFO_POLL_FILL = 0.4


@dataclass(frozen=True)
class OpenedDevice:
    """A device as the station opened it: its config entry and its driver's report of the chip."""

    config: DeviceConfig
    info: DriverInfo

    @property
    def name(self) -> str:
        return self.config.name


@dataclass
class DeviceState:
    """A device of the capture: polled by this process (``driver``), or by a worker process (``driver`` None)."""

    config: DeviceConfig
    driver: Any
    info: DriverInfo
    #: poll interval, ns
    poll_ns: int
    timeline: Timeline
    faults: int = 0
    temp_c: float = float("nan")
    failed: bool = False
    failed_attempts: int = 0
    #: samples seen in the current status window (for the recent rate)
    window_samples: int = 0
    #: station time of the last poll, ns (what a driver's ``drain`` dates its samples from)
    last_poll_ns: int = 0
    #: polled by a reader process: its samples as last reported at a status (for the recent rate)
    reported_samples: int = 0
    #: a chip without a FIFO polled by run_deadline: when it makes its samples, learnt from its reads
    #: (None for the others, and where nothing times the polls by it)
    phase: PollPhase | None = None

    @property
    def samples(self) -> int:
        return self.timeline.samples

    @property
    def lost(self) -> int:
        return self.timeline.lost

    @property
    def gaps(self) -> int:
        return self.timeline.gaps

    def counts(self) -> DeviceStatus:
        tl = self.timeline
        return DeviceStatus(
            rate_cfg_hz=self.info.rate_hz,
            samples=tl.samples,
            gaps=tl.gaps,
            lost=tl.lost,
            faults=self.faults + tl.stalls,
            temp_c=finite(self.temp_c),
            state="failed" if self.failed else "stalled" if tl.stalled else "ok",
        )


def _hold_ns(st: DeviceState) -> int:
    """How long a sample waits in the device before it is overwritten or dropped, ns: the driver's
    ``buffer_s`` (one period for a chip without a FIFO), else its FIFO from its poll interval."""
    buffer_s = st.info.buffer_s
    if buffer_s is not None and buffer_s < float("inf"):
        return max(1, int(buffer_s * 1e9))
    return int(st.poll_ns / FIFO_POLL_FILL)


def _device_state(config: DeviceConfig, driver: Any, info: DriverInfo) -> DeviceState:
    timeline = Timeline(
        1e9 / info.rate_hz, info.settings.get("counter_modulus"), overflow=info.overflow, buffer_s=info.buffer_s
    )
    return DeviceState(config, driver, info, int(info.poll_interval_s * 1e9), timeline)


@dataclass
class ThermometerState:
    config: ThermometerConfig
    driver: Any
    identity: str
    period_ns: int
    readings: int = 0
    lost: int = 0
    faults: int = 0
    celsius: float = float("nan")
    failed: bool = False
    failed_attempts: int = 0

    @property
    def rate_hz(self) -> float:
        """The configured poll rate, Hz (what the run file stores; ``period_ns`` is it rounded to whole ns)."""
        return float(self.config.settings.get("rate_hz", DEFAULT_THERMOMETER_RATE_HZ))

    def counts(self) -> ThermometerStatus:
        return ThermometerStatus(
            readings=self.readings,
            lost=self.lost,
            faults=self.faults,
            celsius=finite(self.celsius),
            state="failed" if self.failed else "ok",
        )


@dataclass
class CaptureSummary:
    duration_s: float
    samples: dict[str, int]
    lost: dict[str, int]
    gaps: dict[str, int]
    wall_s: float
    stopped_early: bool = False
    events: list[str] = field(default_factory=list)
    readings: dict[str, int] = field(default_factory=dict)
    #: why the capture ended before its duration ("signal SIGTERM", "disk full"), else ""
    stop_reason: str = ""
    paths: list[str] = field(default_factory=list)
    #: host clock: CPU time each reader process used while recording, s, by bus URL
    reader_cpu_s: dict[str, float] = field(default_factory=dict)


class Station:
    """Devices and thermometers of a config, opened on real or simulated buses.

    Parameters
    ----------
    config : a validated :class:`StationConfig`.
    simulate : replace every bus and chip by its simulator.
    clock : override the clock (tests); default virtual when simulating,
        monotonic otherwise. A virtual clock selects the single-threaded event
        queue, any other clock the threaded readers.
    trace, replay : record every bus transaction / answer the drivers from a trace.
    workers : processes a simulated capture may poll its bus groups in.
    readers : host clock: poll every bus group in a reader process of its own
        (:mod:`~imustation.acquisition.readers`); this station only writes.
    reader_process : this station is such a reader: one bus group, polled in one thread
        against the devices' hold times.
    sim_level : ``"bus"`` (chip simulators behind the real bus code) or ``"model"``
        (devices polled at the noise-model level, :mod:`~imustation.acquisition.modelsim`).
        :func:`~imustation.acquisition.modes.check_options` says what combines.
    """

    def __init__(
        self,
        config: StationConfig,
        *,
        simulate: bool,
        clock: Clock | None = None,
        trace: TraceWriter | None = None,
        replay: Trace | None = None,
        workers: int = 1,
        sim_level: str = "bus",
        readers: ReaderOptions | None = None,
        reader_process: bool = False,
    ):
        self.config = config
        self.simulate = simulate
        # a replayed trace, like a simulation, runs on a virtual clock
        self.clock: Clock = clock or (VirtualClock() if simulate or replay else MonotonicClock())
        check_options(
            simulate=simulate,
            sim_level=sim_level,
            workers=workers,
            virtual_clock=self.virtual,
            trace=trace is not None,
            replay=replay is not None,
        )
        self.sim_level = sim_level
        self.workers = workers
        self.readers = readers
        self.reader_process = reader_process
        #: a reader process: hybrid sleep before polls of devices without a FIFO (ns; 0 off), and how late
        #: those polls started (scheduler.run_deadline)
        self.spin_ns = 0
        self.deadline_stats: DeadlineStats | None = None
        #: run_deadline polls a device without a FIFO just after each sample once its phase is known
        self.phase_lock = True
        self._pool: WorkerPool | None = None
        self.buses = BusFactory(simulate=simulate, clock=self.clock, seed=config.seed, trace=trace, replay=replay)
        self.devices: dict[str, DeviceState] = {}
        self.thermometers: dict[str, ThermometerState] = {}
        self.t0 = 0
        self._started = False
        self._wall0 = time.monotonic()
        self._window_wall = self._wall0
        self._on_status: Callable[[dict[str, Any]], None] | None = None
        self._recorder: Any = None
        self._duration_s = 0.0

    @property
    def virtual(self) -> bool:
        return bool(getattr(self.clock, "virtual", False))

    def elapsed_ns(self) -> int:
        """Station time since the start of the recording, ns."""
        return self.clock.now_ns() - self.t0

    # -- opening ------------------------------------------------------------------------
    def open(self) -> list[OpenedDevice]:
        """Identify and configure every device and thermometer; return the devices as opened, in config order.

        With ``workers`` > 1 the bus groups other than this process's share are
        opened (and later polled) by worker processes.
        """
        local = None
        if self.readers is not None:
            local = set()
            groups = list(bus_groups(self.config).values())
            self._pool = WorkerPool(self.config, groups, self.sim_level, type(self), host=self.readers)
        elif self.workers > 1 and len(bus_groups(self.config)) > 1:
            shares = partition(self.config, self.workers, self.sim_level)
            local = set(shares[0])
            self._pool = WorkerPool(self.config, shares[1:], self.sim_level, type(self))
        opened: dict[str, OpenedDevice] = {}
        for dev in self.config.devices:
            if local is None or dev.name in local:
                driver, info = self._open_device(dev)
                self.devices[dev.name] = _device_state(dev, driver, info)
                opened[dev.name] = OpenedDevice(dev, info)
        for th in self.config.thermometers:
            if local is None or th.name in local:
                regs = self.buses.register_thermometer(th)
                driver = THERMOMETER_DRIVERS[th.driver](regs, th.settings, sleep=self.clock.sleep)
                identity = driver.open()
                period = int(round(1e9 / float(th.settings.get("rate_hz", DEFAULT_THERMOMETER_RATE_HZ))))
                self.thermometers[th.name] = ThermometerState(th, driver, str(identity), period)
        if self._pool is not None:
            by_name = {d.name: d for d in (*self.config.devices, *self.config.thermometers)}
            for _, devices, thermos in self._pool.opened():
                for od in devices:
                    self.devices[od.name] = _device_state(by_name[od.name], None, od.info)
                    opened[od.name] = od
                for name, (identity, period) in thermos.items():
                    self.thermometers[name] = ThermometerState(by_name[name], None, identity, period)
        # config order, whichever process polls them
        self.devices = {d.name: self.devices[d.name] for d in self.config.devices}
        self.thermometers = {t.name: self.thermometers[t.name] for t in self.config.thermometers}
        return [opened[d.name] for d in self.config.devices]

    def _open_device(self, dev: DeviceConfig) -> tuple[Any, DriverInfo]:
        driver = DRIVERS[dev.driver](self.buses.register_device(dev), dev.settings, sleep=self.clock.sleep)
        if hasattr(driver, "clock_ns"):
            driver.clock_ns = self.clock.now_ns  # it stamps its reads (a chip without a FIFO)
        info = driver.open()
        if self.sim_level == "model":
            # imported here: the noise sources load for a model-level simulation only
            from imustation.acquisition.modelsim import ModelDevice

            # the driver has identified and configured its chip simulator: its report stands,
            # the samples come from the noise model
            driver.close()
            driver = ModelDevice(dev, info, self.clock, self.config.seed, self.config.path)
            info = driver.open()
        return driver, info

    def shortest_hold_s(self) -> float:
        """The shortest hold time of the devices this process polls, s (inf without any)."""
        holds = [_hold_ns(st) for st in self.devices.values() if st.driver is not None]
        return min(holds) / 1e9 if holds else float("inf")

    def scheduling(self) -> dict[str, Any]:
        """What each reader process obtained from the OS (:class:`~imustation.acquisition.realtime.Scheduling`),
        by bus URL; empty without reader processes."""
        if self._pool is None or self._pool.host is None:
            return {}
        return {w.config_bus: w.scheduling for w in self._pool.workers if w.scheduling is not None}

    def close(self) -> None:
        for obj in [*self.devices.values(), *self.thermometers.values()]:
            if obj.driver is None:
                continue  # polled by a worker process
            try:
                obj.driver.close()
            except Exception:  # noqa: BLE001 - closing must not mask the capture's outcome
                pass
        self.buses.close()
        if self._pool is not None:
            self._pool.close()

    # -- the run loop -------------------------------------------------------------------
    def run(
        self,
        recorder: Any,
        duration_s: float,
        *,
        on_status: Callable[[dict[str, Any]], None] | None = None,
        should_stop: Callable[[], bool] = lambda: False,
        status_interval_s: float = STATUS_INTERVAL_S,
        pace: float | None = None,
    ) -> CaptureSummary:
        """Record for ``duration_s`` seconds of station-clock time into ``recorder``.

        ``recorder`` takes ``append``/``append_temperature``/``event`` (a
        :class:`~imustation.runfile.RunWriter` or the capture's rotating
        recorder); its optional ``tick(t_ns)`` is called between polls (flushes,
        rotation) and ``status()`` adds file details to the status.
        ``pace`` (virtual clock only): at most this many virtual seconds per wall
        second (tests that must interrupt a capture mid-write).
        """
        if not self._started:
            self.start(recorder)
        self._wall0 = self._window_wall = time.monotonic()
        self._status_interval = status_interval_s
        self._on_status = on_status
        self._next_status = self._wall0 + status_interval_s
        self._duration_s = duration_s
        self._recorder = recorder
        end = self.t0 + int(round(duration_s * 1e9))
        reason = ""
        pool = self._pool
        if pool is not None:
            pool.start(duration_s, pace, None if self.virtual else self.t0)
        tick = tick_of(recorder)
        pollers = self._pollers()
        try:
            if pool is not None and pool.host is not None:
                # every bus has its reader process: this one writes what they send until they are done
                reason = pool.finish(recorder, should_stop, "", tick, self._status_if_due)
                pool = None
            elif self.virtual:
                hook = pool.keep_pace(recorder, tick, should_stop) if pool is not None else tick
                reason = run_virtual(
                    self.clock,
                    pollers,
                    recorder,
                    t0=self.t0,
                    end=end,
                    between=self._between(hook),
                    should_stop=should_stop,
                    pace=pace,
                )
            elif self.reader_process:
                reason = run_deadline(
                    self.clock,
                    pollers,
                    recorder,
                    t0=self.t0,
                    end=end,
                    between=self._between(tick),
                    should_stop=should_stop,
                    spin_ns=self.spin_ns,
                    stats=self.deadline_stats,
                )
            else:
                reason = run_threaded(
                    self.clock,
                    pollers,
                    recorder,
                    t0=self.t0,
                    end=end,
                    between=self._between(tick),
                    should_stop=should_stop,
                )
            self._drain(recorder)
            if pool is not None:
                reason = pool.finish(recorder, should_stop, reason, tick, self._status_if_due)
        except DiskFullError as exc:
            reason = f"disk full: {exc}"
            raise
        finally:
            if on_status is not None:
                on_status(self.status(final=True, reason=reason))
        return self.summary(reason)

    def start(self, sink: Sink) -> None:
        """Set the time origin and empty every device's buffer: recording starts now.

        Samples a FIFO gathered between opening the devices and now (while the
        run file was being created) predate the run and are dropped, as the
        drivers drop their start-up samples.
        """
        self.t0 = self.clock.now_ns()
        self._started = True
        self._empty(lambda st, exc: self._fault(sink, st, str(exc)))
        self.t0 = self.clock.now_ns()

    def discard(self) -> None:
        """Empty every device's buffer, errors ignored: a reader process waiting to start keeps its
        devices' buffers (a tty's 4 kB) from overflowing; :meth:`start` then reports what fails."""
        self._empty(lambda st, exc: None)

    def _empty(self, failed: Callable[[DeviceState, Exception], None]) -> None:
        """Read and drop what every device of this process holds; ``failed(state, error)`` for each that fails."""
        for st in self.devices.values():
            if st.driver is None:
                continue  # a worker process starts its own
            try:
                st.driver.read_block()
                drain = getattr(st.driver, "drain", None)
                if drain is not None:
                    drain()
            except (BusError, DeviceError) as exc:
                failed(st, exc)

    def summary(self, reason: str = "") -> CaptureSummary:
        devices, thermometers = self.counts()
        return CaptureSummary(
            duration_s=self.elapsed_ns() / 1e9,
            samples={n: d.samples for n, d in devices.items()},
            lost={n: d.lost for n, d in devices.items()},
            gaps={n: d.gaps for n, d in devices.items()},
            wall_s=time.monotonic() - self._wall0,
            stopped_early=bool(reason),
            readings={n: t.readings for n, t in thermometers.items()},
            stop_reason=reason,
            reader_cpu_s={
                w.config_bus: w.cpu_s
                for w in (self._pool.workers if self._pool is not None else ())
                if w.cpu_s is not None
            },
        )

    def _pollers(self) -> list[Poller]:
        """This process's devices and thermometers (not those a worker process polls), in config order.

        Devices without a FIFO get a :class:`PollPhase` only where run_deadline polls them (a reader
        process on the host clock, ``phase_lock``): nowhere else is it read, so no poll feeds it."""
        phased = self.reader_process and self.phase_lock and not self.virtual
        for st in self.devices.values():
            newest = phased and st.driver is not None and st.info.overflow == "newest"
            st.phase = PollPhase(round(1e9 / st.info.rate_hz)) if newest else None
        return [
            Poller(n, st.config.bus, st.poll_ns, partial(self._poll_device, st=st), _hold_ns(st), st.phase)
            for n, st in self.devices.items()
            if st.driver is not None
        ] + [
            Poller(n, th.config.bus, th.period_ns, partial(self._poll_thermometer, th=th))
            for n, th in self.thermometers.items()
            if th.driver is not None
        ]

    def _between(self, tick: Callable[[int], None] | None) -> Callable[[int], None]:
        """What runs between polls: the recorder's (or the worker pool's) hook, then the status when due."""

        def between(t_ns: int) -> None:
            if tick is not None:
                tick(t_ns)
            self._status_if_due()

        return between

    def _drain(self, sink: Sink) -> None:
        """Hand the samples drivers still hold to ``sink``, dated from each device's last poll."""
        for st in self.devices.values():
            drain = getattr(st.driver, "drain", None)
            if drain is not None and not st.failed:
                try:
                    block = drain()
                except (BusError, DeviceError) as exc:
                    self._fault(sink, st, str(exc))
                    continue
                self._store(sink, st, block, st.last_poll_ns, poll=False)

    # -- one poll ---------------------------------------------------------------------
    def _poll_device(self, sink: Sink, st: DeviceState) -> int:
        """One read of a device (a failed one is re-opened first); returns the interval to its next poll, ns."""
        name = st.config.name
        clock = self.clock
        if st.failed:
            try:
                st.info = st.driver.open()
            except (BusError, DeviceError):
                st.failed_attempts += 1
                return st.poll_ns
            sink.event(
                clock.now_ns() - self.t0,
                name,
                "reconnect",
                f"device re-initialised with the same settings after {st.failed_attempts} failed attempt(s)",
            )
            st.failed, st.failed_attempts = False, 0
            st.timeline.restart(clock.now_ns() - self.t0)
        started = clock.now_ns() - self.t0
        try:
            block = st.driver.read_block()
        except (BusError, DeviceError) as exc:
            if st.phase is not None:
                st.phase.reset()
            self._fault(sink, st, str(exc))
            return st.poll_ns
        t_read = st.last_poll_ns = clock.now_ns() - self.t0
        if st.phase is not None:
            st.phase.observe(started + self.t0, t_read + self.t0, getattr(st.driver, "new_sample", None))
        self._store(sink, st, block, t_read, started=started)
        return st.poll_ns

    def _store(
        self, sink: Sink, st: DeviceState, block: Block, t_read: int, *, poll: bool = True, started: int | None = None
    ) -> None:
        """Log a block's losses and append its samples, dated by the device's timeline from ``t_read`` (ns).

        ``poll``: the block comes from a read from ``started`` to ``t_read`` (False: what a driver held
        at the end).
        """
        name = st.config.name
        if block.read_ns is not None:  # the driver's stamps, on the station's clock: to station time
            block = replace(block, read_ns=block.read_ns - self.t0, previous_read_ns=block.previous_read_ns - self.t0)
        placed = st.timeline.place(block, t_read, poll=poll, started=started)
        for ev in placed.events:
            sink.event(ev.t_ns, name, ev.kind, ev.detail, lost=ev.lost)
        if placed.t_ns is None:
            return
        sink.append(name, placed.t_ns, block.channels, block.counter)
        st.window_samples += block.n
        temp = block.channels.get("temp")
        if temp is not None:
            spec = next(c for c in st.info.channels if c.name == "temp")
            st.temp_c = float(temp[-1]) * spec.scale + spec.offset

    def _fault(self, sink: Sink, st: DeviceState, why: str) -> None:
        """Log a device fault once; the device is re-opened at its next polls until it answers."""
        st.faults += 1
        st.failed = True
        st.failed_attempts = 0
        sink.event(self.clock.now_ns() - self.t0, st.config.name, "fault", why)

    def _poll_thermometer(self, sink: Sink, th: ThermometerState) -> int:
        """One reading; a failed reading is one lost reading, logged with the fault and the reconnect.

        Returns the interval to the next reading, ns.
        """
        name = th.config.name
        now = self.clock.now_ns() - self.t0
        try:
            if th.failed:
                th.driver.open()
                sink.event(
                    now,
                    name,
                    "reconnect",
                    f"thermometer re-initialised after {th.failed_attempts} missed reading(s)",
                    lost=th.failed_attempts,
                )
                th.lost += th.failed_attempts
                th.failed, th.failed_attempts = False, 0
            celsius = float(th.driver.read_celsius())
        except (BusError, DeviceError) as exc:
            if not th.failed:
                th.faults += 1
                th.failed = True
                sink.event(now, name, "fault", str(exc))
            th.failed_attempts += 1
            return th.period_ns
        t = self.clock.now_ns() - self.t0
        sink.append_temperature(name, np.array([t], dtype=np.int64), np.array([celsius]))
        th.readings += 1
        th.celsius = celsius
        return th.period_ns

    # -- status -------------------------------------------------------------------------
    def counts(self) -> tuple[dict[str, DeviceStatus], dict[str, ThermometerStatus]]:
        """Every device's and thermometer's counts (those a worker polls as it last sent them)."""
        remote_dev = self._pool.devices if self._pool is not None else {}
        remote_th = self._pool.thermometers if self._pool is not None else {}
        devices = {}
        for name, st in self.devices.items():
            if st.driver is not None:
                devices[name] = st.counts()
            else:
                devices[name] = remote_dev.get(name) or DeviceStatus(rate_cfg_hz=st.info.rate_hz)
        thermometers = {}
        for name, th in self.thermometers.items():
            if th.driver is not None:
                thermometers[name] = th.counts()
            else:
                thermometers[name] = remote_th.get(name) or ThermometerStatus()
        return devices, thermometers

    def _status_if_due(self) -> None:
        if self._on_status is not None and time.monotonic() >= self._next_status:
            self._on_status(self.status())
            self._next_status = time.monotonic() + self._status_interval

    def status(self, *, final: bool = False, reason: str = "") -> dict[str, Any]:
        """The live status document (:func:`imustation.status.capture_status`; docs/capture.md)."""
        own_s = self.elapsed_ns() / 1e9  # this process's station time
        behind = self._pool.t_ns() if self._pool is not None else None
        elapsed = own_s if behind is None else min(own_s, behind / 1e9)
        wall_now = time.monotonic()
        window = wall_now - self._window_wall
        station_s = self._pool.station_s() if self._pool is not None else {}  # each worker's station time
        counts, thermometers = self.counts()
        devices = {}
        for name, st in self.devices.items():
            # a simulation's wall-clock rate says nothing about the device
            recent = None if self.virtual else st.window_samples
            if st.driver is None and not self.virtual:  # a reader process's: from its counts
                recent = counts[name].samples - st.reported_samples
                st.reported_samples = counts[name].samples
            st.window_samples = 0
            devices[name] = counts[name].live(station_s.get(name, own_s), recent, window)
        self._window_wall = wall_now
        file_status = getattr(self._recorder, "status", None)
        return capture_status(
            devices,
            thermometers,
            state=("stopped" if reason else "done") if final else "recording",
            reason=reason,
            elapsed_s=elapsed,
            duration_s=self._duration_s,
            wall_s=wall_now - self._wall0,
            file=file_status() if callable(file_status) else None,
        )
