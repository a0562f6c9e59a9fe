"""When each device and thermometer is polled: three schedulers over the same per-device polls.

* :func:`run_virtual` (simulation, replay): one thread and one event queue (a heap
  of due times) for every device; sleeping only advances the clock, so hours are
  recorded in seconds, and the same seed gives the same file contents.
* :func:`run_threaded` (real clock): one reader thread per bus URL (the devices of
  one I2C adapter share the thread, hence the bus; other buses run in parallel,
  so a slow bus cannot starve another) and the calling thread as the single
  writer that owns the HDF5 file (h5py is not thread-safe): readers hand their
  data over a queue as :mod:`~imustation.acquisition.sinks` messages (a host-clock
  capture with ``--trace``, and tests that impose a clock).
* :func:`run_deadline` (host clock, a reader process of
  :mod:`~imustation.acquisition.readers`): one bus in one thread, polled against
  each device's hold time: the time its oldest unread sample stays before it is
  overwritten (one output period for a chip without a FIFO, its buffer for the
  others). A device is polled at least twice per hold time, and when several are
  due the one whose hold runs out first goes first (earliest deadline first).
  Optionally (``spin_ns``) the last moments before a poll of a device without a
  FIFO are waited for by reading the clock instead of sleeping (hybrid sleep), and
  how late its polls started is kept (:class:`DeadlineStats`). A chip without a FIFO
  is polled just after it makes each sample once its reads show when
  (:mod:`~imustation.acquisition.pollphase`): a poll may then be held up for most of a
  period, not half of one, and it is read once a sample instead of twice.

A :class:`Poller` is one device or thermometer: ``poll(sink)`` reads it once and
returns the interval to its next poll. Times are ns on the station clock.
"""

from __future__ import annotations

import heapq
import queue
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from imustation.acquisition.pollphase import PollPhase
from imustation.acquisition.sinks import MessageSink, Sink, deliver
from imustation.clock import Clock

#: how long the writer thread waits for data before doing its periodic work, s
WRITER_WAKEUP_S = 0.05
#: run_deadline: polls per hold time at least (a poll up to half a hold late still reads every sample)
POLLS_PER_HOLD = 2
#: run_deadline: its ``between`` hook runs at least this often (ns) even while polls are due
BETWEEN_NS = 20_000_000
#: run_deadline: longest sleep (s), so a stop is seen promptly even with nothing due
MAX_SLEEP_S = 0.02
#: run_deadline with ``spin_ns``: only a poll of a device holding its samples at most this long (ns) is
#: waited for by spinning (a chip without a FIFO: the ADIS16448's 2.44 ms), never a FIFO's
SPIN_HOLD_NS = 5_000_000


@dataclass(frozen=True)
class Poller:
    """One device or thermometer: its bus (threads are per bus), its first interval (ns) and its poll."""

    name: str
    bus: str
    interval_ns: int
    #: read the device once into the sink; return the interval to its next poll, ns
    poll: Callable[[Sink], int]
    #: how long a sample waits in the device before it is overwritten or dropped, ns (0: unknown,
    #: nothing is lost by a late poll - a thermometer); only :func:`run_deadline` uses it
    hold_ns: int = 0
    #: a chip without a FIFO: when it makes its samples (the poll updates it); only :func:`run_deadline`
    #: uses it, to poll just after each sample is made once it is known
    phase: PollPhase | None = None


@dataclass
class DeadlineStats:
    """How late :func:`run_deadline` started its polls of the devices with the shortest hold time.

    ``late``: polls that started later than half that hold time after they were due (a sample at risk;
    with the two polls per hold, one already lost if the poll before was late too); ``worst_ns``: the
    latest start, ns after due; ``spun_ns``: time spent spinning (hybrid sleep), ns.
    """

    hold_ns: int = 0
    polls: int = 0
    late: int = 0
    worst_ns: int = 0
    spun_ns: int = 0
    #: start lateness of each late poll, ns (the first 100)
    late_ns: list[int] = field(default_factory=list)

    def add(self, lateness_ns: int) -> None:
        self.polls += 1
        if lateness_ns > self.worst_ns:
            self.worst_ns = lateness_ns
        if lateness_ns > self.hold_ns // 2:
            self.late += 1
            if len(self.late_ns) < 100:
                self.late_ns.append(lateness_ns)


