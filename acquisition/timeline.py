"""One device's sample timeline: when each sample was taken, and which samples were lost.

A driver hands the station blocks of samples (:class:`~imustation.drivers.base.Block`)
without times: the station knows when it read them, the device's output period,
and what the driver says was lost. :class:`Timeline` places every sample on the
device's sample grid (samples written and samples lost both count), dates it and
logs every hole, so that for every device *samples written + logged losses =
samples produced*, and the file alone shows it (docs/capture.md, "Samples lost";
:mod:`imustation.runfile.holes` checks it):

* losses are counted by the device's sample counter (a jump between consecutive
  samples, a wrap is no jump), by the chip (``Block.lost`` > 0), or from time
  (``Block.lost`` < 0, after a fault, a counter that went back, a stall): the
  samples the period fits since those already accounted for, less those read. A
  loss is counted once: a read without samples that reports a loss moves the
  accounted time on by the samples it counted.
* devices that lose samples without a word (``DriverInfo.overflow``) are checked
  from the read times whenever they went unread for longer than they hold
  samples (``DriverInfo.buffer_s``). A chip without a FIFO ("newest", the
  ADIS16448) loses what it made before the sample a late read returns: as many as
  it made between the two reads, less one, counted on its sampling phase
  (:class:`SamplingPhase`, learnt from which reads found a new sample). A tty
  ("oldest", the DSP-3000) keeps the oldest bytes and drops the rest: the hole
  follows the samples that read returns.
* times: consecutive samples are one output period apart and a hole of ``L``
  samples is ``L`` periods more, so the timestamps show every hole. The newest
  sample of a block is dated at the read (less ``Block.behind_ns`` where the
  driver knows when it was made; a chip without a FIFO: each sample at its own
  read, ``Block.read_ns``). Where the reads and the grid disagree (a late read, a
  device off its configured rate) the steps between contiguous samples give way,
  within ``SLEW`` of a period: a contiguous step is 0.6-1.4 periods, a hole of
  ``L`` samples ``L`` periods more, so a step never looks like a hole or a repeat.
* every loss is one event, dated at the nominal time of the first sample it says
  is missing: strictly between the two samples around its hole.
* a device that answers every poll but delivers no samples for ``SILENCE_S``
  (a FIFO that never fills or never drains, every read an overrun) is reported
  once, as a fault, and is ``stalled``: its empty reads count nothing more; when
  samples come back, what it lost meanwhile is measured from time, once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from imustation.channels import OVERFLOW_KINDS
from imustation.drivers.base import Block

#: station seconds without a sample after which a device that still answers is reported stalled
SILENCE_S = 10.0
#: a step between contiguous samples stays within (1 +- SLEW) periods: a hole is >= 1.6, a repeat <= 0.4
SLEW = 0.4
#: reads less than this many periods apart tell the sampling phase something
_INFORMATIVE = 0.99
#: largest denominator of a period in ns (1e9 / 409.6 Hz = 9765625/4 ns): sample times are exact
_PERIOD_DENOMINATOR = 1 << 16


@dataclass(frozen=True)
class TimelineEvent:
    """What the station logs for the device: at ``t_ns`` (station time), ``kind``, ``detail``, samples ``lost``."""

    t_ns: int
    kind: str
    detail: str
    lost: int = 0


@dataclass(frozen=True)
class Placed:
    """A block placed on the timeline: its samples' times (ns; None when it holds none) and its events."""

    t_ns: np.ndarray | None
    events: tuple[TimelineEvent, ...] = ()


#: what a read without samples and without news places
_NOTHING = Placed(None)
_COUNTS: dict[int, np.ndarray] = {}


def _counts(k: int) -> np.ndarray:
    """1 .. k as floats (one array per block length, reused)."""
    counts = _COUNTS.get(k)
    if counts is None:
        counts = np.arange(1, k + 1, dtype=np.float64)
        if len(_COUNTS) < 512:
            _COUNTS[k] = counts
    return counts


def _kind(note: str) -> str:
    low = note.lower()
    return "overrun" if "overrun" in low else "resync" if "resync" in low else "gap"


