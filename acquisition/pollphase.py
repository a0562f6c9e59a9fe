"""Poll a chip without a FIFO just after it makes each sample: an early/late gate on what its reads find.

A chip without a FIFO (the ADIS16448; the BMX055 accelerometer in data-ready mode)
holds each sample one output period ``T``: a sample is lost when no read takes it
within the period after it was made. Polled blind, twice a period at an arbitrary
phase, a read may come up to ``T/2`` after the sample it takes, so a poll held up by
more than about ``T/2`` (1.22 ms at 409.6 Hz) can cost a sample. Polled just after
each sample is made, a poll can be held up for most of a period (on a model chip
with 0.25 ms reads: stalls up to 2.0 ms, 0.82 ``T``, cost nothing;
``tests/test_poll_phase.py``), and the chip is read about 1.2 times a sample
instead of twice.

A read takes the chip's newest sample somewhere between its start and end: taken
as its middle (a latch earlier or later only shifts the polls until the reads that
find nothing correct them). A read that found a new sample says one was made before
its middle; one that found the sample before again says none was.
:class:`PollPhase` keeps an estimate of when the newest sample was made (``edge``)
and asks for the next read's middle ``MARGIN`` of a period after the next one is
due. A read that finds nothing new (too early: the chip's clock is slower than
estimated, or the estimate was early) bounds the edge from below and is retried
``RETRY`` of a period after it ends; with the read that found the sample before
(the next sample comes at most a period after it) the two bound the edge closely
even when a read is long (a USB bridge's millisecond). A read that finds a new
sample moves the estimate ``CREEP`` of a period earlier than one period on, so that
the polls keep probing the edge: about one read in six finds nothing, on purpose.
The chip's clock is its own (the ADIS16448's internal sample clock is not the
host's): the period is measured between two brackets ``PERIOD_BASELINE`` samples or
more apart, and the creep doubles every ``ESCALATE`` reads in a row that all found a
sample (a chip faster than estimated is never caught early), so a chip off its
configured rate (within ``PERIOD_RANGE``) is followed too.

Until a read has bracketed an edge (a read that found nothing, then one that found
a sample, less than a period apart) there is no estimate, and the device is polled
blind as before (:func:`~imustation.acquisition.scheduler.run_deadline`). A read
held up for several periods finds the newest sample: the estimate jumps to it. Reads
that find nothing for ``LOST_AFTER`` periods (a chip that stopped) give the phase up.
"""

from __future__ import annotations

#: the next read's middle this fraction of a period after the estimated instant the next sample is made
MARGIN = 0.10
#: a read that found nothing new: read again this fraction of a period later
RETRY = 0.05
#: each read that found a new sample moves the estimate this fraction of a period early (probing the edge;
#: follows a chip this much faster than the period measured so far)
CREEP = 0.03
#: ... doubled after this many reads in a row that all found a sample
ESCALATE = 4
#: the period is measured between two brackets at least this many samples apart ...
PERIOD_BASELINE = 16
#: ... moving the estimate this fraction of the way to what they show ...
PERIOD_GAIN = 0.5
#: ... within this fraction of the configured period
PERIOD_RANGE = 0.1
#: reads that find nothing for this many periods after the estimated newest sample: the phase is lost
LOST_AFTER = 3


