"""The station: opens every configured device and thermometer and polls them.

Two schedulers share one per-device poll routine (:meth:`Station._poll_device`,
:meth:`Station._poll_thermometer`):

* **virtual clock** (simulation): one thread and one event queue (a heap of due
  times) for every device; sleeping only advances the clock, so hours are
  recorded in seconds, and the same seed gives the same file contents.
* **real clock**: one reader thread per bus URL (the devices of one I2C adapter
  share the thread, hence the bus; other buses run in parallel, so a slow bus
  cannot starve another) and the calling thread as the single writer that owns
  the HDF5 file (h5py is not thread-safe): readers hand their blocks and events
  over a queue.

Every device is polled at its own interval (about 40 % of its FIFO depth),
every thermometer at its ``rate_hz``. Times are ns since the start of the run
on the station clock. Losses are logged as events with their sample count:
FIFO overruns and resyncs (measured from time), counter jumps (from the device
counter), missed thermometer readings.
"""

from __future__ import annotations

import heapq
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from imustation.acquisition import simworkers
from imustation.acquisition.buses import BusFactory
from imustation.acquisition.config import DeviceConfig, StationConfig, ThermometerConfig
from imustation.clock import Clock, MonotonicClock, VirtualClock
from imustation.drivers import DRIVERS, THERMOMETER_DRIVERS, DriverInfo
from imustation.drivers.base import Block
from imustation.drivers.bus.trace import Trace, TraceWriter
from imustation.errors import BusError, DeviceError, DiskFullError
from imustation.runfile import DeviceSpec

#: wall seconds between status reports (default)
STATUS_INTERVAL_S = 1.0
#: how long the writer thread waits for a block before doing its periodic work, s
WRITER_WAKEUP_S = 0.05
#: distinct block lengths whose sample-time offsets a device keeps
_MAX_CACHED_OFFSETS = 512
#: number of first counter jumps of a block quoted in the event text
_QUOTED_JUMPS = 3
#: with worker processes: how often the main process takes in their data (wall s), and how far
#: (station time) it may run ahead of the slowest
WORKER_PUMP_S = 0.02
WORKER_LEAD_NS = 10_000_000_000


#: simulation levels (``capture --simulate --sim-level``): chip simulators behind the bus code,
#: or devices at the noise-model level (:mod:`~imustation.acquisition.modelsim`)
SIM_LEVELS = ("bus", "model")


class Sink(Protocol):
    """Where polled data go: the run-file recorder, or a queue to it."""

    def append(self, device: str, t_ns: np.ndarray, channels: Mapping[str, np.ndarray], counter) -> None: ...

    def append_temperature(self, name: str, t_ns: np.ndarray, celsius: np.ndarray) -> None: ...

    def event(self, t_ns: int, source: str, kind: str, detail: str = "", lost: int = 0) -> None: ...


@dataclass
class DeviceState:
    config: DeviceConfig
    driver: Any
    info: DriverInfo
    period_ns: float
    poll_ns: int = 0
    samples: int = 0
    lost: int = 0
    gaps: int = 0
    faults: int = 0
    last_t_ns: int | None = None
    last_counter: int | None = None
    temp_c: float = float("nan")
    failed: bool = False
    #: after a fault: the next block's loss is measured from time
    resync: bool = False
    failed_attempts: int = 0
    #: samples seen in the current status window (for the recent rate)
    window_samples: int = 0
    #: block length -> time offsets of its samples before the newest, ns (reused every poll)
    offsets: dict[int, np.ndarray] = field(default_factory=dict)
    #: station time of the last poll, ns (what a driver's ``drain`` dates its samples from)
    last_poll_ns: int = 0


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


class _QueueSink:
    """A reader thread's sink: hands everything to the writer thread."""

    def __init__(self, q: queue.SimpleQueue):
        self._put = q.put

    def append(self, device, t_ns, channels, counter) -> None:
        self._put(("append", device, t_ns, channels, counter))

    def append_temperature(self, name, t_ns, celsius) -> None:
        self._put(("temperature", name, t_ns, celsius))

    def event(self, t_ns, source, kind, detail="", lost=0) -> None:
        self._put(("event", t_ns, source, kind, detail, lost))


def _dispatch(recorder: Sink, item: tuple) -> None:
    kind = item[0]
    if kind == "append":
        recorder.append(*item[1:])
    elif kind == "temperature":
        recorder.append_temperature(*item[1:])
    elif kind == "event":
        recorder.event(*item[1:])
    elif kind == "error":
        raise item[1]


