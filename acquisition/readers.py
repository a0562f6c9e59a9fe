"""Host-clock captures: every bus polled by a reader process of its own, the run file written by the main process.

On the host clock a sample of a device without a FIFO (the ADIS16448: 2.4 ms at
409.6 Hz) is lost whenever its reader is held up for longer than that. In one
process, reader threads share the interpreter lock with the writer, which
compresses, writes and fsyncs the HDF5 file and draws the status: held up for
milliseconds. So a capture on the host clock (a real one, or ``capture --simulate
--real-time``) runs each bus group - the devices and thermometers of one bus URL,
which must not be polled concurrently - in a process of its own, spawned through
:class:`~imustation.acquisition.workers.WorkerPool` (the mechanism simulated
captures use with ``--workers``). A reader process

* asks the operating system for timely scheduling (:mod:`~imustation.acquisition.realtime`);
* opens its devices (identity, settings) and reports them, as a simulation worker does;
* on "run", polls them in one thread against their hold times
  (:func:`~imustation.acquisition.scheduler.run_deadline`) on the host clock;
* hands what it polled to the main process as :mod:`~imustation.acquisition.sinks`
  messages through a pipe of its own, written without ever blocking
  (:class:`HostOutbox`): while the writer is busy the messages wait in the
  pipe (enlarged to 1 MiB where permitted) and then in the reader's memory, and
  the reader polls on;
* sends its station time reached, its device counts and, at the start, its own
  time origin: the main process moves every time it sends onto the run's origin
  (the host clock is the same in every process).

Stop signals are for the main process (readers ignore them) and a reader the
main process lost is a device fault logged in the run file, not the end of the
capture (:class:`~imustation.acquisition.workers.WorkerPool`): it is started
again after a back-off, re-opens its devices, and what they made meanwhile is
one logged gap per device (:mod:`~imustation.acquisition.restarts`).
"""

from __future__ import annotations

import fcntl
import gc
import os
import pickle
import signal
import struct
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

from imustation.acquisition.config import StationConfig
from imustation.acquisition.realtime import READER_PRIORITY, reader_priority, release_scheduling, request_scheduling
from imustation.acquisition.scheduler import DeadlineStats
from imustation.acquisition.sinks import MessageSink
from imustation.clock import MonotonicClock

#: a reader hands over what it has at least this often (wall s), or when this many items wait
SEND_INTERVAL_S = 0.02
SEND_ITEMS = 512
#: while waiting for the run to start, a reader empties its devices' buffers this often, s
WAIT_DRAIN_S = 0.1
#: pipe capacity asked for (Linux F_SETPIPE_SZ; /proc/sys/fs/pipe-max-size caps it, 1 MiB by default)
PIPE_BYTES = 2**20
F_SETPIPE_SZ = 1031  # <linux/fcntl.h>: F_LINUX_SPECIFIC_BASE + 7
#: noise samples a simulated chip's source draws at a time in a reader process: the virtual clock's
#: 65536 (160 s of the ADIS16448) cost ~45 ms in one poll, 18 of its samples on the host clock
HOST_SIM_BLOCK = 512
#: the signals the main process handles for every process
STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


@dataclass(frozen=True)
class ReaderOptions:
    """How a reader process runs: simulated chips or hardware, its index among the readers, its scheduling."""

    simulate: bool
    index: int = 0
    #: CPUs the readers run on (None: the kernel places them)
    cpus: tuple[int, ...] | None = None
    #: SCHED_FIFO base priority (realtime.reader_priority adds to it by hold time); 0 asks for nothing
    priority: int = READER_PRIORITY
    #: hybrid sleep before polls of a device without a FIFO, us (0: off; scheduler.run_deadline)
    spin_us: int = 0
    #: poll a device without a FIFO just after it makes each sample (acquisition/pollphase.py); False: blind
    phase: bool = True


class HostOutbox(MessageSink):
    """A reader's sink: sink messages in batches, framed as :class:`multiprocessing.connection.Connection`
    frames (so the main side reads them with ``recv``) and written to a non-blocking pipe.

    A frame the pipe cannot take now waits in ``pending`` and is written at the next
    ``tick``: the reader never waits for the writer. ``stop_requested`` turns True when
    the main process sends "stop" on ``control``.
    """

    def __init__(self, data: Connection, counts: Callable[[], Any], control: Connection):
        self._items: list[tuple] = []
        super().__init__(self._items.append)
        self._data = data
        self._fd = data.fileno()
        os.set_blocking(self._fd, False)
        try:
            fcntl.fcntl(self._fd, F_SETPIPE_SZ, PIPE_BYTES)
        except OSError:
            pass  # the default 64 KiB; the reader's memory takes the rest
        self._counts = counts
        self._control = control
        self.pending = bytearray()
        self._next_send = time.monotonic() + SEND_INTERVAL_S
        self.stop_requested = False

    def tick(self, t_ns: int) -> None:
        """Between polls: hand over the batch when due, else go on writing what waits."""
        if len(self._items) >= SEND_ITEMS or time.monotonic() >= self._next_send:
            self.send("items", t_ns)
        elif self.pending:
            self._write()

    def send(self, kind: str, t_ns: int, *extra: Any) -> None:
        """Frame ``(kind, items, counts, t_ns, *extra)`` after what waits, write what the pipe takes."""
        payload = pickle.dumps((kind, self._items, self._counts(), t_ns, *extra), pickle.HIGHEST_PROTOCOL)
        self._items.clear()
        self.pending += struct.pack("!i", len(payload)) + payload
        self._write()
        self._next_send = time.monotonic() + SEND_INTERVAL_S
        while self._control.poll():
            if self._control.recv()[0] == "stop":
                self.stop_requested = True

    def _write(self) -> None:
        while self.pending:
            try:
                n = os.write(self._fd, self.pending)
            except BlockingIOError:
                return
            del self.pending[:n]

    def close(self) -> None:
        """Write everything that waits, now waiting for the pipe (the reader has finished polling)."""
        os.set_blocking(self._fd, True)
        self._write()

    def should_stop(self) -> bool:
        return self.stop_requested