def _busy() -> None:
    """One turn of a spin: nothing, the clock is read again at once."""


def _heap(pollers: Sequence[Poller], t0: int) -> list[tuple[int, int]]:
    """Initial entries ``(due, index)``; the index also breaks ties in config order."""
    heap = [(t0 + p.interval_ns, i) for i, p in enumerate(pollers)]
    heapq.heapify(heap)
    return heap


def run_virtual(
    clock: Clock,
    pollers: Sequence[Poller],
    sink: Sink,
    *,
    t0: int,
    end: int,
    between: Callable[[int], None],
    should_stop: Callable[[], bool],
    pace: float | None = None,
) -> str:
    """Poll everything due, in time order, on a virtual clock until ``end`` (ns); return why it stopped early.

    ``between(t_ns)`` runs after every poll (flushes, rotation, status, workers),
    with the station time reached (ns since ``t0``). ``pace``: at most this many
    virtual seconds per wall second.
    """
    heap = _heap(pollers, t0)
    heappop, heappush = heapq.heappop, heapq.heappush
    wall0 = time.monotonic()
    while heap:
        due, i = heappop(heap)
        if due > end:
            break
        if should_stop():
            return "stopped by signal"
        if due > clock.now_ns():
            clock.advance_to(due)  # type: ignore[attr-defined]
        if pace is not None:
            ahead = (due - t0) / 1e9 / pace - (time.monotonic() - wall0)
            if ahead > 0:
                time.sleep(ahead)
        interval = pollers[i].poll(sink)
        heappush(heap, (due + interval, i))
        between(clock.now_ns() - t0)
    if clock.now_ns() < end:
        clock.advance_to(end)  # type: ignore[attr-defined]
    return ""


def run_threaded(
    clock: Clock,
    pollers: Sequence[Poller],
    sink: Sink,
    *,
    t0: int,
    end: int,
    between: Callable[[int], None],
    should_stop: Callable[[], bool],
) -> str:
    """Poll every bus in a reader thread of its own until ``end`` (ns); write into ``sink`` from this thread.

    ``between(t_ns)`` runs at every wake-up of this (writer) thread, at least
    every ``WRITER_WAKEUP_S``. Returns why it stopped early ("" at ``end``). An
    exception in a reader stops the capture and is raised here.
    """
    q: queue.SimpleQueue = queue.SimpleQueue()
    stop = threading.Event()
    groups: dict[str, list[Poller]] = {}
    for p in pollers:
        groups.setdefault(p.bus, []).append(p)
    threads = [
        threading.Thread(
            target=_reader, args=(clock, group, MessageSink(q.put), t0, end, stop), name=f"reader {bus}", daemon=True
        )
        for bus, group in groups.items()
    ]
    for th in threads:
        th.start()
    reason = ""
    try:
        while True:
            try:
                item = q.get(timeout=WRITER_WAKEUP_S)
            except queue.Empty:
                item = None
            while item is not None:
                deliver(sink, item)
                try:
                    item = q.get_nowait()
                except queue.Empty:
                    item = None
            now = clock.now_ns()
            between(now - t0)
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
            deliver(sink, q.get_nowait())
        except queue.Empty:
            break
    return reason


def _reader(clock: Clock, pollers: list[Poller], sink: MessageSink, t0: int, end: int, stop: threading.Event) -> None:
    """One bus: poll its devices and thermometers at their intervals until ``end`` or ``stop``."""
    try:
        heap = _heap(pollers, t0)
        while heap and not stop.is_set():
            due, i = heap[0]
            if due > end:
                return
            wait = (due - clock.now_ns()) / 1e9
            if wait > 0 and stop.wait(wait):
                return
            heapq.heappop(heap)
            interval = pollers[i].poll(sink)
            # a late poll is not made up for: the next one is one interval later
            heapq.heappush(heap, (max(due + interval, clock.now_ns()), i))
    except BaseException as exc:  # noqa: BLE001 - a bug in a reader must stop the capture, not vanish
        sink.error(exc)


