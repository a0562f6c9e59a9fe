"""One device's sample timeline: when each sample was taken, and which samples were lost.

A driver hands the station blocks of samples (:class:`~imustation.drivers.base.Block`)
without times: the station knows when it read them, the device's output period,
and what the driver says was lost. :class:`Timeline` turns that into sample times
(ns of station time) and loss events, so that for every device
*samples written + logged losses = samples produced* (docs/capture.md, "Faults
during a run"):

* times: the newest sample of a block is dated at the read (less the periods a
  driver held it, ``Block.age``), the others one output period apart before it;
  a block holding more samples than the time since the previous one fits (the
  host read late the time before) is spread evenly over that time, so times
  stay strictly increasing.
* losses: counted by the chip (``Block.lost`` > 0), by the device's sample
  counter (jumps between consecutive samples, a wrap is no jump), or measured
  from time (``Block.lost`` < 0, after a fault, a counter that went back): the
  samples the period fits since the samples already accounted for, less those
  in the block. A loss is counted once: a block without samples that reports a
  loss moves the accounted time on by the samples it counted, so the next one
  counts from there, not again from the last sample read.
* a device that answers every poll but delivers no samples for ``SILENCE_S``
  (a FIFO that never fills or never drains, every read an overrun) is reported
  once, as a fault, and is ``stalled``: its empty reads count nothing more; when
  samples come back, what it lost meanwhile is measured from time, once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imustation.drivers.base import Block

#: distinct block lengths whose sample-time offsets a timeline keeps
_MAX_CACHED_OFFSETS = 512
#: number of first counter jumps of a block quoted in the event text
_QUOTED_JUMPS = 3
#: station seconds without a sample after which a device that still answers is reported stalled
SILENCE_S = 10.0


@dataclass(frozen=True)
class TimelineEvent:
    """A loss the station logs for the device: event ``kind``, ``detail`` text, samples ``lost``."""

    kind: str
    detail: str
    lost: int = 0


@dataclass(frozen=True)
class Placed:
    """A block placed on the timeline: its samples' times (ns; None when it holds none) and its loss event."""

    t_ns: np.ndarray | None
    event: TimelineEvent | None


class Timeline:
    """Sample times and loss accounting of one device.

    Parameters
    ----------
    period_ns : the device's output period, ns.
    counter_modulus : the value at which the device's sample counter wraps
        (e.g. 65536 for a u16 counter), or None/0 when it does not.
    silence_s : station seconds without samples after which the device is stalled.
    """

    def __init__(self, period_ns: float, counter_modulus: int | None = None, silence_s: float = SILENCE_S):
        self.period_ns = float(period_ns)
        self.counter_modulus = int(counter_modulus) if counter_modulus else 0
        #: samples placed, samples lost, loss events
        self.samples = 0
        self.lost = 0
        self.gaps = 0
        #: time of the newest sample placed, ns (None before the first)
        self.last_t_ns: int | None = None
        #: the device's counter at that sample (None: no counter, or it restarted)
        self.last_counter: int | None = None
        #: station time up to which every sample is placed or counted lost, ns
        self._accounted_ns = 0
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
        #: block length -> time offsets of its samples before the newest, ns (reused every read)
        self._offsets: dict[int, np.ndarray] = {}

    def restart(self, t_ns: int) -> None:
        """The device was re-opened after a fault at ``t_ns`` (ns): what it lost meanwhile is measured at its
        next samples; a stall it was in ends (a new one is reported after another ``silence_s``)."""
        self._resync = True
        self.stalled = False
        self._data_ns = t_ns
        self._empty_losses = 0

    def place(self, block: Block, t_read: int) -> Placed:
        """Date ``block``'s samples (newest at ``t_read``, ns of station time, less its age) and account its loss."""
        k = block.n
        lost, note = block.lost, block.note
        if k == 0:
            if self.stalled:
                return Placed(None, None)  # counted when samples return
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
                return Placed(None, TimelineEvent("fault", detail))
        elif self.stalled:
            self.stalled = False
            again = f"samples again after {(t_read - self._data_ns) / 1e9:.1f} s without any"
            lost, note = -1, f"{again}; {note}" if note else again
        if self._resync and not lost:
            if k == 0:
                return Placed(None, None)  # measure the loss at the first samples (a driver may be holding them)
            lost, note = -1, "samples lost while the device was failing"
            self.last_counter = None  # the device restarted its counter
        self._resync = False
        # the newest sample's time: the read, less the periods it was held
        t_new = t_read - int(round(block.age * self.period_ns))
        counter = block.counter
        event = None
        if counter is not None and k and not lost:
            back, event = self._check_counter(counter)
            if back:
                lost, note = -1, "device counter went back (device restarted?): resync"
        if lost:
            if lost < 0:
                # the chip cannot count them: samples expected since those accounted for, minus those read
                lost = max(0, int(round((t_new - self._accounted_ns) / self.period_ns)) - k)
            if k == 0:
                self._accounted_ns += int(round(lost * self.period_ns))
            self.lost += lost
            self.gaps += 1
            low = note.lower()
            kind = "overrun" if "overrun" in low else "resync" if "resync" in low else "gap"
            event = TimelineEvent(kind, note or "samples lost", lost)
        if k == 0:
            return Placed(None, event)
        self.samples += k
        t = self._times(k, t_new)
        self.last_t_ns = self._accounted_ns = t_new
        self._data_ns, self._empty_losses = t_read, 0
        if counter is not None:
            self.last_counter = int(counter[-1])
        return Placed(t, event)

    def _times(self, k: int, t_new: int) -> np.ndarray:
        """Times of ``k`` samples, the newest at ``t_new``, spaced by the period (or spread, see the module)."""
        offsets = self._offsets.get(k)
        if offsets is None:
            offsets = (np.arange(k - 1, -1, -1, dtype=np.float64) * self.period_ns).round().astype(np.int64)
            if len(self._offsets) < _MAX_CACHED_OFFSETS:
                self._offsets[k] = offsets
        t = t_new - offsets
        last = self.last_t_ns
        if last is not None and t[0] <= last:
            # the host read late last time (or early now): the block holds more samples than
            # the ODR fits in the time since the last read; spread them evenly over that time
            # so sample times stay strictly increasing and still end at this read
            t = last + ((t_new - last) * np.arange(1, k + 1, dtype=np.float64) / k).astype(np.int64)
        return t

    def _check_counter(self, counter: np.ndarray) -> tuple[bool, TimelineEvent | None]:
        """Counter jumps within a block and since the last one: the samples they skipped.

        The counter counts output samples. Returns (the counter went back - the
        device restarted, so the caller measures the block's loss from time
        instead; the gap event of the jumps, or None).
        """
        c = np.asarray(counter, dtype=np.int64)
        if self.last_counter is not None:
            c = np.concatenate(([self.last_counter], c))
        if len(c) < 2:
            return False, None
        steps = np.diff(c)
        if self.counter_modulus:
            steps %= self.counter_modulus
        bad = np.flatnonzero(steps != 1)
        if not len(bad):
            return False, None
        if (steps[bad] <= 0).any():
            return True, None
        lost = int(np.sum(steps[bad] - 1))
        where = ", ".join(f"{c[i]}->{c[i + 1]}" for i in bad[:_QUOTED_JUMPS])
        self.lost += lost
        self.gaps += 1
        return False, TimelineEvent("gap", f"counter jump {where}", lost)
