"""Attitude-error growth: the angle error a gyro's noise model predicts, against the data's spread.

A static gyro integrated from a known start angle, its turn-on bias removed,
accumulates the angle error ``theta(t) = int_0^t (v + b) dt'``. Its variance is
the angle entry of the integrated model's covariance, propagated exactly:
``P(t) = Phi(t) P0 Phi(t)^T + Qd(t)`` with ``Phi``, ``Qd`` the closed-form
transition and process noise of :meth:`NoiseModel.discretize` and ``P0`` the
start covariance — the Gauss-Markov states at their stationary variance
``sigma_b^2 tau_b / 2`` (bias unknown at the start, the default) or zero
(bias known, e.g. just calibrated); a random walk starts at 0 either way; white
angle noise adds ``2 sigma_a^2`` (both end points). Closed forms this
reproduces (tests): white + stationary GM
``sigma_w^2 t + sigma_b^2 tau_b^3 (t/tau_b - 1 + e^{-t/tau_b})``; white + RW
``sigma_w^2 t + sigma_k^2 t^3 / 3``.

:func:`angle_spread` measures the same on data: the standard deviation, over
many windows, of the integrated rate (mean removed) after each lag — the
empirical counterpart the paper reasons with around Fig. 14.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from imustation.analysis.estimators.models.noise_models import GaussMarkov, NoiseModel, WhiteAngle
from imustation.errors import InputError


def gm_mean_variance(sigma_b: float, tau_b: float, record_s: float) -> float:
    """Variance of the mean of a stationary Gauss-Markov bias over ``record_s`` seconds ((unit)^2).

    ``2 s^2 (tau_b/L)^2 (L/tau_b - 1 + e^{-L/tau_b})`` with ``s^2 = sigma_b^2 tau_b / 2``.
    """
    a = record_s / tau_b
    s2 = sigma_b**2 * tau_b / 2.0
    return 2.0 * s2 / a**2 * (a + math.expm1(-a)) if a > 1e-6 else s2 * (1.0 - a / 3.0)


def angle_error_std(
    model: NoiseModel, t_s: np.ndarray, bias_known: bool = False, record_s: float | None = None
) -> np.ndarray:
    """Predicted angle-error standard deviation (rad; m/s for accelerometers) after ``t_s`` (s).

    ``record_s``: the turn-on bias was estimated as the mean of a record this
    long (s), as :func:`angle_spread` does; the Gauss-Markov start variance is
    then the bias's variance about that mean, ``s^2 - Var(mean)`` (position in
    the record averaged out — an approximation, exact in the limits L << tau_b
    and L >> tau_b). Without it the start bias has its full stationary variance.
    """
    t = np.asarray(t_s, dtype=float)
    if np.any(t < 0):
        raise InputError("attitude-error times must be >= 0 s")
    Phi, Qd = model.discretize(t)
    P = Qd
    if not bias_known:
        p = Phi.shape[-1]
        P0 = np.zeros((p, p))
        j = 0
        for term in (c for t in model.terms for c in t.components()):  # a bias instability: its GM sum
            if term.n_states and term.state_space:
                if isinstance(term, GaussMarkov):
                    s2 = term.sigma_b**2 * term.tau_b / 2.0
                    if record_s is not None:
                        s2 -= gm_mean_variance(term.sigma_b, term.tau_b, record_s)
                    P0[j, j] = max(s2, 0.0)
                j += term.n_states
        P = Phi @ P0 @ np.swapaxes(Phi, -1, -2) + Qd
    var = P[..., -1, -1] + 2.0 * sum(tm.sigma_a**2 for tm in model.terms if isinstance(tm, WhiteAngle))
    return np.sqrt(np.where(t > 0, var, 0.0))


@dataclass(frozen=True)
class AngleSpread:
    """Empirical angle-error spread: ``std`` (rad) at lags ``t_s`` (s) over ``windows`` windows.

    ``std_lo``/``std_hi``: a 68 % interval for independent windows (chi-square with
    ``windows - 1`` degrees of freedom); overlapping windows make it optimistic.
    """

    t_s: np.ndarray
    std: np.ndarray
    std_lo: np.ndarray
    std_hi: np.ndarray
    windows: int


def angle_spread(
    rate: np.ndarray,
    fs_hz: float,
    lags_s: np.ndarray,
    *,
    scale: float = 1.0,
    stride_s: float | None = None,
    segment: tuple[int, int] | None = None,
) -> AngleSpread:
    """Std over windows of the integrated rate (its mean removed) after each lag.

    rate : rate samples (unit) or integer counts with ``scale`` (unit per count).
    fs_hz : sampling rate, Hz.
    lags_s : integration times, s (each at most the record length).
    stride_s : spacing of window starts (default: the longest lag, i.e. independent windows).
    segment : contiguous ``(start, stop)`` sample range to use (default: all).
    """
    from scipy.stats import chi2

    a, b = segment if segment is not None else (0, len(rate))
    x = np.asarray(rate[a:b], dtype=np.float64) * scale
    x -= x.mean()  # the turn-on bias, estimated over the whole record
    lags = np.maximum(1, np.round(np.asarray(lags_s, dtype=float) * fs_hz).astype(np.int64))
    L = int(lags.max())
    stride = L if stride_s is None else max(1, int(round(stride_s * fs_hz)))
    angle = np.concatenate([[0.0], np.cumsum(x) / fs_hz])
    starts = np.arange(0, len(x) - L + 1, stride)
    if len(starts) < 3:
        raise InputError(f"angle spread: {len(starts)} windows of {L / fs_hz:g} s fit the record; need at least 3")
    d = angle[starts[:, None] + lags[None, :]] - angle[starts[:, None]]
    std = d.std(axis=0, ddof=1)
    k = len(starts) - 1
    lo = std * math.sqrt(k / chi2.ppf(0.8415, k))
    hi = std * math.sqrt(k / chi2.ppf(0.1585, k))
    return AngleSpread(lags / fs_hz, std, lo, hi, len(starts))