def reader_main(
    conn: Connection,
    data: Connection,
    config: StationConfig,
    station_cls: Callable[..., Any],
    options: ReaderOptions,
) -> None:
    """A reader process: scheduling, open the devices of ``config``, report them, poll them when told.

    ``conn``: the control pipe ("opened" out; "run" and "stop" in); ``data``: the
    pipe everything polled goes out on ("started", "items", "done" or "error").
    """
    # the main process stops the readers itself; both signals were blocked since before this
    # process existed (see Worker), so none can end it before it ignores them
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    station = None
    out: HostOutbox | None = None
    try:
        if options.simulate:
            from imustation.drivers.sim.sources import NoiseSource

            NoiseSource.BLOCK = HOST_SIM_BLOCK
        station = station_cls(config, simulate=options.simulate, clock=MonotonicClock(), reader_process=True)
        devices = station.open()
        # opened (its memory mapped): what it keeps from now on is never scanned by the collector,
        # whose pauses would otherwise grow with it
        gc.freeze()
        priority = reader_priority(options.priority, station.shortest_hold_s())
        scheduling = request_scheduling(priority=priority, cpus=options.cpus)
        thermometers = {n: (th.identity, th.period_ns) for n, th in station.thermometers.items()}
        conn.send(("opened", devices, thermometers, scheduling))
        # the other readers open and the file is created meanwhile (seconds): what the devices make
        # until the run starts is dropped, before it overflows a buffer (a cut line, a resync)
        while not conn.poll(WAIT_DRAIN_S):
            station.discard()
        msg = conn.recv()
        if msg[0] != "run":
            return
        _, duration_s, _pace, t0 = msg
        out = HostOutbox(data, station.counts, conn)
        station.start(out)
        out.send("started", 0, station.t0)
        station.spin_ns, station.deadline_stats = options.spin_us * 1000, DeadlineStats()
        station.phase_lock = options.phase
        steal0 = steal_s()
        cpu0 = time.process_time()
        # the run ends when the main process's does: its origin plus the duration
        remaining_s = max(0.0, (t0 + round(duration_s * 1e9) - station.t0) / 1e9)
        summary = station.run(out, remaining_s, should_stop=out.should_stop)
        release_scheduling()
        note = lateness_note(config, station.deadline_stats, options.spin_us, steal_s() - steal0)
        if note:
            out.event(station.elapsed_ns(), "station", "note", note)
        out.send("done", station.elapsed_ns(), summary.stop_reason, time.process_time() - cpu0)
        out.close()
    except (BrokenPipeError, EOFError, ConnectionResetError):
        return  # the main process is gone (killed): nothing to report to
    except BaseException as exc:  # noqa: BLE001 - every failure must reach the main process
        from imustation.acquisition.workers import picklable

        report = ("error", picklable(exc), traceback.format_exc())
        try:
            if out is None:
                conn.send(report)
            else:
                out.close()  # what was polled before the failure goes first
                data.send(report)
        except Exception:  # noqa: BLE001 - the pipe is gone too
            pass
    finally:
        release_scheduling()
        if station is not None:
            station.close()
        conn.close()
        data.close()


def steal_s() -> float:
    """CPU time the hypervisor has run other guests on this machine's CPUs since boot, s (``steal`` in
    /proc/stat; 0 where there is none or no /proc): a reader not run for tens of ms on a virtual machine
    is often this, which nothing inside the machine changes."""
    try:
        with open("/proc/stat") as fh:
            fields = fh.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK") if fields[0] == "cpu" and len(fields) > 8 else 0.0
    except (OSError, ValueError):
        return 0.0


def lateness_note(config: StationConfig, stats: DeadlineStats | None, spin_us: int, steal: float) -> str:
    """One line for the run file when polls of the reader's devices without a FIFO started late (later
    than half their hold time after due: a sample at risk), with what the host took meanwhile; "" when
    none did."""
    if stats is None or not stats.late:
        return ""
    bus = ", ".join(dict.fromkeys(d.bus for d in config.devices))
    spin = f", hybrid sleep {spin_us} us" if spin_us else ""
    host = f"; the hypervisor ran other guests for {steal:.2f} s of CPU meanwhile (steal)" if steal > 0 else ""
    return (
        f"reader process for {bus}: {stats.late} of {stats.polls} polls started over "
        f"{stats.hold_ns / 2e6:.2f} ms late (the latest {stats.worst_ns / 1e6:.1f} ms){spin}{host}"
    )
