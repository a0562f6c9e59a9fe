"""The rate a record's timestamps show, against the ``rate_hz`` its file states (docs/runfile.md).

:class:`PooledFit` fits stamps against their sample index by least squares over every run of
regular steps (a step in (0, 1.5] periods; gaps, repeated and backward stamps end a run): one
common period, each run its own offset, so holes - logged or not - neither lengthen nor shorten
it. It streams (the importer feeds it block by block) and keeps one open run. :func:`stamp_rate`
applies it to an array against a stated rate; the reader (:mod:`.checks`) refuses a rate the stamps
contradict grossly and corrects one they contradict beyond their jitter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: a step longer than this many periods is a hole (the importer's and holes.py's threshold)
GAP_FACTOR = 1.5


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


def stamp_rate(t_ns: np.ndarray, rate_hz: float) -> StampRate:
    """The rate of the stamps ``t_ns`` (ns) fitted over their runs of steps within (0, GAP_FACTOR] periods
    of ``rate_hz`` (Hz): holes of any length are excluded, so a record that lost 40 % of its samples in
    small holes still shows its rate."""
    t = np.asarray(t_ns, dtype=np.int64)
    if len(t) < 3:
        return StampRate(math.nan, math.nan, 0, 0)
    d = np.diff(t)
    regular = (d > 0) & (d <= GAP_FACTOR * 1e9 / rate_hz)
    fit = PooledFit()
    fit.update(t, d, regular, 0, int(t[0]), cont=False)
    period, sigma, _ = fit.result()
    if not period > 0:
        return StampRate(math.nan, math.nan, int(regular.sum()), int((d > 0).sum()))
    hz = 1e9 / period
    return StampRate(hz, hz * sigma / period, int(regular.sum()), int((d > 0).sum()))
