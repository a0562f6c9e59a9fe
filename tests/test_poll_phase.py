"""Polling a chip without a FIFO just after it makes each sample (acquisition/pollphase.py), on a virtual clock.

A model chip makes a sample every period at a phase of its own and keeps only the
newest; a read takes a while and latches the chip's newest sample half-way through.
The reader's sleeps are held up by injected stalls (a loaded host), so what is lost
depends only on the stalls drawn, never on this machine's speed.
"""

from __future__ import annotations

import numpy as np
import pytest

from imustation.acquisition.pollphase import MARGIN, RETRY, PollPhase
from imustation.acquisition.scheduler import Poller, run_deadline
from imustation.acquisition.sinks import MessageSink
from imustation.acquisition.timeline import Timeline
from imustation.clock import VirtualClock
from imustation.drivers import adis16448 as adis
from tests.test_data_ready import rig

PERIOD = 2_441_406  # ns: the ADIS16448 at 409.6 Hz


class Chip:
    """Samples made at ``phase + k * period`` (ns); a read takes the newest ``latch`` of the way through it."""

    def __init__(self, clock: VirtualClock, period_ns: float, phase_ns: float, read_ns: int = 250_000, latch=0.5):
        self.clock, self.period, self.phase, self.read_ns, self.latch = clock, period_ns, phase_ns, read_ns, latch
        self.last = -1  # index of the newest sample handed over
        self.read, self.lost, self.polls, self.empty = 0, 0, 0, 0

    def newest(self, t_ns: float) -> int:
        return int(np.floor((t_ns - self.phase) / self.period))

    def poll(self, sink, tracker: PollPhase | None) -> int:
        start = self.clock.now_ns()
        k = self.newest(start + self.latch * self.read_ns)
        self.clock.advance_to(start + self.read_ns)
        self.polls += 1
        new = k > self.last
        if new:
            if self.last >= 0:
                self.lost += k - self.last - 1
            self.last = k
            self.read += 1
        else:
            self.empty += 1
        if tracker is not None:
            tracker.observe(start, self.clock.now_ns(), new)
        return int(self.period)


def _stalling_sleep(clock: VirtualClock, rng: np.random.Generator, stall_every: int, stall_ms: tuple[float, float]):
    """Each sleep returns 30 us late; one in ``stall_every`` returns late by a uniform draw in ``stall_ms``."""

    def sleep(s: float) -> None:
        late = 30e-6
        if rng.integers(stall_every) == 0:
            late = rng.uniform(*stall_ms) / 1e3
        clock.sleep(s + late)

    return sleep


def _record(
    phased: bool,
    *,
    rate_error=0.0,
    stall_ms=(1.3, 1.8),
    stall_every=200,
    seconds=20,
    seed=1,
    latch=0.5,
    read_ns=250_000,
):
    clock = VirtualClock()
    chip = Chip(clock, PERIOD * (1 - rate_error), phase_ns=731_000, read_ns=read_ns, latch=latch)
    tracker = PollPhase(PERIOD) if phased else None
    poller = Poller("adis", "spi", PERIOD, lambda sink: chip.poll(sink, tracker), PERIOD, tracker)
    run_deadline(
        clock,
        [poller],
        MessageSink(lambda m: None),
        t0=0,
        end=seconds * 10**9,
        between=lambda t: None,
        should_stop=lambda: False,
        sleep=_stalling_sleep(clock, np.random.default_rng(seed), stall_every, stall_ms),
    )
    return chip, tracker


@pytest.mark.parametrize("latch", [0.0, 0.5, 1.0])
def test_polls_just_after_each_sample_survive_stalls_that_cost_blind_polls_samples(latch):
    """Stalls of 1.3-1.8 ms (over half a period, under three quarters of one) now and then: polled blind
    twice a period, some samples are lost; polled just after each sample is made, none, with fewer polls -
    wherever in its 0.25 ms the read takes the chip's sample (the gate takes it as the middle)."""
    blind, _ = _record(False, latch=latch)
    phased, tracker = _record(True, latch=latch)
    assert blind.lost >= 5
    assert phased.lost == 0 and phased.read > 8000
    assert phased.polls < 0.75 * blind.polls  # about 1.25 reads a sample, not 2
    assert tracker is not None and tracker.early < 0.4 * phased.read


def test_stalls_longer_than_a_period_cost_what_they_must_and_the_phase_is_found_again():
    """A 6 ms stall loses two samples whatever the schedule; after it the polls follow the chip again."""
    chip, tracker = _record(True, stall_ms=(6.0, 6.0), stall_every=2000)
    assert tracker is not None and tracker.edge is not None
    stalls = chip.lost / 2
    assert chip.lost % 2 == 0 and 1 <= stalls <= 40  # two per stall (6 ms < 3 periods), none otherwise


@pytest.mark.parametrize("rate_error", [-0.08, -0.03, 0.005, 0.03, 0.08])
def test_a_chip_off_its_configured_rate_is_followed(rate_error):
    """A chip 8 % slow to 8 % fast: its period is measured from the brackets; every sample read, still about
    one read a sample (with a constant 5 % creep instead, a chip 8 % fast would lose one in ~30)."""
    chip, tracker = _record(True, rate_error=rate_error, stall_every=10**9)
    assert chip.lost == 0
    assert chip.polls < 1.5 * chip.read
    assert tracker is not None
    assert tracker.period_ns == pytest.approx(PERIOD * (1 - rate_error), rel=0.01)


