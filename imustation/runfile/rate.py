"""The rate a record's timestamps show, against the ``rate_hz`` its file states (docs/runfile.md).

:class:`PooledFit` fits stamps against their sample index by least squares over every run of
regular steps (a step in (0, 1.5] periods; gaps, repeated and backward stamps end a run): one
common period, each run its own offset, so holes - logged or not - neither lengthen nor shorten
it. It streams (the importer feeds it block by block) and keeps one open run. :func:`stamp_rate`
applies it to an array (or to windows of one, :func:`windows_rate`) against a stated rate.

The reader (:mod:`.checks`) probes a record in :func:`probe_windows` spread from its first row to its
last (never the whole of a 12 h record), refuses a rate the stamps contradict grossly, and corrects
one only when the record's whole span contradicts it beyond what its stamps' jitter can make
(:func:`span_rate`): a start-up transient over a record's first samples moves a pooled fit of a short
record by tenths of a percent, never the rate of the whole.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: a step longer than this many periods is a hole (the importer's and holes.py's threshold)
GAP_FACTOR = 1.5
#: a record is probed in at most WINDOWS windows of WINDOW_ROWS stamps spread evenly from its first row
#: to its last (a shorter record is read whole): 0.5 MB of stamps whatever its length
WINDOW_ROWS = 4097
WINDOWS = 16
#: a stated rate is contradicted (and corrected by the reader) where the fit over the runs is off by more
#: than RATE_SIGMAS standard errors and RATE_FLOOR (relative), and the record's whole span is off the
#: same way by more than RATE_FLOOR and its stamps' jitter can make (:func:`confirmed`); a deviation
#: below the floor moves a noise density by less than 0.05 %
RATE_SIGMAS = 5.0
RATE_FLOOR = 1e-3


class PooledFit:
    """Streaming least-squares fit of stamps against sample index, one slope for every run of regular steps.

    Each run (segment) keeps its count, index and stamp means and centred co-moments; runs are joined
    across blocks with the pairwise update (Chan et al. 1979), so nothing but the open run is kept and
    no large sums cancel. Stamps are taken relative to the record's first (exact in float64 to 104 days).
    """

    def __init__(self) -> None:
        self.sxx = self.sxy = self.syy = 0.0
        self.nodes = 0
        self.runs = 0
        self.open: list[float] | None = None  # n, mean k, mean t, Ckk, Ckt, Ctt of the open run

    def update(self, t: np.ndarray, dt: np.ndarray, regular: np.ndarray, n0: int, first: int, cont: bool) -> None:
        """``t``: the block's stamps (global indices from ``n0``); ``dt``/``regular``: the steps into each
        of them (the first from the previous block's last stamp when ``cont``, else the steps between them)."""
        k = n0 + np.arange(len(t), dtype=np.float64)
        y = (t - first).astype(np.float64)
        if cont:
            brk = ~regular  # step j leads into sample j
        else:
            brk = np.concatenate([[True], ~regular])  # the record's first sample starts a run
        if len(brk) != len(t):
            raise ValueError("steps and stamps do not match")
        seg = np.cumsum(brk)  # 0: continues the open run
        nseg = int(seg[-1]) + 1
        cnt = np.bincount(seg, minlength=nseg).astype(np.float64)
        used = cnt > 0
        mk = np.bincount(seg, k, nseg)[used] / cnt[used]
        my = np.bincount(seg, y, nseg)[used] / cnt[used]
        ids = np.flatnonzero(used)
        where = np.searchsorted(ids, seg)
        dk, dy = k - mk[where], y - my[where]
        ckk = np.bincount(where, dk * dk, len(ids))
        cky = np.bincount(where, dk * dy, len(ids))
        cyy = np.bincount(where, dy * dy, len(ids))
        stats = [[c, a, b, p, q, r] for c, a, b, p, q, r in zip(cnt[used], mk, my, ckk, cky, cyy, strict=True)]
        if ids[0] == 0 and self.open is not None:
            stats[0] = _merge(self.open, stats[0])
        elif self.open is not None:
            self._close(self.open)
        for st in stats[:-1]:
            self._close(st)
        self.open = stats[-1]

    def _close(self, st: list[float]) -> None:
        n, _, _, ckk, cky, cyy = st
        self.nodes += int(n)
        if n >= 2:
            self.runs += 1
            self.sxx += ckk
            self.sxy += cky
            self.syy += cyy

    def result(self) -> tuple[float, float, int]:
        """``(period ns, its standard error ns, stamps fitted)``; period nan without a regular step."""
        if self.open is not None:
            self._close(self.open)
            self.open = None
        if self.sxx <= 0:
            return math.nan, math.nan, 0
        slope = self.sxy / self.sxx
        fitted = self.nodes
        dof = fitted - 2 * self.runs
        sigma = math.sqrt(max(self.syy - slope * self.sxy, 0.0) / dof / self.sxx) if dof > 0 else math.nan
        return slope, sigma, fitted


def _merge(a: list[float], b: list[float]) -> list[float]:
    """Two runs' (n, mean k, mean t, Ckk, Ckt, Ctt) joined (pairwise update of co-moments)."""
    na, nb = a[0], b[0]
    n = na + nb
    dk, dy = b[1] - a[1], b[2] - a[2]
    w = na * nb / n
    return [n, a[1] + dk * nb / n, a[2] + dy * nb / n, a[3] + b[3] + w * dk * dk, a[4] + b[4] + w * dk * dy,
            a[5] + b[5] + w * dy * dy]  # fmt: skip


@dataclass(frozen=True)
class StampRate:
    """What stamps show against a stated rate: the fitted rate and its standard error (Hz; nan without
    a regular step), the steps near the stated period (regular) among the positive ones."""

    rate_hz: float
    sigma_hz: float
    regular: int
    steps: int


def regular_steps(d_ns: np.ndarray, rate_hz: float) -> np.ndarray:
    """Which steps between stamps (ns) are regular: within (0, GAP_FACTOR] periods of ``rate_hz`` (Hz); a
    gap, a repeated or a backward stamp ends a run."""
    return (d_ns > 0) & (d_ns <= GAP_FACTOR * 1e9 / rate_hz)


def stamp_rate(t_ns: np.ndarray, rate_hz: float) -> StampRate:
    """The rate of the stamps ``t_ns`` (ns) fitted over their runs of steps within (0, GAP_FACTOR] periods
    of ``rate_hz`` (Hz): holes of any length are excluded, so a record that lost 40 % of its samples in
    small holes still shows its rate."""
    return windows_rate([(0, np.asarray(t_ns, dtype=np.int64))], rate_hz)


def windows_rate(windows: list[tuple[int, np.ndarray]], rate_hz: float) -> StampRate:
    """:func:`stamp_rate` pooled over ``windows`` of one record, ``(first row, stamps ns)`` in row order (no
    step is taken between two windows: what lies between them is not read)."""
    fit = PooledFit()
    regular = steps = 0
    first = None
    for row, t in windows:
        t = np.asarray(t, dtype=np.int64)
        if len(t) < 2:
            continue
        d = np.diff(t)
        reg = regular_steps(d, rate_hz)
        first = int(t[0]) if first is None else first
        fit.update(t, d, reg, row, first, cont=False)
        regular += int(reg.sum())
        steps += int((d > 0).sum())
    if regular < 2:
        return StampRate(math.nan, math.nan, regular, steps)
    period, sigma, _ = fit.result()
    if not period > 0:
        return StampRate(math.nan, math.nan, regular, steps)
    hz = 1e9 / period
    return StampRate(hz, hz * sigma / period, regular, steps)


def probe_windows(n: int) -> list[tuple[int, int]]:
    """``(start, stop)`` rows of the windows a record of ``n`` rows is probed in: the whole record up to
    WINDOWS * WINDOW_ROWS rows, else WINDOWS windows of WINDOW_ROWS, the first at row 0, the last ending
    at row ``n - 1``."""
    if n <= WINDOWS * WINDOW_ROWS:
        return [(0, n)] if n else []
    starts = np.rint(np.linspace(0, n - WINDOW_ROWS, WINDOWS)).astype(np.int64)
    return [(int(a), int(a) + WINDOW_ROWS) for a in starts]


@dataclass(frozen=True)
class SpanRate:
    """A record's rate from its whole span: ``count`` sample periods (rows plus the losses its events log)
    between its first and last stamp, ``span_s`` apart; ``rate_hz`` = count / span. ``jitter_ns``: the
    largest distance of a probed stamp from that line (at least one stated period: a host dates a sample at
    the read that found it); ``bound``: the relative error that jitter can make at both ends (2 J / span)."""

    rate_hz: float
    bound: float
    count: int
    span_s: float
    jitter_ns: float


def span_rate(
    windows: list[tuple[int, np.ndarray]], n: int, rate_hz: float, loss_t: np.ndarray, loss_n: np.ndarray
) -> SpanRate:
    """The rate of a record of ``n`` rows from its first to its last stamp (``windows`` from
    :func:`probe_windows`, the first holding row 0 and the last row ``n - 1``; stamps ns).

    ``loss_t`` / ``loss_n``: the times (ns, sorted) and sample counts of the losses the record's events log
    (an event is dated at the first sample it says is missing, so it counts before every later stamp).
    ``rate_hz``: the stated rate, Hz (its period is the least jitter a stamp is given)."""
    cum = np.concatenate([[0], np.cumsum(np.asarray(loss_n, dtype=np.int64))])
    t_sorted = np.asarray(loss_t, dtype=np.int64)

    def lost_before(t: np.ndarray) -> np.ndarray:
        return cum[np.searchsorted(t_sorted, t, side="left")]

    ta, tb = int(windows[0][1][0]), int(windows[-1][1][-1])
    la, lb = lost_before(np.array([ta, tb]))
    count = int(n - 1 + lb - la)
    span = tb - ta
    if count < 1 or span <= 0:
        return SpanRate(math.nan, math.inf, count, span / 1e9, math.nan)
    period = span / count
    jitter = 1e9 / rate_hz
    for row, t in windows:
        t = np.asarray(t, dtype=np.int64)
        k = row + np.arange(len(t), dtype=np.int64) + lost_before(t) - la
        res = (t - ta).astype(np.float64) - k * period
        jitter = max(jitter, float(np.abs(res).max()))
    return SpanRate(1e9 / period, 2 * jitter / span, count, span / 1e9, jitter)


def confirmed(sr: StampRate, rate_hz: float, span: Callable[[], SpanRate]) -> bool:
    """Whether the stamps contradict the stated ``rate_hz`` (Hz) over the whole record: the fit ``sr`` off
    by more than RATE_SIGMAS standard errors and RATE_FLOOR, and ``span()`` (asked only then) off the same
    way by more than RATE_FLOOR and its bound. A fit over a short record follows a start-up transient of a
    host-clock capture (0.63 % over 162 samples); the span of 0.4 s is known to 1.25 % only."""
    if not sr.rate_hz > 0:
        return False
    off = rate_hz / sr.rate_hz - 1.0
    if not (abs(off) > RATE_FLOOR and abs(off) > RATE_SIGMAS * sr.sigma_hz / sr.rate_hz):
        return False
    sp = span()
    whole = rate_hz / sp.rate_hz - 1.0 if sp.rate_hz > 0 else 0.0
    return abs(whole) > RATE_FLOOR and abs(whole) > sp.bound and whole * off > 0


def capture_rate(first_stamps: np.ndarray, rate_hz: float) -> float:
    """The rate (Hz) a capture counts an outage's losses with before its file is read: the stated
    ``rate_hz`` unless its first stamps (ns; no loss logged among them) contradict it by the reader's
    rule (:func:`confirmed`), then their fitted rate - so what the capture logs is what the reader will
    count the file's holes with, and a start-up transient moves neither.

    The stamps may straddle the outage being counted (a device with fewer samples before it than the
    reader probes): the fit takes each run of regular steps on its own, and the span is judged over the
    longest run only - across a hole whose count is not known yet the span says nothing (taken whole,
    with no loss logged, it confirmed any transient: a 400 Hz chip's outage counted at 399.3 Hz, 2 of
    1,154 samples short, and the file then read at 399.3 Hz)."""
    t = np.asarray(first_stamps, dtype=np.int64)
    if len(t) < 64:
        return rate_hz
    sr = stamp_rate(t, rate_hz)
    cuts = np.flatnonzero(~regular_steps(np.diff(t), rate_hz)) + 1
    runs = np.split(t, cuts)
    run = max(runs, key=len)
    none = np.zeros(0, np.int64)
    if len(run) > 1 and confirmed(sr, rate_hz, lambda: span_rate([(0, run)], len(run), rate_hz, none, none)):
        return sr.rate_hz
    return rate_hz
