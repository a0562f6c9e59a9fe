"""Simulated captures on several cores: bus groups polled in worker processes.

A simulated capture is CPU-bound - chip simulators, bridges, buses and
drivers all run in Python on the virtual clock - and devices on different
buses share nothing. ``capture --simulate --workers N`` therefore splits the
config's bus groups (the same groups the real capture gives one reader thread
each) over N processes. Each worker runs a :class:`Station` of its own over
its devices, on its own virtual clock, and sends what it polled (blocks,
temperatures, events) and its device counters through a pipe to the main
process, which polls its own share and alone writes the run file.

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
import os
import pickle
import signal
import time
import traceback
from collections.abc import Callable, Mapping
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

import numpy as np

from imustation.acquisition.config import StationConfig
from imustation.drivers import DRIVERS, THERMOMETER_DRIVERS
from imustation.drivers.sim import output_rate
from imustation.errors import ImustationError

if TYPE_CHECKING:
    from imustation.acquisition.station import Station

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
class _PipeSink:
    """A worker's recorder: batches of polled items plus the device counters, sent through the pipe."""

    def __init__(self, conn: Connection, station: Station):
        self._conn = conn
        self._station = station
        self._items: list[tuple] = []
        self._next_send = time.monotonic() + SEND_INTERVAL_S
        self.stop_requested = False

    def append(
        self, device: str, t_ns: np.ndarray, channels: Mapping[str, np.ndarray], counter: np.ndarray | None
    ) -> None:
        self._items.append(("append", device, t_ns, dict(channels), counter))

    def append_temperature(self, name: str, t_ns: np.ndarray, celsius: np.ndarray) -> None:
        self._items.append(("temperature", name, t_ns, celsius))

    def event(self, t_ns: int, source: str, kind: str, detail: str = "", lost: int = 0) -> None:
        self._items.append(("event", t_ns, source, kind, detail, lost))

    def tick(self, t_ns: int) -> None:
        if len(self._items) >= SEND_ITEMS or time.monotonic() >= self._next_send:
            self.send("items", t_ns)

    def send(self, kind: str, t_ns: int, *extra: Any) -> None:
        items, self._items = self._items, []
        self._conn.send((kind, items, counters(self._station), t_ns, *extra))
        self._next_send = time.monotonic() + SEND_INTERVAL_S
        while self._conn.poll():
            if self._conn.recv()[0] == "stop":
                self.stop_requested = True


def counters(station: Station) -> dict[str, dict[str, tuple]]:
    """What the main process mirrors of a worker's devices and thermometers."""
    return {
        "devices": {
            n: (st.samples, st.lost, st.gaps, st.faults, st.temp_c, st.failed) for n, st in station.devices.items()
        },
        "thermometers": {
            n: (th.readings, th.lost, th.faults, th.celsius, th.failed) for n, th in station.thermometers.items()
        },
    }


def worker_main(conn: Connection, config: StationConfig, sim_level: str = "bus") -> None:
    """Open the devices of ``config``, report them, record when told, report the end."""
    from imustation.acquisition.station import Station

    # Ctrl-C and a group-wide SIGTERM (systemd, kill -- -PGID) reach the workers too: the main
    # process stops them itself. Both were blocked since before this process existed.
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    station = None
    try:
        station = Station(config, simulate=True, sim_level=sim_level)
        specs = station.open()
        conn.send(
            (
                "opened",
                specs,
                {n: st.info for n, st in station.devices.items()},
                {n: (th.identity, th.period_ns) for n, th in station.thermometers.items()},
            )
        )
        msg = conn.recv()
        if msg[0] != "run":
            return
        _, duration_s, pace = msg
        sink = _PipeSink(conn, station)
        summary = station.run(sink, duration_s, should_stop=lambda: sink.stop_requested, pace=pace)
        sink.send("done", station.clock.now_ns() - station.t0, summary.stop_reason)
    except (BrokenPipeError, EOFError, ConnectionResetError):
        return  # the main process is gone (killed): nothing to report to
    except BaseException as exc:  # noqa: BLE001 - every failure must reach the main process
        try:
            conn.send(("error", _picklable(exc), traceback.format_exc()))
        except Exception:  # noqa: BLE001 - the pipe is gone too
            pass
    finally:
        if station is not None:
            station.close()
        conn.close()


def _picklable(exc: BaseException) -> BaseException:
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
    """One worker process as the main station sees it."""

    def __init__(self, config: StationConfig, index: int, sim_level: str = "bus"):
        ctx = mp.get_context("spawn")  # nothing of the parent's open files, threads or HDF5 state
        self.config = config
        self.names = [d.name for d in config.devices] + [t.name for t in config.thermometers]
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(
            target=worker_main, args=(child, config, sim_level), name=f"imustation-sim-{index}", daemon=True
        )
        # the child inherits the mask: no stop signal can kill it before it ignores them
        old = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            self.process.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        child.close()
        self.stop_sent: float | None = None
        #: station time the worker has reached, ns; None once it is done
        self.t_ns: int = 0
        self.done = False
        self.reason = ""

    def opened(self) -> tuple[list, dict, dict]:
        """Wait for the worker to open its devices: (specs, driver infos, thermometer (identity, period))."""
        if not self.conn.poll(OPEN_TIMEOUT_S):
            who = ", ".join(self.names)
            raise WorkerError(f"simulation worker for {who} did not open them in {OPEN_TIMEOUT_S:g} s")
        msg = self._recv()
        return msg[1], msg[2], msg[3]

    def start(self, duration_s: float, pace: float | None) -> None:
        self.conn.send(("run", duration_s, pace))

    def stop(self) -> None:
        if not self.done and self.stop_sent is None:
            self.stop_sent = time.monotonic()
            try:
                self.conn.send(("stop",))
            except OSError:
                pass

    def overdue(self) -> bool:
        """Told to stop more than ``STOP_TIMEOUT_S`` ago and still not done."""
        return not self.done and self.stop_sent is not None and time.monotonic() - self.stop_sent > STOP_TIMEOUT_S

    def pump(self, dispatch: Callable[[tuple], None], mirror: Callable[[dict], None], timeout: float = 0.0) -> bool:
        """Hand over whatever the worker sent (waiting up to ``timeout`` s for something); True if anything came."""
        got = False
        while not self.done and self.conn.poll(timeout):
            try:
                msg = self._recv()
            except WorkerError:
                if self.stop_sent is None:
                    raise
                self.done, self.reason = True, "stopped"  # told to stop, and gone: that is an end too
                return got
            got = True
            timeout = 0.0
            for item in msg[1]:
                dispatch(item)
            mirror(msg[2])
            self.t_ns = msg[3]
            if msg[0] == "done":
                self.done = True
                self.reason = msg[4]
        return got

    def _recv(self) -> tuple:
        try:
            msg = self.conn.recv()
        except (EOFError, OSError):
            self.process.join(timeout=1.0)
            raise WorkerError(
                f"simulation worker for {', '.join(self.names)} ended without a word"
                f" (exit code {self.process.exitcode})"
            ) from None
        if msg[0] == "error":
            exc = msg[1]
            exc.add_note(f"in the simulation worker for {', '.join(self.names)}:\n{msg[2]}")
            raise exc
        return msg

    def close(self) -> None:
        self.stop()
        # a worker blocked on a full pipe (the main process stopped reading) never sees "stop";
        # it ignores SIGTERM, so it is killed
        self.process.join(timeout=1.0 if self.done else 0.2)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=5.0)
        self.conn.close()