class SamplingPhase:
    """When a device without a FIFO makes its samples, as far as its reads tell: the offsets (ns, modulo
    one output period) its sample grid can have, one arc ``[lo, lo + width)``.

    A read that found a new sample says one was made since the read before; one that found the same
    sample again says none was. Each narrows the arc when the reads are less than a period apart; an
    observation the arc cannot hold (the device's clock drifted, a read was dated late) replaces it.
    Knowing the arc, the samples made between two reads are counted exactly unless a read falls in it.

    Parameters
    ----------
    period_ns : the output period, ns.
    """

    def __init__(self, period_ns: float):
        self.period_ns = float(period_ns)
        self.reset()

    def reset(self) -> None:
        """Forget what the reads told (the device was re-opened: its sampling restarted)."""
        self.lo, self.width = 0.0, self.period_ns

    def made_in(self, a: float, b: float) -> None:
        """A sample was made in ``(a, b]`` (ns)."""
        if b - a < _INFORMATIVE * self.period_ns:
            self._meet(a, b - a)

    def none_in(self, a: float, b: float) -> None:
        """No sample was made in ``(a, b]`` (ns)."""
        if b - a >= self.period_ns:
            self.reset()  # impossible at the configured rate: start again
        elif b > a:
            self._meet(b, self.period_ns - (b - a))

    def _meet(self, start: float, length: float) -> None:
        """Keep the part of the arc inside ``[start, start + length)`` modulo the period (the larger part if it
        splits in two); nothing left: the new observation replaces the arc."""
        p = self.period_ns
        c = (start - self.lo) % p
        pieces = [(c, min(c + length, p))] + ([(0.0, c + length - p)] if c + length > p else [])
        a, b = max(((a, min(b, self.width)) for a, b in pieces), key=lambda ab: ab[1] - ab[0])
        if b > a:
            self.lo, self.width = (self.lo + a) % p, b - a
        else:
            self.lo, self.width = start % p, length

    def count(self, a: float, b: float) -> int:
        """Samples made in ``(a, b]`` (ns): exact when neither time falls in the arc, else the count that holds
        over the larger part of it (nothing learnt yet: the period's whole count nearest to ``b - a``)."""
        p = self.period_ns

        def made(phase: float) -> int:
            return math.floor((b - phase) / p) - math.floor((a - phase) / p)

        # the count changes where the grid passes a or b: cut the arc there, weigh each piece by its length
        cuts = sorted(x for x in ((a - self.lo) % p, (b - self.lo) % p) if 0.0 < x < self.width)
        edges = [0.0, *cuts, self.width]
        weight: dict[int, float] = {}
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            n = made(self.lo + (lo + hi) / 2)
            weight[n] = weight.get(n, 0.0) + hi - lo
        return max(weight, key=lambda n: weight[n])


