"""Simulated captures on several cores: bus groups polled in worker processes.

A simulated capture is CPU-bound - chip simulators, bridges, buses and
drivers all run in Python on the virtual clock - and devices on different
buses share nothing. ``capture --simulate --workers N`` therefore splits the
config's bus groups (the same groups the real capture gives one reader thread
each) over N processes. Each worker runs a station of its own over its devices,
on its own virtual clock, and sends what it polled (blocks, temperatures,
events, in the message form of :mod:`~imustation.acquisition.sinks`) and its
device counts through a pipe to the main process, which polls its own share
and alone writes the run file (:class:`WorkerPool` is the main side of it).

The station class a worker runs is handed in (:class:`WorkerPool` takes it), so
this module does not import the station that uses it.

Every device keeps its seed (derived from the station seed and its name), so
its turn-on biases and noise parameters are those of a one-process capture,
and so are its sample counts and spacing; its noise realisation is another
one, because it opens on another clock (the samples a chip makes while the
other devices of its process open are dropped at the start, and sources draw
in the block sizes they are asked for). Each station's time origin is the
end of its own opening.

Worker processes are spawned (not forked): a script that calls
:func:`~imustation.acquisition.capture` with ``workers > 1`` needs the usual
``if __name__ == "__main__":`` guard.
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
import multiprocessing.connection
import os
import pickle
import signal
import time
import traceback
from collections.abc import Callable, Mapping
from multiprocessing.connection import Connection
from typing import Any, Protocol

from imustation.acquisition.config import StationConfig
from imustation.acquisition.readers import ReaderOptions, reader_main
from imustation.acquisition.restarts import (
    OutageLog,
    Restarts,
    carried,
    failed_counts,
    fault_detail,
    lost_to_end,
    reconnect_detail,
)
from imustation.acquisition.sinks import MessageSink, Sink, deliver, shifted
from imustation.drivers import DRIVERS, THERMOMETER_DRIVERS
from imustation.drivers.sim import output_rate
from imustation.errors import ImustationError
from imustation.status import DeviceStatus, ThermometerStatus

#: rough wall cost of one simulated sample by bus kind, us (benchmarks/bench_capture.py --devices:
#: ADIS16448 on a CP2130 ~35, MTi ~12, FIFO devices on I2C ~3-20); balances the split
SIM_COST_US = {"spi": 35.0, "serial": 12.0, "i2c": 8.0}
#: the main process also writes every sample to the run file, us per sample
WRITER_COST_US = 1.5
#: at --sim-level model a sample costs about the same on every bus, and writing it about half
#: as much again (benchmarks/bench_capture.py --profile: generation ~0.9 us, writer ~0.5 us)
MODEL_COST_US = 1.0
MODEL_WRITER_COST_US = 0.5
#: a worker sends what it has at least this often (wall s), or when this many items wait
SEND_INTERVAL_S = 0.02
SEND_ITEMS = 512
#: wall s a worker may take to open its devices, and to finish once told to stop
OPEN_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 10.0
#: what an operator sends to stop a capture; the main process handles them for every process
STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}
#: with worker processes: how often the main process takes in their data (wall s), and how far
#: (station time) it may run ahead of the slowest
PUMP_S = 0.02
LEAD_NS = 10_000_000_000


def bus_groups(config: StationConfig) -> dict[str, list[str]]:
    """Device and thermometer names by bus URL, in config order (one group per reader)."""
    groups: dict[str, list[str]] = {}
    for dev in (*config.devices, *config.thermometers):
        groups.setdefault(dev.bus, []).append(dev.name)
    return groups


def _group_cost_us(config: StationConfig, names: list[str], sim_level: str = "bus") -> float:
    """Estimated wall us per virtual second of polling these devices."""
    cost = 0.0
    for dev in config.devices:
        if dev.name in names:
            per_sample = MODEL_COST_US if sim_level == "model" else SIM_COST_US.get(DRIVERS[dev.driver].bus_kind, 10.0)
            cost += output_rate(dev) * per_sample
    for th in config.thermometers:
        if th.name in names:
            kind = THERMOMETER_DRIVERS[th.driver].bus_kind
            cost += float(th.settings.get("rate_hz", 1.0)) * SIM_COST_US.get(kind, 10.0)
    return cost


def default_workers(config: StationConfig) -> int:
    """One process per usable core, at most one per bus group."""
    return max(1, min(len(os.sched_getaffinity(0)), len(bus_groups(config))))


def partition(config: StationConfig, workers: int, sim_level: str = "bus") -> list[list[str]]:
    """Split the bus groups over ``workers`` processes, heaviest first to the least loaded.

    Returns the device/thermometer names of each process; the first list is the
    main process's (which also carries the writer's cost). Empty shares are dropped.
    """
    costs = [(_group_cost_us(config, names, sim_level), names) for names in bus_groups(config).values()]
    total_rate = sum(output_rate(d) for d in config.devices)
    writer = MODEL_WRITER_COST_US if sim_level == "model" else WRITER_COST_US
    loads = [total_rate * writer] + [0.0] * (max(1, workers) - 1)
    shares: list[list[str]] = [[] for _ in loads]
    for cost, names in sorted(costs, key=lambda c: -c[0]):
        i = min(range(len(loads)), key=loads.__getitem__)
        shares[i].extend(names)
        loads[i] += cost
    return [shares[0]] + [s for s in shares[1:] if s]


def subset(config: StationConfig, names: list[str]) -> StationConfig:
    """The config restricted to ``names`` (devices and thermometers)."""
    keep = set(names)
    return dataclasses.replace(
        config,
        devices=tuple(d for d in config.devices if d.name in keep),
        thermometers=tuple(t for t in config.thermometers if t.name in keep),
    )


# -- worker side ---------------------------------------------------------------------------
class LocalStation(Protocol):
    """What a worker process runs: the station class handed to :class:`WorkerPool` (``Station``)."""

    thermometers: Mapping[str, Any]

    def open(self) -> list: ...

    def run(self, recorder: Any, duration_s: float, *, should_stop: Callable[[], bool], pace: float | None) -> Any: ...

    def elapsed_ns(self) -> int: ...

    def counts(self) -> tuple[dict[str, DeviceStatus], dict[str, ThermometerStatus]]: ...

    def close(self) -> None: ...


class _PipeSink(MessageSink):
    """A worker's recorder: batches of sink messages plus the station's counts, sent through the pipe."""

    def __init__(self, conn: Connection, counts: Callable[[], tuple]):
        self._items: list[tuple] = []
        super().__init__(self._items.append)
        self._conn = conn
        self._counts = counts
        self._next_send = time.monotonic() + SEND_INTERVAL_S
        self.stop_requested = False

    def tick(self, t_ns: int) -> None:
        if len(self._items) >= SEND_ITEMS or time.monotonic() >= self._next_send:
            self.send("items", t_ns)

    def send(self, kind: str, t_ns: int, *extra: Any) -> None:
        self._conn.send((kind, self._items, self._counts(), t_ns, *extra))
        self._items.clear()  # pickled by send: the list is free again
        self._next_send = time.monotonic() + SEND_INTERVAL_S
        while self._conn.poll():
            if self._conn.recv()[0] == "stop":
                self.stop_requested = True


def worker_main(
    conn: Connection, config: StationConfig, sim_level: str, station_cls: Callable[..., LocalStation]
) -> None:
    """Open the devices of ``config``, report them, record when told, report the end."""
    # Ctrl-C and a group-wide SIGTERM (systemd, kill -- -PGID) reach the workers too: the main
    # process stops them itself. Both were blocked since before this process existed.
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    station = None
    try:
        station = station_cls(config, simulate=True, sim_level=sim_level)
        devices = station.open()
        conn.send(("opened", devices, {n: (th.identity, th.period_ns) for n, th in station.thermometers.items()}))
        msg = conn.recv()
        if msg[0] != "run":
            return
        _, duration_s, pace = msg
        sink = _PipeSink(conn, station.counts)
        summary = station.run(sink, duration_s, should_stop=lambda: sink.stop_requested, pace=pace)
        sink.send("done", station.elapsed_ns(), summary.stop_reason)
    except (BrokenPipeError, EOFError, ConnectionResetError):
        return  # the main process is gone (killed): nothing to report to
    except BaseException as exc:  # noqa: BLE001 - every failure must reach the main process
        try:
            conn.send(("error", picklable(exc), traceback.format_exc()))
        except Exception:  # noqa: BLE001 - the pipe is gone too
            pass
    finally:
        if station is not None:
            station.close()
        conn.close()


def picklable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else its nearest project error class with its message."""
    if _round_trips(exc):
        return exc
    for cls in type(exc).__mro__:
        if isinstance(cls, type) and issubclass(cls, ImustationError):
            try:
                twin = cls(str(exc))
            except Exception:  # noqa: BLE001 - a constructor with other arguments
                continue
            if _round_trips(twin):
                return twin
    return RuntimeError(f"{type(exc).__name__}: {exc}")


