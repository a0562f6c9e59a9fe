"""Temperature statistics: bias-vs-temperature regression, warm-up detection.

Statistics only: the readings come from run files through
:func:`imustation.analysis.pipeline.loaders.device_temperature` /
:func:`~imustation.analysis.pipeline.loaders.thermometer_temperature`, or from the monitor.

* :func:`fit_tempco` regresses the bias (block means of the rate) on the
  temperature interpolated to the block centres: slope in unit/K (e.g.
  rad/s/K; x 3600·180/π for °/h/K), with the OLS standard error and a
  significance test that accounts for autocorrelated noise. Block means of a
  rate with bias fluctuations are correlated, and the temperature is too, so the
  OLS standard error is a lower bound and a slow bias wander "explains" a slow
  temperature drift with a high R² (spurious regression). The test uses the
  effective number of independent blocks of the regression (Bartlett's variance
  of a cross-product of two autocorrelated series; Bretherton et al. 1999,
  J. Climate 12, eq. 30): ``n_eff = n / (1 + 2 sum_k (1 - k/n) r_x(k) r_e(k))``
  with ``r_x``, ``r_e`` the autocorrelations of the temperature and of the
  regression residuals, summed up to the first lag where ``r_e`` is no longer
  positive. The standard error is inflated by ``sqrt((n - 2) / (n_eff - 2))`` and
  the slope is significant when Student's t with ``n_eff - 2`` degrees of
  freedom gives a two-sided p below :data:`TEMPCO_ALPHA`. Measured on simulated
  12 h records with a Gauss-Markov bias and no temperature coefficient
  (tests/test_temperature.py, docs/reports.md): the OLS test finds a
  "coefficient" in most records, this one in a few per cent.
* :func:`fit_warmup` / :func:`detect_warmup` find the end of the warm-up from a
  smooth fit of the temperature (level + linear drift + one exponential
  transient): the first time after which the fitted curve changes slower than
  a limit. Quantisation steps of a coarse die thermometer (0.5 K) are not a
  warm-up: they average out of the fit. The paper discards at least the first
  hour; callers combine both (``max(detected, minimum)``).

Arrays in, dataclasses out; nothing here touches files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from imustation.errors import InputError

#: smallest temperature span (K) a coefficient is fitted over: about twice the finest MCP9804
#: resolution (0.0625 degC); below it the slope is quantisation noise
MIN_SPAN_C = 0.125
#: two-sided level of one temperature-coefficient significance test
TEMPCO_ALPHA = 0.01
#: family-wise level of a report's coefficients (every axis against every temperature, some tens of
#: tests): Holm's step-down procedure (:func:`holm`) picks the ones the report lists
TEMPCO_FAMILY_ALPHA = 0.05


@dataclass(frozen=True)
class TempcoResult:
    """Bias = intercept + slope * (T - T_mean): ``slope`` (unit/K) with OLS ``slope_stderr``.

    ``t_mean_c`` the mean temperature (°C), ``span_c`` the temperature range covered (K),
    ``r2`` the fraction of bias variance explained, ``n`` blocks used. The autocorrelation
    test (module docstring): ``rho_temp``, ``rho_resid`` lag-1 autocorrelations, ``n_eff``
    effective independent blocks, ``slope_stderr_eff`` the inflated standard error (unit/K;
    inf when ``n_eff`` <= 3), ``p_value`` and ``significant`` (p < ``alpha``).
    """

    slope: float
    slope_stderr: float
    intercept: float
    t_mean_c: float
    span_c: float
    r2: float
    n: int
    rho_temp: float = math.nan
    rho_resid: float = math.nan
    n_eff: float = math.nan
    slope_stderr_eff: float = math.nan
    p_value: float = math.nan
    significant: bool = False


def fit_tempco(
    bias_t_s: np.ndarray,
    bias: np.ndarray,
    temp_t_s: np.ndarray,
    temp_c: np.ndarray,
    min_span_c: float = MIN_SPAN_C,
    alpha: float = TEMPCO_ALPHA,
) -> TempcoResult:
    """Least-squares bias-vs-temperature line and its significance under autocorrelated noise.

    bias_t_s, bias : block centres (s) and block-mean rate (unit).
    temp_t_s, temp_c : temperature readings (s, °C), interpolated to the block centres;
        blocks outside the readings' time span are not used.
    min_span_c : refuse (InputError) when the temperature covers less than this (K).
    alpha : two-sided level of the significance test.
    """
    bias_t_s, bias = np.asarray(bias_t_s, float), np.asarray(bias, float)
    temp_t_s, temp_c = np.asarray(temp_t_s, float), np.asarray(temp_c, float)
    if len(temp_t_s) < 2:
        raise InputError("temperature regression needs at least two temperature readings")
    inside = (bias_t_s >= temp_t_s[0]) & (bias_t_s <= temp_t_s[-1])
    x = np.interp(bias_t_s[inside], temp_t_s, temp_c)
    y = bias[inside]
    n = len(y)
    if n < 3:
        raise InputError(f"temperature regression needs at least 3 bias blocks inside the readings, got {n}")
    xm = float(x.mean())
    dx = x - xm
    sxx = float(dx @ dx)
    span = float(x.max() - x.min())
    if span < min_span_c:
        raise InputError(
            f"temperature spans {span:.3g} K (< {min_span_c:g} K) over the record: no temperature coefficient"
        )
    slope = float(dx @ (y - y.mean())) / sxx
    resid = y - y.mean() - slope * dx
    s2 = float(resid @ resid) / (n - 2)
    syy = float(((y - y.mean()) ** 2).sum())
    r2 = 1.0 - float(resid @ resid) / syy if syy > 0 else math.nan
    se = math.sqrt(s2 / sxx)
    acf_x, acf_e = _acf(dx), _acf(resid)
    # Bartlett's sum, truncated where the residuals' autocorrelation is first no longer positive
    stop = np.nonzero(acf_e[1:] <= 0.0)[0]
    k_max = int(stop[0]) + 1 if len(stop) else n // 2
    lags = np.arange(1, k_max)
    excess = max(float(np.sum((1.0 - lags / n) * acf_x[1:k_max] * acf_e[1:k_max])), 0.0)
    n_eff = min(float(n), n / (1.0 + 2.0 * excess))
    if n_eff > 3.0:
        from scipy.stats import t as student_t  # here: the monitor imports this module for detect_warmup

        se_eff = se * math.sqrt((n - 2) / (n_eff - 2.0))
        p = float(2.0 * student_t.sf(abs(slope) / se_eff, n_eff - 2.0)) if se_eff > 0 else 0.0
    else:
        se_eff, p = math.inf, 1.0
    r_x, r_e = float(acf_x[1]), float(acf_e[1])
    return TempcoResult(slope, se, float(y.mean()), xm, span, r2, n, r_x, r_e, n_eff, se_eff, p, p < alpha)


def holm(p_values: np.ndarray, alpha: float = TEMPCO_FAMILY_ALPHA) -> np.ndarray:
    """Which of several tests are rejected at family-wise level ``alpha`` (Holm 1979, step-down).

    The k-th smallest p (k = 0, 1, ...) is compared with ``alpha / (m - k)``; every test up to the
    first that fails is rejected. NaN p-values count as 1.
    """
    p = np.nan_to_num(np.asarray(p_values, dtype=float), nan=1.0)
    m = len(p)
    order = np.argsort(p, kind="stable")
    ok = p[order] <= alpha / (m - np.arange(m))
    n_rejected = int(np.argmin(ok)) if not ok.all() else m
    out = np.zeros(m, dtype=bool)
    out[order[:n_rejected]] = True
    return out


def _acf(x: np.ndarray) -> np.ndarray:
    """Autocorrelation of a zero-mean series at lags 0..n-1 (biased estimator, FFT); zeros for a constant one."""
    n = len(x)
    f = np.fft.rfft(x, 2 * n)
    a = np.fft.irfft(f * np.conj(f), 2 * n)[:n]
    return a / a[0] if a[0] > 0 else np.zeros(n)


#: what a warm-up fit found (:attr:`WarmupFit.state`)
WARMUP_STATES = ("none", "transient", "unsettled", "unknown")


@dataclass(frozen=True)
class WarmupFit:
    """Smooth fit of a temperature record: ``T(t) = level + drift t + amplitude e^{-t/tau}``.

    ``amplitude_c`` (K, 0 when no transient is resolved) and ``tau_s`` (s) describe the
    warm-up transient, ``drift_c_per_h`` the linear drift; ``t0_s`` is the time of the first
    reading. ``state`` (one of :data:`WARMUP_STATES`) and ``end_s`` (s, on the readings' time axis):

    * ``"none"``: no warm-up (a flat record, quantisation steps, a drift slower than the limit);
      ``end_s`` is ``t0_s``;
    * ``"transient"``: a warm-up that settles inside the record; ``end_s`` its end, after which
      the smooth curve changes slower than the limit;
    * ``"unsettled"``: a warm-up still going (or settled too shortly before the last reading to
      tell), or a temperature drifting faster than the limit to the end without a transient to tell
      apart; ``end_s`` the last reading: no settled data;
    * ``"unknown"``: a record too short to tell (:data:`MIN_WARMUP_RECORD_S`); ``end_s`` NaN.

    ``change_c`` is the fitted curve's change over the warm-up (K), ``step_c`` the reading
    resolution estimated from the data (:func:`reading_step`), ``duration_s`` the record's span.
    """

    end_s: float
    amplitude_c: float
    tau_s: float
    drift_c_per_h: float
    level_c: float
    t0_s: float
    state: str = "none"
    change_c: float = 0.0
    step_c: float = math.nan
    duration_s: float = math.nan

    def smooth(self, t_s: np.ndarray) -> np.ndarray:
        """The fitted curve at ``t_s`` (°C)."""
        u = np.asarray(t_s, dtype=float) - self.t0_s
        tr = self.amplitude_c * np.exp(-u / self.tau_s) if self.amplitude_c else 0.0
        return self.level_c + self.drift_c_per_h / 3600.0 * u + tr

    @property
    def cut_s(self) -> float:
        """What a ``--warmup auto`` analysis leaves out (s on the readings' time axis, from its 0):
        ``end_s`` for ``"transient"``, else 0 (nothing settled to keep, or nothing to cut)."""
        return self.end_s if self.state == "transient" else 0.0

    def describe(self) -> str:
        """One phrase for tables and verdicts, e.g. ``"warm-up 2.3 K until 2749 s"``."""
        if self.state == "transient":
            return f"warm-up {abs(self.change_c):.2g} K until {self.end_s:.0f} s"
        if self.state == "unsettled":
            return f"temperature still changing at the end ({self.change_c:+.2g} K over the record): no settled data"
        if self.state == "unknown":
            # duration_s is the thermometer's span (its first to its last reading), not the record's length
            if self.duration_s < MIN_WARMUP_RECORD_S:
                return (
                    f"temperature readings span {self.duration_s:.0f} s: too short to tell a warm-up "
                    f"(needs {MIN_WARMUP_RECORD_S:.0f} s)"
                )
            return (
                f"temperature readings too few to tell a warm-up (needs {MIN_WARMUP_RECORD_S / WARMUP_BLOCK_S:.0f} "
                f"blocks of {WARMUP_BLOCK_S:.0f} s over {2 * MIN_WARMUP_TAU_S:.0f} s)"
            )
        return "no warm-up"


#: smallest warm-up time constant fitted (s): thermal transients of a die take minutes
MIN_WARMUP_TAU_S = 120.0
#: a transient must exceed this many standard errors (and MIN_WARMUP_C) to count
WARMUP_SIGNIFICANCE = 5.0
#: ... and this amplitude (K)
MIN_WARMUP_C = 0.05
#: ... and the fitted curve must change by this many reading steps (:func:`reading_step`) over the
#: warm-up: one or two quantisation steps of a 0.5 K die thermometer are not a warm-up
MIN_WARMUP_STEPS = 4.0
#: readings are averaged over blocks this long (s) before the fit: quantisation steps average out
WARMUP_BLOCK_S = 60.0
#: a record shorter than this (s) cannot tell a warm-up (two of the shortest time constants, and
#: eight blocks): state "unknown", nothing cut
MIN_WARMUP_RECORD_S = 8 * WARMUP_BLOCK_S


def reading_step(temp_c: np.ndarray) -> float:
    """Resolution of a temperature record (K), from the data: the median size of the changes
    between consecutive readings that change. One LSB for a quantised thermometer (its readings
    move by single steps), about the noise for a fine or block-averaged one; 0 for a constant record."""
    d = np.abs(np.diff(np.asarray(temp_c, dtype=float)))
    d = d[d > 0]
    return float(np.median(d)) if len(d) else 0.0


def fit_warmup(
    t_s: np.ndarray,
    temp_c: np.ndarray,
    *,
    window_s: float = 600.0,
    max_rate_c_per_h: float = 1.0,
    step_c: float | None = None,
) -> WarmupFit:
    """Fit the smooth warm-up model to a temperature record and find where the warm-up ends.

    t_s, temp_c : readings (s, °C), increasing times.
    window_s : settled data needed after the end (s): a record whose smooth curve settles
        less than this before its last reading is still warming up (state ``"unsettled"``).
    max_rate_c_per_h : settled when the smooth curve changes slower than this (°C/h).
    step_c : the readings' resolution (K); None: :func:`reading_step` of ``temp_c`` (pass the raw
        readings' step when ``temp_c`` are block means: ``pipeline.loaders.TemperatureRecord.step_c``).

    The readings are averaged over :data:`WARMUP_BLOCK_S` blocks and fitted by least squares
    with a level, a linear drift and, for each time constant of a log grid from
    :data:`MIN_WARMUP_TAU_S` to half the record, an exponential transient; the transient is
    kept when its amplitude exceeds :data:`WARMUP_SIGNIFICANCE` standard errors and
    :data:`MIN_WARMUP_C`. It is a warm-up only when the fitted curve also changes by
    :data:`MIN_WARMUP_STEPS` reading steps (:func:`reading_step`) and :data:`MIN_WARMUP_C`
    before it settles: quantisation steps, a slow drift or a flat record give none (a transient
    and a drift that cancel each other are not a change); a drift faster than the limit without a
    transient (by many reading steps) is ``"unsettled"``.
    A record shorter than :data:`MIN_WARMUP_RECORD_S` is ``"unknown"``.
    """
    t_s, temp_c = np.asarray(t_s, float), np.asarray(temp_c, float)
    ok = np.isfinite(t_s) & np.isfinite(temp_c)
    t_s, temp_c = t_s[ok], temp_c[ok]
    duration = float(t_s[-1] - t_s[0]) if len(t_s) else 0.0
    level = float(np.median(temp_c)) if len(temp_c) else math.nan
    t0 = float(t_s[0]) if len(t_s) else 0.0
    step = reading_step(temp_c) if step_c is None else float(step_c)
    if len(t_s) < 3 or duration < MIN_WARMUP_RECORD_S:
        return WarmupFit(math.nan, 0.0, math.inf, 0.0, level, t0, "unknown", 0.0, step, duration)
    idx = np.floor((t_s - t0) / WARMUP_BLOCK_S).astype(np.int64)
    cnt = np.bincount(idx)
    keep = cnt > 0
    u = (np.bincount(idx, weights=t_s - t0)[keep]) / cnt[keep]
    y = np.bincount(idx, weights=temp_c)[keep] / cnt[keep]
    span = float(u[-1] - u[0])
    if len(u) < 8 or span < 2 * MIN_WARMUP_TAU_S:  # readings bunched in a few blocks
        return WarmupFit(math.nan, 0.0, math.inf, 0.0, level, t0, "unknown", 0.0, step, duration)
    null = np.stack([np.ones_like(u), u / span], axis=1)
    coef0, *_ = np.linalg.lstsq(null, y, rcond=None)
    best = None
    taus = np.geomspace(MIN_WARMUP_TAU_S, span, 40)
    for tau in taus:
        X = np.column_stack([null, np.exp(-u / tau)])
        coef, res, rank, _ = np.linalg.lstsq(X, y, rcond=None)
        if rank < 3:
            continue
        rss = float(np.sum((y - X @ coef) ** 2))
        if best is None or rss < best[0]:
            best = (rss, tau, coef, X)
    drift0 = float(coef0[1]) / span * 3600.0
    none = WarmupFit(t0, 0.0, math.inf, drift0, float(coef0[0]), t0, "none", 0.0, step, duration)
    moved = drift0 * duration / 3600.0
    if abs(drift0) > max_rate_c_per_h and abs(moved) >= max(MIN_WARMUP_STEPS * step, MIN_WARMUP_C):
        # no transient to tell apart, but the temperature changes faster than the limit to the end (the
        # first minutes of a warm-up slower than the record, or a drifting room): nothing settled
        none = WarmupFit(t0 + duration, 0.0, math.inf, drift0, float(coef0[0]), t0, "unsettled", moved, step, duration)
    if best is None:
        return none
    rss, tau, coef, X = best
    if tau >= taus[-1]:  # at the grid's top: a slow curve, not told apart from the drift (a room swing)
        return none
    s2 = rss / max(len(u) - 4, 1)
    try:
        se = math.sqrt(max(float(s2 * np.linalg.inv(X.T @ X)[2, 2]), 0.0))
    except np.linalg.LinAlgError:  # transient indistinguishable from the drift: none
        return none
    amp = float(coef[2])
    if abs(amp) < max(WARMUP_SIGNIFICANCE * se, MIN_WARMUP_C):
        return none
    drift = float(coef[1]) / span * 3600.0
    fit = WarmupFit(t0, amp, float(tau), drift, float(coef[0]), t0, "none", 0.0, step, duration)
    # end: after it the smooth slope stays within the limit (the transient decays, the drift is constant)
    grid = np.linspace(0.0, duration, 2001)
    # a drift that moves the readings by fewer than MIN_WARMUP_STEPS over the whole record is not
    # resolved (one 0.5 K step late in a 40 min record reads as 1.3 K/h): it does not keep the record unsettled
    resolved = abs(drift) * duration / 3600.0 >= MIN_WARMUP_STEPS * step
    slope = (drift if resolved else 0.0) - amp / tau * np.exp(-grid / tau) * 3600.0
    fast = np.abs(slope) > max_rate_c_per_h
    if not fast.any():
        return none
    last = int(np.nonzero(fast)[0][-1])
    unsettled = last + 1 >= len(grid) or grid[last + 1] > duration - window_s
    end = duration if unsettled else float(grid[last + 1])
    curve = fit.smooth(t0 + np.array([0.0, end]))
    change = float(curve[1] - curve[0])
    if abs(change) < max(MIN_WARMUP_STEPS * step, MIN_WARMUP_C):
        return none  # a fitted curve that hardly moves the readings: not a temperature change
    state = "unsettled" if unsettled else "transient"
    return WarmupFit(t0 + end, amp, float(tau), drift, fit.level_c, t0, state, change, step, duration)


def detect_warmup(
    t_s: np.ndarray,
    temp_c: np.ndarray,
    *,
    window_s: float = 600.0,
    max_rate_c_per_h: float = 1.0,
    step_c: float | None = None,
) -> float:
    """End of the warm-up (s, on the readings' time axis) from :func:`fit_warmup`'s smooth fit.

    The first reading's time when there is no warm-up, the last reading's time when the record
    is still warming up at its end, NaN when the record is too short to tell
    (:attr:`WarmupFit.state` says which).
    """
    return fit_warmup(t_s, temp_c, window_s=window_s, max_rate_c_per_h=max_rate_c_per_h, step_c=step_c).end_s