def test_a_chip_that_stops_making_samples_is_polled_blind_not_retried_in_a_spin():
    """The chip freezes (every read finds the same sample): after LOST_AFTER periods the phase is given up
    and the device polled blind (twice a period), not retried every RETRY of a period."""
    clock = VirtualClock()
    chip = Chip(clock, PERIOD, phase_ns=731_000)
    tracker = PollPhase(PERIOD)
    frozen_at = 2 * 10**9
    polls_after = []

    def poll(sink) -> int:
        if clock.now_ns() > frozen_at:
            chip.period = 1e18  # makes nothing more
            polls_after.append(clock.now_ns())
        return chip.poll(sink, tracker)

    run_deadline(
        clock,
        [Poller("adis", "spi", PERIOD, poll, PERIOD, tracker)],
        MessageSink(lambda m: None),
        t0=0,
        end=3 * 10**9,
        between=lambda t: None,
        should_stop=lambda: False,
        sleep=clock.sleep,
    )
    assert tracker.edge is None
    assert len(polls_after) < 1.05 * 2 * 10**9 / (PERIOD / 2) * 0.5  # ~2 a period, for the last second


def test_the_phase_is_learnt_from_a_bracket_and_forgotten_when_a_read_fails():
    """Reads of 0.1 ms, each taken as taking its sample at its middle."""
    p = PollPhase(1_000_000)
    assert p.next_poll_ns(0) is None
    p.observe(0, 100_000, True)  # found something, but when it was made is unknown
    assert p.next_poll_ns(100_000) is None
    p.observe(500_000, 600_000, False)  # nothing at 0.55 ms
    p.observe(1_000_000, 1_100_000, True)  # found at 1.05 ms, and the read before found one at 0.05 ms:
    # made in (0.55, min(1.05, 0.05 + 1)] ms; the estimate is MARGIN before its latest
    assert p.edge == max(550_000, 1_050_000 - int(MARGIN * 1_000_000))
    # the next read's middle MARGIN after the next sample
    assert p.next_poll_ns(1_100_000) == p.edge + 1_000_000 + int(MARGIN * 1_000_000) - 50_000
    p.observe(1_900_000, 2_000_000, False)  # too early: read again a little later
    assert p.early == 1 and p.next_poll_ns(2_000_000) == 2_000_000 + int(RETRY * 1_000_000)
    p.observe(2_050_000, 2_150_000, None)  # a failed read: start again
    assert p.edge is None and p.next_poll_ns(2_150_000) is None


@pytest.mark.parametrize("wired", [False, True])
def test_the_adis16448_driver_polled_on_its_phase_loses_nothing_to_stalls_that_cost_blind_polls(wired):
    """The real driver on the chip and CP2130 simulators (tests/test_data_ready.py's rig), placed by the
    station's Timeline, a read taking 0.2 ms: stalls of 1.3-1.8 ms every ~30 sleeps cost blind polls
    samples, and none polled on the chip's phase. Wired, the data-ready count is the truth: every pulse is
    a sample written or lost."""
    lost = {}
    for phased in (False, True):
        clock, chip, _, _, spi = rig("cp2130", wired=wired)
        drv = adis.ADIS16448(spi, {"data_ready": "gpio4" if wired else "none"}, sleep=clock.sleep)
        drv.clock_ns = clock.now_ns
        info = drv.open()
        period = round(1e9 / info.rate_hz)
        tl = Timeline(period, info.settings.get("counter_modulus"), overflow=info.overflow, buffer_s=info.buffer_s)
        tracker = PollPhase(period) if phased else None

        def poll(sink, drv=drv, clock=clock, tl=tl, tracker=tracker, period=period) -> int:
            start = clock.now_ns()
            clock.sleep(100e-6)  # the USB transfer before the chip's sample is taken ...
            block = drv.read_block()
            clock.sleep(100e-6)  # ... and after
            end = clock.now_ns()
            if tracker is not None:
                tracker.observe(start, end, drv.new_sample)
            tl.place(block, end, started=start)
            return period

        first = chip.data_ready_edges()
        run_deadline(
            clock,
            [Poller("adis", "cp2130", period, poll, period, tracker)],
            MessageSink(lambda m: None),
            t0=clock.now_ns(),
            end=clock.now_ns() + 4 * 10**9,
            between=lambda t: None,
            should_stop=lambda: False,
            sleep=_stalling_sleep(clock, np.random.default_rng(5), 30, (1.3, 1.8)),
        )
        tl.place(drv.drain(), clock.now_ns(), poll=False)
        produced = chip.data_ready_edges() - first
        assert tl.samples > 0.99 * produced - tl.lost
        if wired:
            assert tl.samples + tl.lost == produced  # the count: exact
        lost[phased] = tl.lost
    assert lost[False] >= 5 and lost[True] == 0