def _round_trips(exc: BaseException) -> bool:
    try:
        pickle.loads(pickle.dumps(exc))
        return True
    except Exception:  # noqa: BLE001 - exceptions with odd constructors
        return False


class WorkerError(ImustationError):
    """A simulation worker process ended without saying why (killed, crashed)."""


# -- main-process side ---------------------------------------------------------------------
class Worker:
    """One worker process as the main station sees it: a simulation worker, or with ``host`` a
    reader process of a host-clock capture (:mod:`~imustation.acquisition.readers`)."""

    def __init__(
        self,
        config: StationConfig,
        index: int,
        sim_level: str,
        station_cls: Callable[..., LocalStation],
        host: ReaderOptions | None = None,
    ):
        self.config = config
        self.host = host
        self.names = [d.name for d in config.devices] + [t.name for t in config.thermometers]
        #: the bus URL(s) it polls
        self.config_bus = ", ".join(dict.fromkeys(d.bus for d in (*config.devices, *config.thermometers)))
        self._spawn_args = (index, sim_level, station_cls)
        self._spawn()
        self.stop_sent: float | None = None
        #: station time the worker has reached, ns
        self.t_ns: int = 0
        self.done = False
        self.reason = ""
        #: host clock: the run's origin (ns), and the reader's own origin less it (its times are moved by it)
        self.t0: int | None = None
        self.offset_ns = 0
        #: what a reader process obtained from the OS (readers.Scheduling), when it opened
        self.scheduling: Any = None
        #: a reader process lost during the run: why ("" while it runs)
        self.lost_reason = ""
        #: the run's planned end, station ns
        self.end_ns = 0
        #: CPU time the process used, s (reader processes, when done)
        self.cpu_s: float | None = None
        #: a lost reader process is started again after a back-off (restarts.Restarts)
        self.restarts = Restarts(OPEN_TIMEOUT_S)
        self._duration_s = 0.0
        self._pace: float | None = None
        #: the counts its earlier processes reached (a restarted reader's are added to them)
        self._base: tuple = ({}, {})
        #: what its devices handed over last, and the gap of each outage after a restart
        self.outages = OutageLog(self.what, self._add_gap)

    def _spawn(self) -> None:
        """Start the process (again, for a lost reader)."""
        index, sim_level, station_cls = self._spawn_args
        ctx = mp.get_context("spawn")  # nothing of the parent's open files, threads or HDF5 state
        self.conn, child = ctx.Pipe()
        data_w = None
        if self.host is None:
            target, args, kind = worker_main, (child, self.config, sim_level, station_cls), "sim"
        else:
            # the data come on a one-way pipe of their own, which the reader writes without blocking
            self.data, data_w = ctx.Pipe(duplex=False)
            target, args, kind = reader_main, (child, data_w, self.config, station_cls, self.host), "reader"
        self.process = ctx.Process(target=target, args=args, name=f"imustation-{kind}-{index}", daemon=True)
        # the child inherits the mask: no stop signal can kill it before it ignores them
        old = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            self.process.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        child.close()
        if data_w is not None:
            data_w.close()
        else:
            self.data = self.conn

    @property
    def restarting(self) -> bool:
        """A lost reader process waiting to be started again, or its successor opening its devices."""
        return self.restarts.pending

    @property
    def what(self) -> str:
        kind = "simulation worker" if self.host is None else "reader process"
        return f"{kind} for {', '.join(self.names)}"

    def opened(self) -> tuple[list, dict[str, tuple[str, int]]]:
        """Wait for the worker to open its devices: (its opened devices, thermometer (identity, period ns))."""
        if not self.conn.poll(OPEN_TIMEOUT_S):
            raise WorkerError(f"{self.what} did not open them in {OPEN_TIMEOUT_S:g} s")
        msg = self._recv(self.conn)
        if len(msg) > 3:
            self.scheduling = msg[3]
        self.outages.opened(msg[1], msg[2])
        return msg[1], msg[2]

    @property
    def rates(self) -> dict[str, float]:
        """Its devices' output rates, Hz."""
        return self.outages.rates

    @property
    def last_t(self) -> dict[str, int]:
        """Station time of each device's last sample handed over, ns."""
        return self.outages.last_t

    def start(self, duration_s: float, pace: float | None, t0: int | None = None) -> None:
        """Tell the worker to record; ``t0``: the run's origin on the host clock (reader processes)."""
        self.end_ns = round(duration_s * 1e9)
        self._duration_s, self._pace = duration_s, pace
        if self.host is None:
            self.conn.send(("run", duration_s, pace))
        else:
            self.t0 = t0
            self.conn.send(("run", duration_s, pace, t0))

    def stop(self) -> None:
        if self.restarting and not self.done:
            # nothing of it is recording: it ends here (its devices' gap runs to now)
            self.restarts.cancel()
            self.done, self.reason = True, "stopped"
            self._kill()
            return
        if not self.done and self.stop_sent is None:
            self.stop_sent = time.monotonic()
            try:
                self.conn.send(("stop",))
            except OSError:
                pass

    def overdue(self) -> bool:
        """Told to stop more than ``STOP_TIMEOUT_S`` ago and still not done."""
        return not self.done and self.stop_sent is not None and time.monotonic() - self.stop_sent > STOP_TIMEOUT_S

    def pump(self, sink: Sink, mirror: Callable[[tuple], None], timeout: float = 0.0) -> bool:
        """Hand what the worker sent to ``sink`` and its counts to ``mirror`` (waiting up to ``timeout`` s
        for something); True if anything came.

        A reader process that fails or ends without a word is a fault of its devices
        (:meth:`lose`); a simulation worker's failure is raised.
        """
        got = False
        if self.restarting:
            self._tend(sink, mirror)
            return False
        while not self.done and self.data.poll(timeout):
            try:
                msg = self._recv(self.data)
            except Exception as exc:  # noqa: BLE001 - a reader's failure is logged, not raised
                if self.stop_sent is not None and isinstance(exc, WorkerError):
                    self.done, self.reason = True, "stopped"  # told to stop, and gone: that is an end too
                    return got
                if self.host is None:
                    raise
                self.lose(sink, mirror, str(exc) if isinstance(exc, WorkerError) else f"{type(exc).__name__}: {exc}")
                return got
            got = True
            timeout = 0.0
            if msg[0] == "started" and self.t0 is not None:
                self.offset_ns = msg[4] - self.t0
            off = self.offset_ns
            seen = self.outages.seen
            for item in msg[1]:
                if off:
                    item = shifted(item, off)
                seen(sink, item)
                deliver(sink, item)
            mirror(carried(self._base, msg[2]))
            self.t_ns = msg[3] + off
            if msg[0] == "done":
                self.done = True
                self.reason = msg[4]
                if len(msg) > 5:
                    self.cpu_s = msg[5]
        return got

    def lose(self, sink: Sink, mirror: Callable[[tuple], None], why: str) -> None:
        """A reader process is gone mid-run: each of its devices and thermometers gets a ``fault`` event
        and is ``failed`` in the status, and the reader is started again after a back-off
        (:class:`~imustation.acquisition.restarts.Restarts`; never: its devices are not read for the
        rest of the capture); the capture goes on with the other buses."""
        self.lost_reason = why
        self.outages.lost(sink)
        t = time.monotonic_ns() - (self.t0 or 0)
        self.t_ns = t
        self._base = failed_counts(carried(self._base, self._counts), self.rates, self.names)
        self._counts = ({}, {})
        mirror(self._base)
        self._kill()
        delay = self.restarts.lost(time.monotonic())
        for name in self.names:
            sink.event(t, name, "fault", fault_detail(self.what, why, delay))
        self.done = delay is None

    def _tend(self, sink: Sink, mirror: Callable[[tuple], None]) -> None:
        """A lost reader process: start it again when its back-off is over, tell it to record once it has
        opened its devices; a successor that fails to open them is another attempt, backed off in turn."""
        now = time.monotonic()
        self.t_ns = time.monotonic_ns() - (self.t0 or 0)  # nothing of it comes from before now
        restarts = self.restarts
        if self.t_ns >= self.end_ns:
            restarts.cancel()
            self.done = True  # the run is over: gap to its end
            self._kill()
            return
        if not restarts.reopening:
            if restarts.due(now):
                self._close_pipes()
                restarts.started(now)
                self._spawn()
            return
        try:
            if not self.conn.poll(0):
                if not restarts.opening_too_long(now):
                    return
                raise WorkerError(f"{self.what} did not open them in {OPEN_TIMEOUT_S:g} s")
            msg = self._recv(self.conn)
            self.conn.send(("run", self._duration_s, self._pace, self.t0))
        except Exception as exc:  # noqa: BLE001 - the successor failed too: another attempt later
            self._kill()
            self.done = restarts.lost(now) is None
            self.lost_reason = str(exc) if isinstance(exc, WorkerError) else f"{type(exc).__name__}: {exc}"
            return
        attempts = restarts.reopened()
        self.lost_reason, self.offset_ns = "", 0
        if len(msg) > 3:
            self.scheduling = msg[3]
        t = time.monotonic_ns() - (self.t0 or 0)
        for name in self.names:
            sink.event(t, name, "reconnect", reconnect_detail(self.what, attempts))
        self.outages.restarted(self.names)

    def _add_gap(self, name: str, lost: int) -> None:
        """An outage gap logged: counted with the counts its earlier processes reached."""
        devices, thermometers = self._base
        if name in devices:
            c = devices[name]
            devices[name] = dataclasses.replace(c, gaps=c.gaps + 1, lost=c.lost + lost)
        elif name in thermometers:
            thermometers[name] = dataclasses.replace(thermometers[name], lost=thermometers[name].lost + lost)

    @property
    def pending_outage(self) -> dict[str, int]:
        """After a restart: the devices and thermometers without a sample yet."""
        return self.outages.pending

    def flush_outages(self, sink: Sink, mirror: Callable[[tuple], None]) -> None:
        """At the end: log the outage gaps still waiting for their devices' first samples."""
        if self.outages.flush(sink):
            mirror(carried(self._base, self._counts))

    def _kill(self) -> None:
        if self.process.is_alive():
            self.process.kill()
        self.process.join(timeout=5.0)

    def _close_pipes(self) -> None:
        self.conn.close()
        if self.data is not self.conn:
            self.data.close()

    def _recv(self, conn: Connection) -> tuple:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            self.process.join(timeout=1.0)
            raise WorkerError(f"{self.what} ended without a word (exit code {self.process.exitcode})") from None
        if msg[0] == "error":
            exc = msg[1]
            exc.add_note(f"in the {self.what}:\n{msg[2]}")
            raise exc
        if len(msg) > 2 and isinstance(msg[2], tuple):
            self._counts = msg[2]
        return msg

    _counts: tuple = ({}, {})

    def close(self) -> None:
        self.stop()
        # a worker blocked on a full pipe (the main process stopped reading) never sees "stop";
        # it ignores SIGTERM, so it is killed
        self.process.join(timeout=1.0 if self.done else 0.2)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=5.0)
        self._close_pipes()


