"""Bias terms beyond the paper's standard model: bias instability, rate random walk, temperature.

Why: real recordings show a flat bias-instability floor over decades of cluster time
that one Gauss-Markov term cannot follow, a rising rate random walk, and a bias that
follows the die temperature (warm-up after power-on, the room's slow drift). These
terms change slowly, so they are generated on coarse time grids and linearly
interpolated to the output samples: cheap at any output rate, and added after the
chip's output filter (its unit DC gain leaves them unchanged).

* **Bias instability** B (IEEE Std 952-1997, C.1: flicker rate noise whose Allan
  deviation has its floor at 0.664 B): a sum of Gauss-Markov terms with correlation
  times spread two per decade from :data:`FLICKER_T_MIN_S` to :data:`FLICKER_T_MAX_S`
  (the usual construction of 1/f noise from relaxation processes), each generated
  exactly (AR(1)) on a grid of 32 steps per correlation time (the grid step, not
  finer than :data:`BASE_STEP_S`, for the fastest terms), the weights
  fitted once (non-negative least squares) so that the sum's Allan variance is flat
  at (2 ln 2 / pi) B^2 over 1 s .. 1e6 s. docs/simulation.md gives the error.
* **Rate random walk** K: a random walk of the bias, steps K sqrt(h) every h
  (:data:`BASE_STEP_S`); Allan variance K^2 tau / 3.
* **Temperature**: ``bias_tempco`` times the die's rise over its power-on temperature,
  :class:`DieTemperature` (a warm-up exponential plus the room's slow sinusoid).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: correlation times of the flicker terms, s: two per decade over these bounds
FLICKER_T_MIN_S = 0.25
FLICKER_T_MAX_S = 1e7
FLICKER_PER_DECADE = 2
#: cluster times over which the flicker floor is fitted flat, s
FLICKER_FIT_TAU_S = (1.0, 1e6)
#: grid step of the slow terms, s (rounded to whole output periods); every flicker term
#: has at least this many grid steps per correlation time
BASE_STEP_S = 1.0 / 16.0
STEPS_PER_TAU = 32
#: Allan deviation floor of flicker noise over B (IEEE 952): sqrt(2 ln 2 / pi)
FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)


def gauss_markov_avar(tau: np.ndarray, variance: float, t_corr: float) -> np.ndarray:
    """Allan variance of a Gauss-Markov process (stationary ``variance``, correlation time ``t_corr`` s)
    at cluster times ``tau`` (s); IEEE 952 / El-Sheimy et al. 2008."""
    tau = np.asarray(tau, dtype=float)
    a = tau / t_corr
    small = a < 1e-4
    safe = np.where(small, 1.0, a)
    exact = variance / safe**2 * (2.0 * safe - 3.0 + 4.0 * np.exp(-safe) - np.exp(-2.0 * safe))
    return np.where(small, variance * (2.0 * a / 3.0 - a**2 / 2.0), exact)


@lru_cache(maxsize=1)
def flicker_design() -> tuple[np.ndarray, np.ndarray]:
    """(correlation times s, stationary variances per B^2) of the Gauss-Markov sum."""
    from scipy.optimize import nnls

    decades = math.log10(FLICKER_T_MAX_S / FLICKER_T_MIN_S)
    times = FLICKER_T_MIN_S * 10.0 ** (np.arange(int(round(decades * FLICKER_PER_DECADE)) + 1) / FLICKER_PER_DECADE)
    tau = np.logspace(math.log10(FLICKER_FIT_TAU_S[0]), math.log10(FLICKER_FIT_TAU_S[1]), 300)
    design = np.column_stack([gauss_markov_avar(tau, 1.0, t) for t in times]) / FLICKER_FLOOR**2
    weights, _ = nnls(design, np.ones_like(tau))
    return times, weights


def flicker_avar(tau: np.ndarray, b: float) -> np.ndarray:
    """Allan variance of the generated bias instability ``b`` at ``tau`` (s), continuous time."""
    times, weights = flicker_design()
    return b * b * sum(w * gauss_markov_avar(tau, 1.0, t) for t, w in zip(times, weights, strict=True))


@dataclass(frozen=True)
class DieTemperature:
    """Die temperature after power-on, degC: ``temp_c`` + a warm-up ``warmup_c`` (1 - exp(-t /
    warmup_tau_s)) + the room's ``drift_c`` sin(2 pi t / ``period_s``); t in s since power-on."""

    temp_c: float = 30.0
    drift_c: float = 0.5
    period_s: float = 6 * 3600.0
    warmup_c: float = 0.0
    warmup_tau_s: float = 600.0

    def __call__(self, t_s: float) -> float:
        value = self.temp_c + self.drift_c * math.sin(2.0 * math.pi * t_s / self.period_s)
        if self.warmup_c:
            value += self.warmup_c * -math.expm1(-t_s / self.warmup_tau_s)
        return value

    def rise(self, t_s: np.ndarray) -> np.ndarray:
        """Temperature minus the power-on temperature at times ``t_s`` (s), K."""
        out = self.drift_c * np.sin(2.0 * np.pi * t_s / self.period_s)
        if self.warmup_c:
            out = out - self.warmup_c * np.expm1(-t_s / self.warmup_tau_s)
        return out