class Timeline:
    """Sample times and loss accounting of one device.

    Parameters
    ----------
    period_ns : the device's output period, ns (1e9 / the configured rate).
    counter_modulus : the value at which the device's sample counter wraps
        (e.g. 65536 for a u16 counter), or None/0 when it does not.
    silence_s : station seconds without samples after which the device is stalled.
    overflow, buffer_s : how the device loses samples it is not read in time for
        (``DriverInfo.overflow``, one of :data:`~imustation.channels.OVERFLOW_KINDS`) and
        for how long it holds them, s.
    """

    def __init__(
        self,
        period_ns: float,
        counter_modulus: int | None = None,
        silence_s: float = SILENCE_S,
        *,
        overflow: str = "reported",
        buffer_s: float = float("inf"),
    ):
        if overflow not in OVERFLOW_KINDS:
            raise ValueError(f"overflow = {overflow!r}: one of {', '.join(OVERFLOW_KINDS)}")
        self.period = Fraction(period_ns).limit_denominator(_PERIOD_DENOMINATOR)
        self.period_ns = float(self.period)
        self.counter_modulus = int(counter_modulus) if counter_modulus else 0
        self.overflow = overflow
        self.buffer_ns = buffer_s * 1e9
        #: samples placed, samples lost, loss events
        self.samples = 0
        self.lost = 0
        self.gaps = 0
        #: time of the newest sample placed, ns (None before the first)
        self.last_t_ns: int | None = None
        #: the device's counter at that sample (None: no counter, or it restarted)
        self.last_counter: int | None = None
        #: the read of the newest sample placed (start, end; ns): what every later loss is measured from.
        #: A read without samples that counted a loss moves it on by the samples it counted.
        self._accounted = (0, 0)
        #: samples counted lost after the newest placed one (reads that found a loss and no samples)
        self._pending = 0
        #: the last read and the one before it (start, end; ns); the start, which emptied the device, is one
        self._read = self._read_before = (0, 0)
        #: a device without a FIFO: its sampling phase, learnt from its reads
        self.phase = SamplingPhase(self.period_ns) if overflow == "newest" else None
        self.silence_ns = int(round(silence_s * 1e9))
        #: no samples for ``silence_s`` although the device answers (reported once per stall)
        self.stalled = False
        self.stalls = 0
        #: station time of the last read that delivered samples (or of the start, a re-open), ns
        self._data_ns = 0
        #: reads that reported a loss without samples since then
        self._empty_losses = 0
        #: the device was re-opened: the next samples' loss is measured from time
        self._resync = False

    def restart(self, t_ns: int) -> None:
        """The device was re-opened after a fault at ``t_ns`` (ns): what it lost meanwhile is measured at its
        next samples; a stall it was in ends (a new one is reported after another ``silence_s``)."""
        self._resync = True
        self.stalled = False
        self._data_ns = t_ns
        self._empty_losses = 0
        if self.phase is not None:
            self.phase.reset()  # re-configured: its sampling started again

    # -- the sample grid -----------------------------------------------------------------
    def _grid(self, periods: np.ndarray | int) -> np.ndarray | int:
        """``periods`` output periods in ns, rounded to the ns (exact integer arithmetic)."""
        num, den = self.period.numerator, self.period.denominator
        return (periods * (2 * num) + den) // (2 * den)

    def _missing_at(self, before: int) -> int:
        """Time of the first of the samples lost after the newest placed one, ``before`` lost ones already counted."""
        base = self.last_t_ns if self.last_t_ns is not None else -int(self._grid(1))
        return int(base + self._grid(1 + before))

    # -- placing a block -----------------------------------------------------------------
    def place(self, block: Block, t_read: int, *, poll: bool = True, started: int | None = None) -> Placed:
        """Date ``block``'s samples and account its losses; ``t_read``: the end of the read, ns of station time.

        ``started``: when the read started (ns; default ``t_read``): the device was read
        between the two. ``poll``: the block comes from a read of the device (False: the
        samples a driver still held when the capture ended; ``Block.read_ns`` dates them).
        ``Block.read_ns`` / ``previous_read_ns``, if given, are station times too.
        """
        if poll:
            self._read_before = self._read
            self._read = (started if started is not None and started < t_read else t_read, t_read)
        k = block.n
        lost, note = block.lost, block.note
        if k == 0:
            if not lost and (self.stalled or t_read - self._data_ns < self.silence_ns):
                return _NOTHING  # most reads of a driver that holds its samples
            return self._empty(block, t_read)
        if self.stalled:
            self.stalled = False
            again = f"samples again after {(t_read - self._data_ns) / 1e9:.1f} s without any"
            lost, note = -1, f"{again}; {note}" if note else again
        if self._resync and not lost:
            lost, note = -1, "samples lost while the device was failing"
            self.last_counter = None  # the device restarted its counter
        self._resync = False
        reads = self._reads(block, t_read)
        newest = int(reads[1][-1]) if reads is not None else t_read - int(block.behind_ns or 0)
        events: list[tuple[int, str, str]] = []  # (sample, kind, detail) of each new loss
        read_gap = t_read - self._read_before[1] if poll else 0
        gaps, trailing, anchored = self._losses(block, reads, newest, lost, note, events, read_gap)
        if not anchored:
            t = self._date(gaps, None, None)
        else:
            t = self._date(gaps, newest - int(self._grid(trailing)), reads[1] if reads is not None else None)
        placed = []
        for j, kind, detail in events:
            n = int(gaps[j]) - 1 - (self._pending if j == 0 else 0)
            at = int(t[j] - self._grid(n))  # the first of the samples it says are missing
            placed.append(TimelineEvent(at if self.last_t_ns is not None or at >= 0 else 0, kind, detail, n))
            self.lost += n
            self.gaps += 1
        self.samples += k
        self.last_t_ns = int(t[-1])
        self._pending = 0
        if trailing:
            detail = (
                f"not read for {read_gap / 1e9:.2f} s, longer than its input buffer holds "
                f"({self.buffer_ns / 1e9:.2f} s): the samples after those read were dropped"
            )
            placed.append(TimelineEvent(self._missing_at(0), "gap", detail, trailing))
            self._pending, self.lost, self.gaps = trailing, self.lost + trailing, self.gaps + 1
        self._accounted = (int(reads[0][-1]), newest) if reads is not None else (newest, newest)
        self._data_ns, self._empty_losses = t_read, 0
        if block.counter is not None:
            self.last_counter = int(block.counter[-1])
        return Placed(t, tuple(placed))

    def _empty(self, block: Block, t_read: int) -> Placed:
        """A read without samples: a stall, or a loss counted now (its samples are gone)."""
        if self.stalled:
            return Placed(None)  # counted when samples return
        lost = block.lost
        self._empty_losses += bool(lost)
        silent_ns = t_read - self._data_ns
        if silent_ns >= self.silence_ns:
            self.stalled = True
            self.stalls += 1
            losses = f", {self._empty_losses} of its reads reporting lost samples" if self._empty_losses else ""
            detail = (
                f"no samples for {silent_ns / 1e9:.1f} s although the device answers{losses}: stalled; "
                "what it loses is counted when samples return"
            )
            return Placed(None, (TimelineEvent(t_read, "fault", detail),))
        if not lost:
            return Placed(None)  # a re-opened device's loss is measured at its first samples
        self._resync = False
        if lost < 0:
            # the chip cannot count them: the samples the period fits since those accounted for
            made = t_read - int(block.behind_ns or 0) - self._accounted[1]
            lost = max(0, int(round(made / self.period_ns)))
        end = self._accounted[1] + int(self._grid(lost))
        self._accounted = (end, end)
        event = TimelineEvent(self._missing_at(self._pending), _kind(block.note), block.note or "samples lost", lost)
        self._pending += lost
        self.lost += lost
        self.gaps += 1
        return Placed(None, (event,))

    def _reads(self, block: Block, t_read: int) -> tuple[np.ndarray, ...] | None:
        """For a chip without a FIFO, when each sample was read and when the chip was read before that:
        (start, end, start before, end before), ns. The driver's own stamps (``Block.read_ns``, one instant
        each), or, for a single sample, this read and the one before. None for a FIFO's block."""
        if block.read_ns is not None:
            read = np.asarray(block.read_ns, dtype=np.int64)
            before = np.asarray(block.previous_read_ns, dtype=np.int64)
            return read, read, before, before
        if self.overflow != "newest" or block.n != 1:
            return None
        (start, end), (start_before, end_before) = self._read, self._read_before
        return tuple(np.array([v], dtype=np.int64) for v in (start, end, start_before, end_before))

    def _losses(
        self,
        block: Block,
        reads: tuple[np.ndarray, ...] | None,
        newest: int,
        lost: int,
        note: str,
        events: list[tuple[int, str, str]],
        read_gap: int,
    ) -> tuple[np.ndarray, int, bool]:
        """Periods from the sample before to each sample of the block (1 + samples lost between them; the first
        also counts the losses logged since the newest placed one), the samples lost after the block (a
        buffer that kept the oldest), and whether the block's newest sample is the newest at the read (not
        when a full buffer kept the oldest); appends ``(sample, kind, detail)`` for each new loss."""
        k = block.n
        counter = block.counter
        if counter is not None and self.last_counter is not None and lost >= 0:
            c = np.concatenate(([self.last_counter], np.asarray(counter, dtype=np.int64)))
            steps = np.diff(c)
            if self.counter_modulus:
                steps %= self.counter_modulus
            if not (steps <= 0).any():
                # the counter also counts what reads without samples logged since the last sample
                steps[0] = max(int(steps[0]), 1 + self._pending)
                counted = steps - 1 - np.where(np.arange(k) == 0, self._pending, 0)
                for j in np.flatnonzero(counted > 0):
                    jump = f"counter jump {c[j]}->{c[j + 1]}"
                    events.append((int(j), "gap", f"{jump}; {note}" if note and not events else jump))
                # a full buffer kept the oldest samples: the counter placed them; the read dates nothing
                return steps, 0, not (self.overflow == "oldest" and read_gap > self.buffer_ns)
            lost, note = -1, "device counter went back (device restarted?): resync"
        gaps = np.ones(k, dtype=np.int64)
        trailing = 0
        if reads is not None:
            self._losses_unbuffered(reads, lost, note, gaps, events)
        else:
            missing = max(0, int(round((newest - self._accounted[1]) / self.period_ns)) - k)
            if self.overflow == "oldest" and read_gap > self.buffer_ns:
                trailing = missing  # the buffer kept the oldest samples: the hole follows them
            elif lost < 0 or (lost > 0 and self.overflow != "reported"):
                gaps[0] = 1 + missing  # measured from time (the device's own count may be a lower bound)
            elif lost > 0:
                gaps[0] = 1 + lost
            if lost and not trailing:
                events.append((0, _kind(note), note or "samples lost"))
        gaps[0] += self._pending
        return gaps, trailing, True

    def _losses_unbuffered(
        self, reads: tuple[np.ndarray, ...], lost: int, note: str, gaps: np.ndarray, events: list
    ) -> None:
        """A chip without a FIFO: each sample is the newest at its read; what it made before, since the read of
        the sample before, and did not hand over is lost. Fills ``gaps`` and ``events``."""
        phase = self.phase if self.phase is not None else SamplingPhase(self.period_ns)
        start, end, start_before, end_before = reads
        waited = end - start_before
        if (
            not lost
            and waited.min() >= _INFORMATIVE * self.period_ns
            and waited.max() <= self.buffer_ns
            and start_before[0] <= self._accounted[1]
            and (len(end) == 1 or (start_before[1:] <= end[:-1]).all())
        ):
            return  # every read about a period after the one before, each a new sample: nothing to tell
        found = waited < _INFORMATIVE * self.period_ns
        late = waited > self.buffer_ns
        # the read of the sample before each (the first: the newest placed one)
        sample_start = np.concatenate(([self._accounted[0]], start[:-1]))
        sample_end = np.concatenate(([self._accounted[1]], end[:-1]))
        # reads since the sample before found nothing new until the one before this one; that one found it
        nothing_new = start_before > sample_end
        # in order, only the samples whose reads tell something or that need counting
        for j in np.flatnonzero(nothing_new | found | late | (np.arange(len(end)) == 0)).tolist():
            if j == 0 and lost:
                # a loss the device reported, or cannot count (a re-opened device): since the sample before
                made = self._made_between(phase, sample_start[0], sample_end[0], start[0], end[0])
                gaps[0] = max(made, 1 + max(lost, 0))
                events.append((0, _kind(note), note or "samples lost"))
                continue
            if nothing_new[j]:
                phase.none_in(float(sample_end[j]), float(start_before[j]))
            if found[j]:
                phase.made_in(float(start_before[j]), float(end[j]))
            if late[j]:
                made = self._made_between(phase, start_before[j], end_before[j], start[j], end[j])
                if made > 1:
                    gaps[j] = made
                    detail = (
                        f"not read for {(end[j] - start_before[j]) / 1e6:.1f} ms, longer than the device holds a "
                        f"sample ({self.buffer_ns / 1e6:.1f} ms): samples made meanwhile were lost"
                    )
                    events.append((j, "gap", detail))

    @staticmethod
    def _made_between(phase: SamplingPhase, start_a: float, end_a: float, start_b: float, end_b: float) -> int:
        """Samples made between two reads, each somewhere in its ``[start, end]`` (ns): at the reads' middles on
        the sampling phase, within what their ends allow; at least one (the second read found a new one)."""
        surely = phase.count(float(end_a), float(start_b)) if start_b > end_a else 0
        at_most = phase.count(float(start_a), float(end_b))
        middle = phase.count((start_a + end_a) / 2, (start_b + end_b) / 2)
        return max(1, min(max(middle, surely), at_most))

    def _date(self, gaps: np.ndarray, newest: int | None, reads: np.ndarray | None) -> np.ndarray:
        """Times of samples ``gaps`` periods apart (the first from the newest placed one).

        Each run of contiguous samples ends at its target - the read of its last sample
        (``reads``), or ``newest`` for the last run - as far as its steps may give way
        (``SLEW``); a run without a target continues the grid exactly.
        """
        k = len(gaps)
        offsets = np.cumsum(gaps)
        if self.last_t_ns is None:
            end = newest if newest is not None else int(reads[-1]) if reads is not None else 0
            return end - self._grid(offsets[-1] - offsets)
        low, high = (1 - SLEW) * self.period_ns, (1 + SLEW) * self.period_ns
        if offsets[-1] == k and newest is not None:  # one run, no hole: the usual block
            step = min(max((newest - self.last_t_ns) / k, low), high)
            return self.last_t_ns + (_counts(k) * step).round().astype(np.int64)
        t = np.empty(k, dtype=np.int64)
        prev_t, prev_off = self.last_t_ns, 0
        bounds = [0, *(np.flatnonzero(gaps[1:] > 1) + 1).tolist(), k]
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            base = prev_t + int(self._grid(int(offsets[a] - prev_off) - 1))  # past the hole before the run
            target = int(reads[b - 1]) if reads is not None else newest if b == k else None
            if target is None:
                t[a:b] = base + self._grid(offsets[a:b] - offsets[a] + 1)
            else:
                step = min(max((target - base) / (b - a), low), high)
                t[a:b] = base + (np.arange(1, b - a + 1) * step).round().astype(np.int64)
            prev_t, prev_off = int(t[b - 1]), int(offsets[b - 1])
        return t