class WorkerPool:
    """The worker processes of a capture: start, take in their data, keep pace, finish.

    Parameters
    ----------
    config : the whole station config.
    shares : device/thermometer names per worker process (see :func:`partition`).
    sim_level : the capture's simulation level.
    station_cls : the station class each worker runs over its share.
    host : reader processes of a host-clock capture (:mod:`~imustation.acquisition.readers`);
        None: simulation workers, each on its virtual clock.

    The pool keeps the latest counts each worker sent (``devices``,
    ``thermometers``: :class:`~imustation.status.DeviceStatus` and
    :class:`~imustation.status.ThermometerStatus` by name).
    """

    def __init__(
        self,
        config: StationConfig,
        shares: list[list[str]],
        sim_level: str,
        station_cls: Callable[..., LocalStation],
        host: ReaderOptions | None = None,
    ):
        self.host = host
        self.workers: list[Worker] = []
        try:
            for i, share in enumerate(shares, 1):
                options = None if host is None else dataclasses.replace(host, index=i - 1)
                self.workers.append(Worker(subset(config, share), i, sim_level, station_cls, options))
        except BaseException:
            self.close()
            raise
        self.devices: dict[str, DeviceStatus] = {}
        self.thermometers: dict[str, ThermometerStatus] = {}

    def opened(self) -> list[tuple[Worker, list, dict[str, tuple[str, int]]]]:
        """Wait for every worker to open its share: (worker, opened devices, thermometers) each."""
        return [(w, *w.opened()) for w in self.workers]

    def start(self, duration_s: float, pace: float | None, t0: int | None = None) -> None:
        for w in self.workers:
            w.start(duration_s, pace, t0)

    def stop(self) -> None:
        for w in self.workers:
            w.stop()

    def close(self) -> None:
        for w in self.workers:
            try:
                w.close()
            except Exception:  # noqa: BLE001 - closing must not mask the capture's outcome
                pass

    def t_ns(self) -> int | None:
        """Station time every running worker has reached, ns (None: all done)."""
        running = [w.t_ns for w in self.workers if not w.done]
        return min(running) if running else None

    def station_s(self) -> dict[str, float]:
        """Station time of the worker polling each device/thermometer, s."""
        return {n: w.t_ns / 1e9 for w in self.workers for n in w.names}

    def pump(self, sink: Sink, timeout: float = 0.0) -> bool:
        """Hand what the workers sent to ``sink`` (waiting up to ``timeout`` s for any); True if anything came."""
        if timeout > 0:
            waiting = [w.data for w in self.workers if not w.done and not w.restarting]
            if waiting:
                multiprocessing.connection.wait(waiting, timeout)
        got = False
        for w in self.workers:
            got |= w.pump(sink, self._mirror)
        return got

    def _mirror(self, counts: tuple[dict[str, DeviceStatus], dict[str, ThermometerStatus]]) -> None:
        self.devices.update(counts[0])
        self.thermometers.update(counts[1])

    def keep_pace(
        self, sink: Sink, tick: Callable[[int], None] | None, should_stop: Callable[[], bool]
    ) -> Callable[[int], None]:
        """The main process's between-polls hook: take in the workers' data and stay in step with them.

        The main process runs at most ``LEAD_NS`` of station time ahead of the
        slowest worker, so the data of all processes reach the file together
        (bounded memory, coherent status). ``tick``: the recorder's own hook, called after.
        """
        next_pump = 0.0

        def hook(t_ns: int) -> None:
            nonlocal next_pump
            now = time.monotonic()
            if now >= next_pump:
                self.pump(sink)
                next_pump = now + PUMP_S
            behind = self.t_ns()
            while behind is not None and t_ns > behind + LEAD_NS and not should_stop():
                self.pump(sink, timeout=PUMP_S)
                behind = self.t_ns()
            if tick is not None:
                tick(t_ns)

        return hook

    def finish(
        self,
        sink: Sink,
        should_stop: Callable[[], bool],
        reason: str,
        tick: Callable[[int], None] | None,
        waiting: Callable[[], None],
    ) -> str:
        """After the main process's share: stop the workers if stopping, and write what they still send.

        ``reason``: why the main process stopped early ("" at the end of the duration);
        ``tick``: the recorder's hook, at the slowest worker's time; ``waiting``: called
        at every wait (status). Returns why the capture stopped, "" when it did not.
        A host-clock capture (reader processes, nothing polled by the main process)
        spends its whole run here.
        """
        stopping = bool(reason)
        if stopping:
            self.stop()
        while not all(w.done for w in self.workers):
            if not stopping and should_stop():
                stopping, reason = True, "stopped by signal"
                self.stop()
            for w in self.workers:
                if w.overdue():
                    w.done, w.reason = True, "stopped"
                    sink.event(self.t_ns() or w.t_ns, "station", "note", f"{w.what} did not stop in time: killed")
            self.pump(sink, timeout=PUMP_S)
            behind = self.t_ns()
            if tick is not None and behind is not None:
                tick(behind)
            waiting()
        self._count_lost_readers(sink)
        return reason or next((w.reason for w in self.workers if w.reason), "")

    def _count_lost_readers(self, sink: Sink) -> None:
        """Each device of a reader lost mid-run: one ``gap`` after its last sample with the samples its
        rate fits from there to the end of the capture (written + logged losses = produced)."""
        for w in self.workers:
            w.flush_outages(sink, self._mirror)
            if w.t0 is None:
                continue
            # a reader lost for good, or restarted but ended before a device's first sample
            rates = w.rates if w.lost_reason else {n: r for n, r in w.rates.items() if n in w.pending_outage}
            end = min(time.monotonic_ns() - w.t0, w.end_ns)
            for name, lost in lost_to_end(sink, w.what, rates, w.last_t, end).items():
                c = self.devices.get(name)
                if c is not None:
                    self.devices[name] = dataclasses.replace(c, gaps=c.gaps + 1, lost=c.lost + lost)