class Station:
    """Devices and thermometers of a config, opened on real or simulated buses.

    Parameters
    ----------
    config : a validated :class:`StationConfig`.
    simulate : replace every bus and chip by its simulator.
    clock : override the clock (tests); default virtual when simulating,
        monotonic otherwise. A virtual clock selects the single-threaded event
        queue, any other clock the threaded readers.
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
    ):
        self.config = config
        self.simulate = simulate
        if workers < 1:
            raise ValueError(f"workers = {workers}: at least 1")
        if sim_level not in SIM_LEVELS:
            raise ValueError(f"sim_level = {sim_level!r}: {' or '.join(SIM_LEVELS)}")
        if sim_level == "model" and (not simulate or trace is not None or replay is not None):
            raise ValueError("sim_level = 'model' needs a simulated capture without trace or replay")
        #: "bus": chip simulators behind the real bus code; "model": devices polled at the
        #: noise-model level (:mod:`~imustation.acquisition.modelsim`)
        self.sim_level = sim_level
        #: processes a simulated capture may use (bus groups polled in worker processes)
        self.workers = workers
        self._workers: list[Any] = []
        self._trace, self._replay = trace, replay
        # a replayed trace, like a simulation, runs on a virtual clock
        self.clock: Clock = clock or (VirtualClock() if simulate or replay else MonotonicClock())
        self.buses = BusFactory(simulate=simulate, clock=self.clock, seed=config.seed, trace=trace, replay=replay)
        self.devices: dict[str, DeviceState] = {}
        self.thermometers: dict[str, ThermometerState] = {}
        self.t0 = 0
        self._started = False
        self._wall0 = time.monotonic()
        self._window_wall = self._wall0

    @property
    def virtual(self) -> bool:
        return bool(getattr(self.clock, "virtual", False))

    def open(self) -> list[DeviceSpec]:
        """Identify and configure every device and thermometer; return the devices' run-file descriptions.

        With ``workers`` > 1 on a virtual clock, the bus groups other than this
        process's share are opened (and later polled) by worker processes.
        """
        local = None
        if self.workers > 1 and len(simworkers.bus_groups(self.config)) > 1:
            if not self.virtual or self._trace is not None or self._replay is not None:
                raise ValueError("workers > 1 needs a simulated capture without trace or replay")
            shares = simworkers.partition(self.config, self.workers, self.sim_level)
            local = set(shares[0])
            self._workers = [
                simworkers.Worker(simworkers.subset(self.config, share), i, self.sim_level)
                for i, share in enumerate(shares[1:], 1)
            ]
        specs = {}
        for dev in self.config.devices:
            if local is not None and dev.name not in local:
                continue
            driver_cls = DRIVERS[dev.driver]
            regs = self.buses.register_device(dev)
            driver = driver_cls(regs, dev.settings, sleep=self.clock.sleep)
            info = driver.open()
            if self.sim_level == "model":
                from imustation.acquisition.modelsim import ModelDevice

                # the driver has identified and configured its chip simulator: its report stands,
                # the samples come from the noise model
                driver.close()
                driver = ModelDevice(dev, info, self.clock, self.config.seed, self.config.path)
                info = driver.open()
            st = DeviceState(dev, driver, info, 1e9 / info.rate_hz, int(info.poll_interval_s * 1e9))
            self.devices[dev.name] = st
            specs[dev.name] = DeviceSpec(
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
        for th in self.config.thermometers:
            if local is not None and th.name not in local:
                continue
            driver_cls = THERMOMETER_DRIVERS[th.driver]
            regs = self.buses.register_thermometer(th)
            driver = driver_cls(regs, th.settings, sleep=self.clock.sleep)
            identity = driver.open()
            period = int(round(1e9 / float(th.settings.get("rate_hz", 1.0))))
            self.thermometers[th.name] = ThermometerState(th, driver, str(identity), period)
        for w in self._workers:
            w_specs, infos, thermos = w.opened()
            for spec in w_specs:
                specs[spec.name] = spec
            for dev in w.config.devices:
                info = infos[dev.name]
                poll = int(info.poll_interval_s * 1e9)
                self.devices[dev.name] = DeviceState(dev, None, info, 1e9 / info.rate_hz, poll)
            for th in w.config.thermometers:
                identity, period = thermos[th.name]
                self.thermometers[th.name] = ThermometerState(th, None, identity, period)
        # config order, whichever process polls them
        self.devices = {d.name: self.devices[d.name] for d in self.config.devices}
        self.thermometers = {t.name: self.thermometers[t.name] for t in self.config.thermometers}
        return [specs[d.name] for d in self.config.devices]

    def close(self) -> None:
        for obj in [*self.devices.values(), *self.thermometers.values()]:
            if obj.driver is None:
                continue  # polled by a worker process
            try:
                obj.driver.close()
            except Exception:  # noqa: BLE001 - closing must not mask the capture's outcome
                pass
        self.buses.close()
        for w in self._workers:
            try:
                w.close()
            except Exception:  # noqa: BLE001 - closing must not mask the capture's outcome
                pass

    # -- scheduling ---------------------------------------------------------------
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
        for w in self._workers:
            w.start(duration_s, pace)
        try:
            if self.virtual:
                reason = self._run_virtual(recorder, end, should_stop, pace)
            else:
                reason = self._run_threaded(recorder, end, should_stop)
            self._drain(recorder)
            if self._workers:
                reason = self._finish_workers(recorder, should_stop, reason)
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
        for st in self.devices.values():
            if st.driver is None:
                continue  # a worker process starts its own
            try:
                st.driver.read_block()
                drain = getattr(st.driver, "drain", None)
                if drain is not None:
                    drain()
            except (BusError, DeviceError) as exc:
                self._fault(sink, st, str(exc))
        self.t0 = self.clock.now_ns()

    def summary(self, reason: str = "") -> CaptureSummary:
        return CaptureSummary(
            duration_s=(self.clock.now_ns() - self.t0) / 1e9,
            samples={n: s.samples for n, s in self.devices.items()},
            lost={n: s.lost for n, s in self.devices.items()},
            gaps={n: s.gaps for n, s in self.devices.items()},
            wall_s=time.monotonic() - self._wall0,
            stopped_early=bool(reason),
            readings={n: s.readings for n, s in self.thermometers.items()},
            stop_reason=reason,
        )

    def _pollers(self, names: list[tuple[str, str]]) -> list[tuple[int, int, str, str]]:
        """Initial heap entries ``(due, seq, kind, name)`` for devices and thermometers."""
        heap = []
        for seq, (kind, name) in enumerate(names):
            interval = self.devices[name].poll_ns if kind == "device" else self.thermometers[name].period_ns
            heap.append((self.t0 + interval, seq, kind, name))
        heapq.heapify(heap)
        return heap

    def _all_pollers(self) -> list[tuple[str, str]]:
        """This process's devices and thermometers (not those a worker process polls)."""
        return [("device", n) for n, st in self.devices.items() if st.driver is not None] + [
            ("thermometer", n) for n, th in self.thermometers.items() if th.driver is not None
        ]

    def _poll(self, sink: Sink, kind: str, name: str) -> int:
        """Poll one device or thermometer; return its poll interval, ns."""
        if kind == "device":
            st = self.devices[name]
            self._poll_device(sink, st)
            return st.poll_ns
        th = self.thermometers[name]
        self._poll_thermometer(sink, th)
        return th.period_ns

    def _run_virtual(self, recorder: Any, end: int, should_stop: Callable[[], bool], pace: float | None) -> str:
        clock = self.clock
        heap = self._pollers(self._all_pollers())
        tick = _ticker(recorder)
        if self._workers:
            tick = self._pumping(recorder, tick, should_stop)
        heappop, heappush = heapq.heappop, heapq.heappush
        wall0 = time.monotonic()
        while heap:
            due, seq, kind, name = heappop(heap)
            if due > end:
                break
            if should_stop():
                return "stopped by signal"
            now = clock.now_ns()
            if due > now:
                clock.advance_to(due)  # type: ignore[attr-defined]
            if pace is not None:
                ahead = (due - self.t0) / 1e9 / pace - (time.monotonic() - wall0)
                if ahead > 0:
                    time.sleep(ahead)
            interval = self._poll(recorder, kind, name)
            heappush(heap, (due + interval, seq, kind, name))
            if tick is not None:
                tick(clock.now_ns() - self.t0)
            if self._on_status is not None and time.monotonic() >= self._next_status:
                self._emit_status()
        if clock.now_ns() < end:
            clock.advance_to(end)  # type: ignore[attr-defined]
        return ""

    # -- worker processes (simulated captures on several cores) ---------------------------
    def _pump(self, recorder: Any, timeout: float = 0.0) -> bool:
        """Write what the workers sent; True if anything came."""
        got = False
        for w in self._workers:
            got |= w.pump(lambda item: _dispatch(recorder, item), self._mirror, timeout)
        return got

    def _mirror(self, counts: dict[str, dict[str, tuple]]) -> None:
        for name, (samples, lost, gaps, faults, temp_c, failed) in counts["devices"].items():
            st = self.devices[name]
            st.samples, st.lost, st.gaps, st.faults, st.temp_c, st.failed = samples, lost, gaps, faults, temp_c, failed
        for name, (readings, lost, faults, celsius, failed) in counts["thermometers"].items():
            th = self.thermometers[name]
            th.readings, th.lost, th.faults, th.celsius, th.failed = readings, lost, faults, celsius, failed

    def _workers_t_ns(self) -> int | None:
        """Station time every running worker has reached (None: all done)."""
        running = [w.t_ns for w in self._workers if not w.done]
        return min(running) if running else None

    def _pumping(self, recorder: Any, tick: Callable[[int], None] | None, should_stop: Callable[[], bool]):
        """The virtual loop's between-polls hook with workers: take in their data, stay in step with them.

        This process runs at most ``WORKER_LEAD_NS`` of station time ahead of the
        slowest worker, so the data of all processes reach the file together
        (bounded memory, coherent status).
        """
        next_pump = 0.0

        def hook(t_ns: int) -> None:
            nonlocal next_pump
            now = time.monotonic()
            if now >= next_pump:
                self._pump(recorder)
                next_pump = now + WORKER_PUMP_S
            behind = self._workers_t_ns()
            while behind is not None and t_ns > behind + WORKER_LEAD_NS and not should_stop():
                self._pump(recorder, timeout=WORKER_PUMP_S)
                behind = self._workers_t_ns()
            if tick is not None:
                tick(t_ns)

        return hook

    def _finish_workers(self, recorder: Any, should_stop: Callable[[], bool], reason: str) -> str:
        """After this process's share: stop the workers if stopping, and write what they still send."""
        stopping = bool(reason)
        if stopping:
            for w in self._workers:
                w.stop()
        tick = _ticker(recorder)
        while not all(w.done for w in self._workers):
            if not stopping and should_stop():
                stopping, reason = True, "stopped by signal"
                for w in self._workers:
                    w.stop()
            for w in self._workers:
                if w.overdue():
                    w.done, w.reason = True, "stopped"
                    recorder.event(
                        self._workers_t_ns() or 0,
                        "station",
                        "note",
                        f"simulation worker for {', '.join(w.names)} did not stop in time: killed",
                    )
            self._pump(recorder, timeout=WORKER_PUMP_S)
            behind = self._workers_t_ns()
            if tick is not None and behind is not None:
                tick(behind)
            if self._on_status is not None and time.monotonic() >= self._next_status:
                self._emit_status()
        return reason or next((w.reason for w in self._workers if w.reason), "")

    def _run_threaded(self, recorder: Any, end: int, should_stop: Callable[[], bool]) -> str:
        q: queue.SimpleQueue = queue.SimpleQueue()
        stop = threading.Event()
        groups: dict[str, list[tuple[str, str]]] = {}
        for kind, name in self._all_pollers():
            cfg = self.devices[name].config if kind == "device" else self.thermometers[name].config
            groups.setdefault(cfg.bus, []).append((kind, name))
        threads = [
            threading.Thread(
                target=self._reader, args=(pollers, _QueueSink(q), end, stop), name=f"reader {bus}", daemon=True
            )
            for bus, pollers in groups.items()
        ]
        for th in threads:
            th.start()
        tick = _ticker(recorder)
        reason = ""
        try:
            while True:
                try:
                    item = q.get(timeout=WRITER_WAKEUP_S)
                except queue.Empty:
                    item = None
                while item is not None:
                    _dispatch(recorder, item)
                    try:
                        item = q.get_nowait()
                    except queue.Empty:
                        item = None
                now = self.clock.now_ns()
                if tick is not None:
                    tick(now - self.t0)
                if self._on_status is not None and time.monotonic() >= self._next_status:
                    self._emit_status()
                if should_stop():
                    reason = "stopped by signal"
                    break
                if now >= end and not any(th.is_alive() for th in threads):
                    break
        finally:
            stop.set()
            for th in threads:
                th.join()
        # the readers are gone: hand over what they left in the queue
        while True:
            try:
                _dispatch(recorder, q.get_nowait())
            except queue.Empty:
                break
        return reason

    def _reader(self, pollers: list[tuple[str, str]], sink: _QueueSink, end: int, stop: threading.Event) -> None:
        """One bus: poll its devices and thermometers at their intervals until ``end`` or ``stop``."""
        try:
            heap = self._pollers(pollers)
            clock = self.clock
            while heap and not stop.is_set():
                due, seq, kind, name = heap[0]
                if due > end:
                    return
                wait = (due - clock.now_ns()) / 1e9
                if wait > 0 and stop.wait(wait):
                    return
                heapq.heappop(heap)
                interval = self._poll(sink, kind, name)
                # a late poll is not made up for: the next one is one interval later
                heapq.heappush(heap, (max(due + interval, clock.now_ns()), seq, kind, name))
        except BaseException as exc:  # noqa: BLE001 - a bug in a reader must stop the capture, not vanish
            sink._put(("error", exc))

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
                self._store(sink, st, block, st.last_poll_ns)

    # -- one poll ---------------------------------------------------------------------
    def _poll_device(self, sink: Sink, st: DeviceState) -> None:
        name = st.config.name
        clock = self.clock
        if st.failed:
            try:
                st.info = st.driver.open()
            except (BusError, DeviceError):
                st.failed_attempts += 1
                return
            sink.event(
                clock.now_ns() - self.t0,
                name,
                "reconnect",
                f"device re-initialised with the same settings after {st.failed_attempts} failed attempt(s)",
            )
            st.failed, st.failed_attempts, st.resync = False, 0, True
        try:
            block = st.driver.read_block()
        except (BusError, DeviceError) as exc:
            return self._fault(sink, st, str(exc))
        t_read = st.last_poll_ns = clock.now_ns() - self.t0
        self._store(sink, st, block, t_read)

    def _store(self, sink: Sink, st: DeviceState, block: Block, t_read: int) -> None:
        """Log a block's losses and append its samples, the newest dated ``t_read`` (ns) less its age."""
        name = st.config.name
        k = block.n
        if st.resync and not block.lost:
            if k == 0:
                return  # measure the loss at the first samples (a driver may be holding them)
            block.lost, block.note = -1, "samples lost while the device was failing"
            st.last_counter = None  # the device restarted its counter
        st.resync = False
        # the newest sample's time: the read, less the periods it was held
        t_new = t_read - int(round(block.age * st.period_ns))
        counter = block.counter
        if counter is not None and k and not block.lost and self._check_counter(sink, st, counter, t_read):
            block.lost, block.note = -1, "device counter went back (device restarted?): resync"
        if block.lost:
            lost = block.lost
            if lost < 0:
                # the chip cannot count them: samples expected since the last one, minus those read
                last = st.last_t_ns if st.last_t_ns is not None else 0
                lost = max(0, int(round((t_new - last) / st.period_ns)) - k)
            st.lost += lost
            st.gaps += 1
            note = block.note.lower()
            kind = "overrun" if "overrun" in note else "resync" if "resync" in note else "gap"
            sink.event(t_read, name, kind, block.note or "samples lost", lost=lost)
        if k == 0:
            return
        # sample times: the last sample is the newest (at read time unless held), spaced by the ODR
        offsets = st.offsets.get(k)
        if offsets is None:
            offsets = (np.arange(k - 1, -1, -1, dtype=np.float64) * st.period_ns).round().astype(np.int64)
            if len(st.offsets) < _MAX_CACHED_OFFSETS:
                st.offsets[k] = offsets
        t = t_new - offsets
        last = st.last_t_ns
        if last is not None and t[0] <= last:
            # the host read late last time (or early now): the block holds more samples than
            # the ODR fits in the time since the last read; spread them evenly over that time
            # so sample times stay strictly increasing and still end at this read
            t = last + ((t_new - last) * np.arange(1, k + 1, dtype=np.float64) / k).astype(np.int64)
        sink.append(name, t, block.channels, counter)
        st.samples += k
        st.window_samples += k
        st.last_t_ns = t_new
        if counter is not None:
            st.last_counter = int(counter[-1])
        temp = block.channels.get("temp")
        if temp is not None:
            spec = _channel(st.info, "temp")
            st.temp_c = float(temp[-1]) * spec.scale + spec.offset

    def _check_counter(self, sink: Sink, st: DeviceState, counter: np.ndarray, t_read: int) -> bool:
        """Counter jumps within a block and since the last one: log the samples they skipped.

        The counter counts output samples; a driver whose counter wraps gives
        ``counter_modulus`` in its settings (e.g. 65536 for a u16 counter).
        Returns True when the counter went back (the device restarted): the
        caller then measures the block's loss from time instead.
        """
        c = np.asarray(counter, dtype=np.int64)
        if st.last_counter is not None:
            c = np.concatenate(([st.last_counter], c))
        if len(c) < 2:
            return False
        steps = np.diff(c)
        modulus = st.info.settings.get("counter_modulus")
        if modulus:
            steps %= int(modulus)
        bad = np.flatnonzero(steps != 1)
        if not len(bad):
            return False
        back = steps[bad] <= 0
        if back.any():
            return True
        jumps = steps[bad]
        if len(jumps):
            lost = int(np.sum(jumps - 1))
            where = ", ".join(f"{c[i]}->{c[i + 1]}" for i in bad[:_QUOTED_JUMPS])
            st.lost += lost
            st.gaps += 1
            sink.event(t_read, st.config.name, "gap", f"counter jump {where}", lost=lost)
        return False

    def _fault(self, sink: Sink, st: DeviceState, why: str) -> None:
        """Log a device fault once; the device is re-opened at its next polls until it answers."""
        st.faults += 1
        st.failed = True
        st.failed_attempts = 0
        sink.event(self.clock.now_ns() - self.t0, st.config.name, "fault", why)

    def _poll_thermometer(self, sink: Sink, th: ThermometerState) -> None:
        """One reading; a failed reading is one lost reading, logged with the fault and the reconnect."""
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
            return
        t = self.clock.now_ns() - self.t0
        sink.append_temperature(name, np.array([t], dtype=np.int64), np.array([celsius]))
        th.readings += 1
        th.celsius = celsius

    # -- status -------------------------------------------------------------------------
    def _emit_status(self) -> None:
        assert self._on_status is not None
        self._on_status(self.status())
        self._next_status = time.monotonic() + self._status_interval

    def status(self, *, final: bool = False, reason: str = "") -> dict[str, Any]:
        """The live status (see docs/capture.md for the JSON keys)."""
        own_s = (self.clock.now_ns() - self.t0) / 1e9  # this process's station time
        behind = self._workers_t_ns() if self._workers else None
        elapsed = own_s if behind is None else min(own_s, behind / 1e9)
        wall_now = time.monotonic()
        wall = wall_now - self._wall0
        window = wall_now - self._window_wall
        duration = self._duration_s
        speed = elapsed / wall if wall > 0 else None
        devices = {}
        own = {n: w.t_ns / 1e9 for w in self._workers for n in w.names}  # each worker's station time
        for name, st in self.devices.items():
            recent = None
            if window > 0 and not self.virtual:
                recent = st.window_samples / window
            st.window_samples = 0
            t_dev = own.get(name, own_s)
            devices[name] = {
                "state": "failed" if st.failed else "ok",
                "samples": st.samples,
                "rate_hz": st.samples / t_dev if t_dev > 0 else 0.0,
                "rate_recent_hz": recent,
                "rate_cfg_hz": st.info.rate_hz,
                "gaps": st.gaps,
                "lost": st.lost,
                "faults": st.faults,
                "temp_c": _finite(st.temp_c),
            }
        self._window_wall = wall_now
        status = {
            "format": "imustation-status",
            "version": 1,
            "state": ("stopped" if reason else "done") if final else "recording",
            "reason": reason,
            "elapsed_s": elapsed,
            "duration_s": duration,
            "remaining_s": max(0.0, duration - elapsed),
            "wall_s": wall,
            "speed": speed,
            "devices": devices,
            "thermometers": {
                name: {
                    "state": "failed" if th.failed else "ok",
                    "readings": th.readings,
                    "lost": th.lost,
                    "faults": th.faults,
                    "celsius": _finite(th.celsius),
                }
                for name, th in self.thermometers.items()
            },
        }
        file_status = getattr(self._recorder, "status", None)
        if callable(file_status):
            status.update(file_status())
        return status


def _ticker(recorder: Any) -> Callable[[int], None] | None:
    """The recorder's between-polls hook: ``tick(t_ns)``, or a plain writer's ``flush_if_due``."""
    tick = getattr(recorder, "tick", None)
    if tick is None and hasattr(recorder, "flush_if_due"):
        return lambda t_ns: recorder.flush_if_due()
    return tick


def _channel(info: DriverInfo, name: str):
    return next(c for c in info.channels if c.name == name)


def _finite(x: float) -> float | None:
    return x if x == x and abs(x) != float("inf") else None