class PollPhase:
    """When to poll a chip without a FIFO next, learnt from which of its reads found a new sample.

    Parameters
    ----------
    period_ns : the chip's configured output period, ns.
    """

    def __init__(self, period_ns: int):
        self.configured_ns = int(period_ns)
        self.reset()

    def reset(self) -> None:
        """Forget the phase (the chip was re-opened, a read failed): poll blind until it is learnt again."""
        #: the chip's output period as its reads show it, ns (the configured one until measured)
        self.period_ns = float(self.configured_ns)
        #: estimated instant the newest sample was made, ns (None: not known)
        self.edge: int | None = None
        #: middle and end of the latest read that found nothing new, ns (its middle bounds the next sample)
        self._nothing: tuple[int, int] | None = None
        #: how long the latest read took, ns
        self._read_ns = 0
        #: middle of the latest read that found a new sample, ns (the sample after it is made at most a
        #: period later)
        self._found: int | None = None
        #: the edge of an earlier bracket and the samples found since (None: a read held up for periods
        #: came between, so the count is not exact), from which the period is measured
        self._anchor: int | None = None
        self._since: int | None = 0
        #: reads in a row that found a new sample
        self._found_run = 0
        #: reads that found nothing new since the phase was learnt (a health figure)
        self.early = 0

    @property
    def creep(self) -> float:
        """How early each found sample moves the estimate, in periods: ``CREEP``, doubled for every
        ``ESCALATE`` reads in a row that all found a sample (a chip faster than the period measured so far
        is never caught early, so the polls must look for its edge), at most ``MARGIN``."""
        return min(CREEP * 2 ** min(self._found_run // ESCALATE, 3), MARGIN)

    def observe(self, start_ns: int, end_ns: int, new: bool | None) -> None:
        """One read from ``start_ns`` to ``end_ns`` (ns, the station's clock); ``new``: it found a sample the
        read before had not (None: the driver cannot say - a failed or rejected transfer)."""
        p = self.period_ns
        if new is None:
            self.reset()
            return
        # a read takes the chip's sample somewhere between its start and end: taken as its middle (a latch
        # later or earlier only moves the polls until the reads that find nothing correct them)
        latch, self._read_ns = (start_ns + end_ns) // 2, end_ns - start_ns
        if not new:
            if self.edge is not None and latch - self.edge > LOST_AFTER * p:
                # no sample for periods (a chip that stopped, or a clock far off): the phase is gone, and
                # retrying every RETRY of a period would only spin; poll blind until it is found again
                self.reset()
                return
            # nothing was made before this read took its sample: the next sample comes after that
            self._nothing = (latch, end_ns)
            self._found_run = 0
            if self.edge is not None:
                self.early += 1
            return
        nothing, self._nothing = self._nothing, None
        found, self._found = self._found, latch
        if nothing is not None and latch - nothing[0] < p:
            # made after the read that found nothing and before this one took its sample, and at most a
            # period after the read that found the sample before (a long read leaves the first bracket
            # wide); of that bracket the earliest instant from which the next read (MARGIN after it) is
            # still after the next sample
            latest = latch if found is None or found >= nothing[0] else min(latch, int(found + p))
            self.edge = max(nothing[0], latest - int(MARGIN * p))
            self._bracketed()
        elif self.edge is not None:
            # one period on, a little early (probing), and never after this read took its sample (it found
            # one); a read held up for periods found the newest: the estimate jumps to it
            self._found_run += 1
            edge = self.edge + p - self.creep * p
            if latch - edge >= p:
                edge += (latch - edge) // p * p
                self._since = None
            elif self._since is not None:
                self._since += 1
            self.edge = int(min(edge, latch))
        # else: nothing learnt yet (no read found nothing less than a period before this one)

    def _bracketed(self) -> None:
        """A tight bracket: measure the period from the one ``PERIOD_BASELINE`` samples or more before."""
        assert self.edge is not None
        since = self._since + 1 if self._since is not None else None
        if self._anchor is not None and since is not None and since < PERIOD_BASELINE:
            self._since = since
            return
        if self._anchor is not None and since is not None:
            measured = (self.edge - self._anchor) / since
            low, high = (1 - PERIOD_RANGE) * self.configured_ns, (1 + PERIOD_RANGE) * self.configured_ns
            self.period_ns = min(max(self.period_ns + PERIOD_GAIN * (measured - self.period_ns), low), high)
        self._anchor, self._since = self.edge, 0

    def next_poll_ns(self, now_ns: int) -> int | None:
        """When to read the chip next (ns), or None while the phase is not known (poll blind)."""
        if self.edge is None:
            return None
        p = self.period_ns
        if self._nothing is not None:
            return max(now_ns, self._nothing[1] + int(RETRY * p))
        # the read's middle MARGIN after the next sample; a poll held up past it: at once (the newest)
        return max(self.edge + int((1 + MARGIN) * p) - self._read_ns // 2, now_ns)
