"""Timestamp hygiene of imported recordings: order, duplicates, gaps, jitter, true rate.

:class:`StampChecker` is fed the stamps block by block (bounded memory, any
length of record) and gives a :class:`StampReport`. Nothing is dropped or
reordered: the checker only measures and lists the places (``gaps``,
``backwards``) so the importer can log them as run-file events.

Definitions (``dt`` = difference of consecutive stamps in file order):

* nominal period: median ``dt`` of the first block's positive steps (a few
  thousand samples at least; a block is the importer's read size);
* backwards: ``dt < 0`` (non-monotonic); duplicate: ``dt == 0``;
* gap: ``dt > gap_factor`` x nominal period, with the samples it misses
  ``round(dt / period) - 1``, unless a neighbouring step is a duplicate or
  backward one (then the long step is the other half of a misordered stamp);
* jitter: standard deviation of the regular steps (positive, not gaps) around
  their mean, in ns;
* true rate: one over the period of a least-squares fit of the stamps against
  their sample index over every run of regular steps (gaps, backward and
  duplicated steps excluded; one common period, each run its own offset), Hz,
  with its standard error from the fit's residuals. A median step is never
  used: integer-ms stamps of a 400 Hz log step 2, 3, 2, 3 ms, whose median is
  2 or 3 ms (500 or 333 Hz) while the fit gives 2.5 ms;
* quantum: the greatest common divisor of the positive steps (1 ms for
  integer-ms stamps); :meth:`StampReport.warnings` names it when it is coarser
  than a tenth of the period.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imustation.runfile.rate import PooledFit

#: a step longer than this many nominal periods is a gap
GAP_FACTOR = 1.5
#: at most this many gaps / backward steps are listed individually (all are counted)
MAX_LISTED = 1000
#: stamps quantised coarser than this fraction of the period are named in a warning
QUANTUM_WARN = 0.1


@dataclass
class StampReport:
    """What the stamps of one stream show. Times in ns, rates in Hz."""

    n: int = 0
    first_ns: int = 0
    last_ns: int = 0
    nominal_period_ns: float = math.nan
    true_rate_hz: float = math.nan
    jitter_ns: float = math.nan
    backwards: int = 0
    duplicates: int = 0
    gaps: int = 0
    missing: int = 0
    #: (sample index, dt ns, missing samples) of the first MAX_LISTED gaps
    gap_list: list[tuple[int, int, int]] = field(default_factory=list)
    #: (sample index, dt ns) of the first MAX_LISTED backward steps
    backward_list: list[tuple[int, int]] = field(default_factory=list)
    #: standard error of true_rate_hz from the fit's residuals, Hz (nan with fewer than 3 regular stamps)
    rate_sigma_hz: float = math.nan
    #: greatest common divisor of the positive steps, ns (0: no positive step)
    quantum_ns: int = 0
    #: stamps in the fit (those joined to a neighbour by a regular step)
    fitted: int = 0
    #: longest minus shortest regular step, ns
    step_spread_ns: int = 0

    def warnings(self) -> list[str]:
        """What makes the stamps less than they look: a quantum coarser than QUANTUM_WARN of the period."""
        out = []
        period = 1e9 / self.true_rate_hz if self.true_rate_hz > 0 else self.nominal_period_ns
        # steps that all equal one period are not quantised, they are exact: only steps that differ by the quantum
        varied = self.step_spread_ns >= self.quantum_ns > 0
        if varied and math.isfinite(period) and self.quantum_ns > QUANTUM_WARN * period:
            out.append(
                f"stamps quantised to {_ns_text(self.quantum_ns)}, {self.quantum_ns / period:.2g} of the "
                f"{_ns_text(period)} period: single steps are off by up to {_ns_text(self.quantum_ns)}; the rate "
                f"{self.true_rate_hz:.7g} Hz is a fit over {self.fitted} stamps, not a step"
            )
        return out

    @property
    def monotonic(self) -> bool:
        return self.backwards == 0

    @property
    def duration_s(self) -> float:
        return (self.last_ns - self.first_ns) * 1e-9 if self.n > 1 else 0.0

    def summary(self) -> str:
        """One line for the import printout."""
        return (
            f"{self.n} samples, {self.duration_s:.1f} s, true rate {self.true_rate_hz:.4g} Hz, "
            f"jitter {self.jitter_ns / 1e3:.3g} us, {self.gaps} gaps ({self.missing} samples missing), "
            f"{self.duplicates} duplicated, {self.backwards} non-monotonic stamps"
        )

    def as_dict(self) -> dict:
        return {
            "n": self.n,
            "duration_s": self.duration_s,
            "nominal_period_ns": self.nominal_period_ns,
            "true_rate_hz": self.true_rate_hz,
            "jitter_ns": self.jitter_ns,
            "backwards": self.backwards,
            "duplicates": self.duplicates,
            "gaps": self.gaps,
            "missing": self.missing,
            "rate_sigma_hz": self.rate_sigma_hz,
            "quantum_ns": self.quantum_ns,
        }


def _ns_text(ns: float) -> str:
    """A duration in ns as text in the unit that suits it (``1 ms``, ``2.5 ms``, ``40 ns``)."""
    for unit, f in (("s", 1e9), ("ms", 1e6), ("us", 1e3)):
        if ns >= f:
            return f"{ns / f:.4g} {unit}"
    return f"{ns:.4g} ns"


class StampChecker:
    """Streaming hygiene check: :meth:`update` with each block of stamps, then :meth:`report`.

    A long step next to a duplicated or backward step is a misordered stamp,
    not a gap (a swapped pair makes steps 2T, -T, 2T); so each step is
    classified once its neighbours are known, the last one of a block with the
    next block (or in :meth:`report`).
    """

    def __init__(self, gap_factor: float = GAP_FACTOR, period_ns: float | None = None):
        self.gap_factor = float(gap_factor)
        self.r = StampReport()
        if period_ns is not None:
            self.r.nominal_period_ns = float(period_ns)
        self._last: int | None = None
        # the last step, not yet classified: (dt, index of the sample after it, previous step was <= 0)
        self._pending: tuple[int, int, bool] | None = None
        self._reg_n = 0
        self._reg_sum = 0.0
        self._reg_sum2 = 0.0
        self._fit = PooledFit()
        self._reg_lo, self._reg_hi = math.inf, -math.inf

    def update(self, t_ns: np.ndarray) -> None:
        t = np.asarray(t_ns, dtype=np.int64)
        if len(t) == 0:
            return
        r = self.r
        if self._last is None:
            r.first_ns = int(t[0])
            r.last_ns = int(t.max())
            dt = np.diff(t)
            g0 = 1
        else:
            dt = np.diff(t, prepend=self._last)
            g0 = r.n
            r.last_ns = max(r.last_ns, int(t.max()))
        if math.isnan(r.nominal_period_ns):
            pos = dt[dt > 0]
            if len(pos):
                med = float(np.median(pos))
                # the mean of the steps near the median: 2.5 ms for integer-ms steps of 2 and 3 ms
                r.nominal_period_ns = float(pos[pos <= self.gap_factor * med].mean())
        pos = dt[dt > 0]
        if len(pos):
            r.quantum_ns = int(np.gcd.reduce(np.append(pos, r.quantum_ns)))
        if math.isfinite(r.nominal_period_ns) and len(dt):
            self._fit.update(t, dt, (dt > 0) & (dt <= self.gap_factor * r.nominal_period_ns), r.n, r.first_ns,
                             self._last is not None)  # fmt: skip
        r.n += len(t)
        self._last = int(t[-1])
        if len(dt) == 0:
            return
        idx = g0 + np.arange(len(dt), dtype=np.int64)
        back = np.nonzero(dt < 0)[0]
        r.backwards += len(back)
        r.duplicates += int(np.count_nonzero(dt == 0))
        for k in back[: max(0, MAX_LISTED - len(r.backward_list))]:
            r.backward_list.append((int(idx[k]), int(dt[k])))
        if self._pending is not None:
            pdt, pidx, pbad = self._pending
            dt = np.concatenate([[pdt], dt])
            idx = np.concatenate([[pidx], idx])
        else:
            pbad = False
        bad = dt <= 0
        prev_bad = np.concatenate([[pbad], bad[:-1]])
        self._pending = (int(dt[-1]), int(idx[-1]), bool(prev_bad[-1]))
        self._classify(dt[:-1], idx[:-1], prev_bad[:-1], bad[1:])

    def _classify(self, dt: np.ndarray, idx: np.ndarray, prev_bad: np.ndarray, next_bad: np.ndarray) -> None:
        r = self.r
        period = r.nominal_period_ns
        if len(dt) == 0 or not math.isfinite(period) or period <= 0:
            return
        long = dt > self.gap_factor * period
        gi = np.nonzero(long & ~prev_bad & ~next_bad)[0]
        if len(gi):
            miss = np.maximum(np.rint(dt[gi] / period).astype(np.int64) - 1, 1)
            r.gaps += len(gi)
            r.missing += int(miss.sum())
            room = max(0, MAX_LISTED - len(r.gap_list))
            for k, m in zip(gi[:room], miss[:room], strict=True):
                r.gap_list.append((int(idx[k]), int(dt[k]), int(m)))
        reg = dt[(dt > 0) & ~long].astype(np.float64)
        if len(reg):
            self._reg_lo = min(self._reg_lo, float(reg.min()))
            self._reg_hi = max(self._reg_hi, float(reg.max()))
        self._reg_n += len(reg)
        self._reg_sum += float(reg.sum())
        self._reg_sum2 += float((reg * reg).sum())

    def flush(self) -> None:
        """Classify the held-back last step (the record has ended)."""
        if self._pending is not None:
            pdt, pidx, pbad = self._pending
            self._pending = None
            self._classify(np.array([pdt]), np.array([pidx]), np.array([pbad]), np.array([False]))

    def report(self) -> StampReport:
        self.flush()
        r = self.r
        if self._reg_n:
            mean = self._reg_sum / self._reg_n
            var = max(self._reg_sum2 / self._reg_n - mean * mean, 0.0)
            r.jitter_ns = math.sqrt(var)
            r.step_spread_ns = int(self._reg_hi - self._reg_lo)
            period, sigma, r.fitted = self._fit.result()
            if period > 0:
                r.true_rate_hz = 1e9 / period
                r.rate_sigma_hz = r.true_rate_hz * sigma / period
        return r


def check_stamps(t_ns: np.ndarray, gap_factor: float = GAP_FACTOR) -> StampReport:
    """Hygiene report of a whole array of stamps (ns)."""
    c = StampChecker(gap_factor)
    c.update(t_ns)
    return c.report()