class _Nodes:
    """A process known every ``step`` fine samples (node 0 at sample 0), read at consecutive fine
    samples by linear interpolation. ``produce(n)`` gives the next ``n`` nodes, shape (n, axes)."""

    def __init__(self, step: int, produce: Callable[[int], np.ndarray]):
        self.step = step
        self.produce = produce
        self.first = 0  # node index of vals[0]
        self.vals = produce(1)
        self.k = 0  # next fine sample

    def next(self, n: int) -> np.ndarray:
        k0, k1 = self.k, self.k + n
        self.k = k1
        step = self.step
        last = (k1 - 1) // step + (0 if step == 1 else 1)  # the node after the last sample, for the slope
        have = self.first + len(self.vals) - 1
        if last > have:
            self.vals = np.concatenate([self.vals, self.produce(last - have)])
        if step == 1:
            out = self.vals[k0 - self.first : k1 - self.first]
        else:
            # whole node intervals by broadcasting, then the wanted samples out of them
            q0, q1 = k0 // step - self.first, (k1 - 1) // step - self.first + 1
            lo = self.vals[q0:q1]
            slope = self.vals[q0 + 1 : q1 + 1] - lo
            frac = np.arange(step) / step
            block = (lo[:, None, :] + slope[:, None, :] * frac[None, :, None]).reshape(-1, lo.shape[1])
            start = k0 - (q0 + self.first) * step
            out = block[start : start + n]
        cut = k1 // step - self.first  # nodes before the next sample's are not needed again
        self.vals = self.vals[cut:]
        self.first += cut
        return out


class SlowBias:
    """Bias instability, rate random walk and temperature-driven bias of every axis of a source.

    Parameters
    ----------
    fs_hz : output rate, Hz.
    b : bias instability B per axis (rad/s or m/s^2; 0 = none).
    k : rate random walk K per axis (rad/s/sqrt(s) or m/s^2/sqrt(s); 0 = none).
    tempco : bias change per kelvin of die temperature per axis (rad/s/K or m/s^2/K).
    temperature : the die temperature model (its rise over power-on drives ``tempco``).
    seed : integer seed (the stream does not depend on how it is asked).
    """

    def __init__(
        self,
        fs_hz: float,
        b: Sequence[float],
        k: Sequence[float],
        tempco: Sequence[float],
        temperature: DieTemperature,
        seed: int,
    ):
        self.b = np.asarray(b, dtype=float)
        self.k = np.asarray(k, dtype=float)
        self.tempco = np.asarray(tempco, dtype=float)
        self.temperature = temperature
        self.axes = len(self.b)
        self.step = max(1, round(fs_hz * BASE_STEP_S))
        self.h = self.step / fs_hz  # grid step, s
        self._node = 0  # next base node
        self._flicker: _Nodes | None = None
        if np.any(self.b > 0):
            self._flicker = self._flicker_levels(seed)
        self._rrw_rng = np.random.default_rng([seed, 0x4E4B, 1]) if np.any(self.k > 0) else None
        self._rrw = np.zeros(self.axes)
        self._out = _Nodes(self.step, self._base)

    def _flicker_levels(self, seed: int) -> _Nodes:
        """The flicker terms on nested grids (steps 2^j base steps, at least STEPS_PER_TAU per
        correlation time); each level adds its own terms to the next coarser level interpolated
        onto its nodes, so every level costs its own nodes only. Returns the finest level, read
        on the base grid."""
        times, weights = flicker_design()
        levels: dict[int, list] = {}
        for i, (t_corr, w) in enumerate(zip(times, weights, strict=True)):
            if w > 0:
                m = max(1, 2 ** int(math.floor(math.log2(t_corr / (STEPS_PER_TAU * self.h)))))
                levels.setdefault(m, []).append(self._flicker_term(t_corr, m, math.sqrt(w) * self.b, seed, i))
        coarser: tuple[int, _Nodes] | None = None
        for m in sorted(levels, reverse=True):
            terms = levels[m]
            above = None if coarser is None else _Nodes(coarser[0] // m, coarser[1])

            def produce(n: int, terms=terms, above=above) -> np.ndarray:
                out = terms[0](n)
                for term in terms[1:]:
                    out = out + term(n)
                return out if above is None else out + above.next(n)

            coarser = (m, produce)
        assert coarser is not None
        return _Nodes(coarser[0], coarser[1])

    def _flicker_term(self, t_corr: float, m: int, scale: np.ndarray, seed: int, i: int) -> Callable[[int], np.ndarray]:
        """Node values of one Gauss-Markov term (exact AR(1)) on a grid of ``m`` base steps."""
        phi = math.exp(-m * self.h / t_corr)
        innov = math.sqrt(-math.expm1(-2.0 * m * self.h / t_corr))
        rng = np.random.default_rng([seed, 0xF11C, i])
        state = [None]

        def produce(n: int) -> np.ndarray:
            from scipy.signal import lfilter

            e = rng.standard_normal((n, self.axes))
            if state[0] is None:  # node 0: stationary start
                e[0] /= innov
                zi = np.zeros((1, self.axes))
            else:
                zi = phi * state[0][None, :]
            x, _ = lfilter([innov], [1.0, -phi], e, axis=0, zi=zi)
            state[0] = x[-1]
            return x * scale

        return produce

    def _base(self, n: int) -> np.ndarray:
        """The next ``n`` nodes of the base grid: every term's sum there."""
        j = np.arange(self._node, self._node + n)
        self._node += n
        out = np.zeros((n, self.axes))
        if self._flicker is not None:
            out += self._flicker.next(n)
        if self._rrw_rng is not None:
            steps = self._rrw_rng.standard_normal((n, self.axes)) * (self.k * math.sqrt(self.h))
            if j[0] == 0:
                steps[0] = 0.0  # the walk starts at zero at power-on
            walk = np.cumsum(steps, axis=0) + self._rrw
            self._rrw = walk[-1]
            out += walk
        if np.any(self.tempco != 0):
            out += self.temperature.rise(j * self.h)[:, None] * self.tempco
        return out

    def next(self, n: int) -> np.ndarray:
        """The next ``n`` output samples of the slow bias, shape ``(n, axes)``."""
        return self._out.next(n)