def run_deadline(
    clock: Clock,
    pollers: Sequence[Poller],
    sink: Sink,
    *,
    t0: int,
    end: int,
    between: Callable[[int], None],
    should_stop: Callable[[], bool],
    sleep: Callable[[float], None] = time.sleep,
    spin_ns: int = 0,
    spin: Callable[[], None] = _busy,
    stats: DeadlineStats | None = None,
) -> str:
    """Poll one bus's devices in this thread on the host clock until ``end`` (ns); return why it stopped early.

    Each poller is polled at its own interval, or every ``hold_ns / POLLS_PER_HOLD`` if
    that is shorter; of those due, the one whose hold time runs out first is polled
    first. A poll late by more than its interval is not made up for: the next one is
    an interval after it; each poller's last poll is at ``end``. A poller with a ``phase``
    (a chip without a FIFO, :mod:`~imustation.acquisition.pollphase`) is polled just after
    each sample is made once its reads have shown when, within a hold of its last poll,
    instead of blind. ``between(t_ns)`` (the
    reader's hand-over to the writer) runs whenever nothing is due, and at least every
    ``BETWEEN_NS`` while polls are due.
    ``sleep(seconds)`` waits for the next due poll (tests pass a virtual clock's).

    Hybrid sleep: with ``spin_ns`` > 0, a poll of a device whose hold time is at most
    ``SPIN_HOLD_NS`` is slept for until ``spin_ns`` before it is due, and the rest waited
    for by reading the clock (``spin()`` between two reads; tests pass one that moves a
    virtual clock): a sleep that returns late by less than ``spin_ns`` then costs nothing.
    It costs CPU (``spin_ns`` per poll) and cannot help when the reader is not run at all.
    ``stats``: filled with how late the polls of the devices with the shortest hold started.
    """
    n = len(pollers)
    holds = [p.hold_ns for p in pollers if p.hold_ns > 0]
    shortest = min(holds) if holds else 0
    if stats is not None:
        stats.hold_ns = shortest
    spins = [spin_ns > 0 and 0 < p.hold_ns <= SPIN_HOLD_NS for p in pollers]
    step = [_step(p, p.interval_ns) for p in pollers]
    due = [t0 + s for s in step]
    deadline = [t0 + (p.hold_ns or s) for p, s in zip(pollers, step, strict=True)]
    last_between = t0
    while n:
        if should_stop():
            return "stopped by signal"
        now = clock.now_ns()
        ready = [i for i in range(n) if due[i] <= now]
        if not ready or now - last_between >= BETWEEN_NS:
            between(now - t0)
            last_between = now
        if not ready:
            nxt = min(due)
            if nxt > end:
                return ""
            wait_ns = nxt - clock.now_ns()
            spinning = spin_ns > 0 and any(spins[k] and due[k] == nxt for k in range(n))
            if spinning and wait_ns <= spin_ns:
                t_spin = clock.now_ns()
                while clock.now_ns() < nxt:
                    spin()
                if stats is not None:
                    stats.spun_ns += clock.now_ns() - t_spin
                continue
            if spinning:
                wait_ns -= spin_ns  # wake up before it; spin the rest
            if wait_ns > 0:
                sleep(min(wait_ns / 1e9, MAX_SLEEP_S))
            continue
        i = min(ready, key=lambda k: (deadline[k], k))
        if due[i] > end:
            return ""
        p = pollers[i]
        if stats is not None and p.hold_ns == shortest > 0:
            stats.add(now - due[i])
        interval = p.poll(sink)
        t = clock.now_ns()
        step[i] = _step(p, interval)
        nxt = due[i] + step[i]
        nxt = nxt if nxt > t else t + step[i]
        phased = p.phase.next_poll_ns(t) if p.phase is not None else None
        if phased is not None:
            nxt = min(phased, t + p.hold_ns)  # just after its next sample is made, within a hold
        # the last poll is at the end, wherever late polls moved the others: what was made until then is read
        due[i] = end if nxt > end > t else nxt
        deadline[i] = t + (p.hold_ns or step[i])
    return ""


def _step(p: Poller, interval_ns: int) -> int:
    """The interval to a poller's next poll: its own, or less to poll at least POLLS_PER_HOLD times a hold."""
    if p.hold_ns > 0:
        return max(1, min(interval_ns, p.hold_ns // POLLS_PER_HOLD))
    return max(1, interval_ns)
