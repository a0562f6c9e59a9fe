"""Does the fitted noise model explain the measured Allan variance? A goodness-of-fit test across tau.

Given the measured overlapping Allan variance ``avar_j`` at cluster times
``tau_j`` (:func:`.allan.oadev`) and a fitted :class:`~.noise_models.NoiseModel`:

1. The model's exact sampled AVAR ``A_j`` (``adev_model = sqrt(A_j)``) and the
   covariance of the AVAR estimates under the model, ``V_jk``
   (:func:`.avar_cov.avar_covariance`: Greenhall and Riley's EDF double sum, for
   every pair of taus). ``edf_j = 2 A_j^2 / V_jj``.
2. Standardised residual per tau: ``z_j = Phi^-1(F_chi2(edf_j * avar_j / A_j; edf_j))``,
   the normal score of the measured value in its own (scaled chi-square)
   distribution — exact per tau, skewed at long tau handled.
3. The taus with at least :data:`MIN_EDF` degrees of freedom are thinned to
   about one per octave (neighbouring points of a 10-per-decade curve carry
   almost the same information); with ``R`` the correlation matrix of their
   estimates, ``T = z^T R^-1 z`` is the generalised chi-square (Mahalanobis)
   distance, referred to chi-square with as many degrees of freedom as taus
   less the noise parameters fitted to the record but one (a Gaussian-copula
   approximation of the correlated chi-squares).
4. A misfit confined to a few taus is diluted in ``T``, so the largest ``|z|``
   of the thinned taus is tested as well (Bonferroni over them). Each test runs
   at ``alpha / 2``; the reported ``p_value`` is ``min(1, 2 min(p_T, p_max))``
   and the verdict is "does not fit" when it is below ``alpha``.
5. Where: contiguous tau ranges (over all taus with enough EDF) whose ``|z|``
   exceeds ``band``, the per-tau limit of step 4; when only the global test
   rejects, the ranges where ``|z| > 2``.

The model's parameters were fitted to the same record, which makes the test
conservative (fitted curves pass closer to the data than the truth does);
docs/noise-model.md gives the measured false-alarm and detection rates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtri_exp
from scipy.stats import chi2, norm

from imustation.analysis.estimators.classical.allan import AllanResult
from imustation.analysis.estimators.classical.avar_cov import avar_covariance
from imustation.analysis.estimators.engine.fitting import MLiResult
from imustation.analysis.estimators.models.noise_models import NoiseModel
from imustation.errors import InputError

#: significance level of the verdict (a 31-channel lab that fits shows ~0.3 false "does not fit")
ALPHA = 0.01
#: taus with fewer equivalent degrees of freedom are shown but not tested (as the IEEE-952 fit)
MIN_EDF = 10.0
#: smallest ratio between consecutive taus of the global statistic
THIN_RATIO = 2.0
#: |z| that marks a broad misfit when only the global statistic rejects
BROAD_Z = 2.0
METHOD = "mahalanobis-avar"

FITS, NO_FIT, NOT_TESTED = "fits", "does not fit", "not tested"


@dataclass(frozen=True)
class Misfit:
    """A contiguous tau range (s) where the model misses the measured Allan variance.

    ``direction``: ``"model low"`` (measured above the model) or ``"model high"``;
    ``z`` the standardised residual of largest magnitude in the range.
    """

    tau_lo: float
    tau_hi: float
    direction: str
    z: float

    def as_dict(self) -> dict:
        return {"tau_lo": self.tau_lo, "tau_hi": self.tau_hi, "direction": self.direction, "z": self.z}

    def describe(self) -> str:
        where = f"{self.tau_lo:.3g} s" if self.tau_hi == self.tau_lo else f"{self.tau_lo:.3g}-{self.tau_hi:.3g} s"
        return f"{where} {self.direction}"


@dataclass(frozen=True)
class Adequacy:
    """Goodness of fit of a noise model to the measured Allan variance (see the module doc).

    ``adev_model``, ``z``, ``edf`` are given at every measured tau; ``tested``
    marks the taus of the global statistic ``statistic`` (chi-square with ``dof``).
    ``verdict`` is :data:`FITS`, :data:`NO_FIT` or :data:`NOT_TESTED` (with ``message``
    saying why).
    """

    verdict: str
    p_value: float
    statistic: float
    dof: int
    p_statistic: float
    p_max: float
    alpha: float
    band: float
    adev_model: np.ndarray
    z: np.ndarray
    edf: np.ndarray
    tested: np.ndarray
    misfit: tuple[Misfit, ...] = field(default_factory=tuple)
    message: str = ""
    method: str = METHOD

    @property
    def fits(self) -> bool:
        return self.verdict == FITS

    def summary(self) -> str:
        """One short line: the verdict and where the model misses."""
        if self.verdict == NOT_TESTED:
            return f"not tested ({self.message})"
        if self.verdict == FITS:
            return f"fits (p={self.p_value:.2g})"
        where = ", ".join(m.describe() for m in self.misfit)
        # a p of 1e-300 (or 0.0) says no more than 'far below any level': printed as such
        p = f"p={self.p_value:.1e}" if self.p_value >= 1e-4 else "p<1e-4"
        return f"does not fit ({p}){': ' + where if where else ''}"

    def as_dict(self) -> dict:
        """The ``adequacy`` block of the analysis JSON (docs/analysis-json.md)."""
        return {
            "verdict": self.verdict,
            "p_value": self.p_value,
            "alpha": self.alpha,
            "statistic": self.statistic,
            "dof": self.dof,
            "p_statistic": self.p_statistic,
            "p_max": self.p_max,
            "band": self.band,
            "z": self.z,
            "edf": self.edf,
            "tested": [bool(t) for t in self.tested],
            "misfit": [m.as_dict() for m in self.misfit],
            "method": self.method,
            "message": self.message,
        }


def normal_scores(ratio: np.ndarray, edf: np.ndarray) -> np.ndarray:
    """Normal score of ``edf * ratio`` in chi-square with ``edf`` degrees of freedom.

    Exact (from the log tail probabilities) where they are representable; further out
    the Wilson-Hilferty approximation, so a gross misfit gives a large finite score.
    """
    ratio = np.asarray(ratio, dtype=float)
    edf = np.asarray(edf, dtype=float)
    x = edf * ratio
    lower = x < edf  # below the mean: from the log cdf, else from the log survival function
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        z = np.where(lower, ndtri_exp(chi2.logcdf(x, edf)), -ndtri_exp(chi2.logsf(x, edf)))
        # beyond the reach of the log tails (|z| of hundreds): Wilson-Hilferty's cube-root normal
        v = 2.0 / (9.0 * edf)
        wh = (np.cbrt(np.maximum(ratio, 0.0)) - (1.0 - v)) / np.sqrt(v)
    z = np.where(np.isfinite(z), z, wh)
    return np.where(np.isfinite(x) & (edf > 0), z, np.nan)


def thin(tau: np.ndarray, ok: np.ndarray, ratio: float = THIN_RATIO) -> np.ndarray:
    """Indices of taus where ``ok``, from the shortest, each at least ``ratio`` times the previous one."""
    out: list[int] = []
    for i in np.nonzero(ok)[0]:
        if not out or tau[i] >= ratio * tau[out[-1]] * (1 - 1e-9):
            out.append(int(i))
    return np.asarray(out, dtype=int)


def _ranges(tau: np.ndarray, z: np.ndarray, flagged: np.ndarray) -> tuple[Misfit, ...]:
    """Contiguous runs of flagged taus with one sign of z."""
    out: list[Misfit] = []
    i = 0
    n = len(tau)
    while i < n:
        if not flagged[i]:
            i += 1
            continue
        sign = z[i] > 0
        j = i
        while j + 1 < n and flagged[j + 1] and (z[j + 1] > 0) == sign:
            j += 1
        k = i + int(np.argmax(np.abs(z[i : j + 1])))
        out.append(Misfit(float(tau[i]), float(tau[j]), "model low" if sign else "model high", float(z[k])))
        i = j + 1
    return tuple(out)


def model_adequacy(
    allan: AllanResult,
    model: NoiseModel,
    fs_hz: float,
    segment_lengths: Sequence[int],
    *,
    n_fitted: int = 0,
    alpha: float = ALPHA,
    tau_min: float = 0.0,
) -> Adequacy:
    """Test ``model`` against the measured overlapping Allan variance ``allan``.

    allan : the measured OADEV (:func:`.allan.oadev`) of the record the model was fitted to.
    model : the fitted noise model (SI units of the rate).
    fs_hz : sampling rate, Hz.
    segment_lengths : rate samples of each contiguous segment the Allan variance pooled.
    n_fitted : noise parameters fitted to this record (0 for a model given in advance);
        all but one take a degree of freedom from the global statistic (measured on
        fitted wn+gm records: the statistic's mean is ``taus - 1.8`` on 2 h and
        ``taus - 3.1`` on 12 h records; docs/noise-model.md).
    alpha : significance level of the verdict.
    tau_min : shortest cluster time tested, s (a device filter's memory: below it the
        model's low-pass term is an approximation, ``sensor_terms.LowPass``); shorter
        taus keep their ``z`` but are not tested.

    A model term without an angle covariance, or fewer than two testable taus,
    gives the verdict ``"not tested"`` with the reason in ``message``.
    """
    tau = np.asarray(allan.tau, dtype=float)
    m = np.round(tau * fs_hz).astype(np.int64)
    avar_model = np.asarray(model.avar(tau, fs_hz), dtype=float)
    adev_model = np.sqrt(avar_model)
    nan = np.full(len(tau), np.nan)

    def untested(why: str, edf=nan, z=nan) -> Adequacy:
        return Adequacy(NOT_TESTED, math.nan, math.nan, 0, math.nan, math.nan, alpha, math.nan, adev_model,
                        z, edf, np.zeros(len(tau), bool), (), why)  # fmt: skip

    try:
        var = avar_covariance(model, fs_hz, m, segment_lengths, diagonal=True)
    except InputError as exc:
        return untested(str(exc))
    with np.errstate(divide="ignore", invalid="ignore"):
        edf = np.where(var > 0, 2.0 * avar_model**2 / var, np.nan)
        ratio = np.asarray(allan.adev, dtype=float) ** 2 / avar_model
    z = normal_scores(ratio, edf)
    ok = np.isfinite(z) & (edf >= MIN_EDF) & (tau >= tau_min * (1.0 - 1e-9))
    idx = thin(tau, ok)
    if len(idx) < 2:
        return untested(f"fewer than two taus with {MIN_EDF:g} degrees of freedom", edf, z)
    cov = avar_covariance(model, fs_hz, m[idx], segment_lengths)
    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd)
    zt = z[idx]
    try:
        chol = np.linalg.cholesky(corr)
    except np.linalg.LinAlgError:
        return untested("the correlation matrix of the Allan variance estimates is singular", edf, z)
    w = np.linalg.solve(chol, zt)
    stat = float(w @ w)
    p = len(idx)
    dof = max(1, p - max(0, int(n_fitted) - 1))
    p_stat = float(chi2.sf(stat, dof))
    zmax = float(np.max(np.abs(zt)))
    p_max = float(min(1.0, p * 2.0 * norm.sf(zmax)))
    p_value = float(min(1.0, 2.0 * min(p_stat, p_max)))
    band = float(norm.isf(alpha / (4.0 * p)))
    verdict = NO_FIT if p_value < alpha else FITS
    misfit: tuple[Misfit, ...] = ()
    if verdict == NO_FIT:
        misfit = _ranges(tau, z, ok & (np.abs(z) > band))
        if not misfit:
            misfit = _ranges(tau, z, ok & (np.abs(z) > BROAD_Z))
    return Adequacy(verdict, p_value, stat, dof, p_stat, p_max, alpha, band, adev_model, z, edf,
                    np.isin(np.arange(len(tau)), idx), misfit)  # fmt: skip


def fit_adequacy(allan: AllanResult, fit: MLiResult, fs_hz: float, segment_lengths: Sequence[int]) -> Adequacy:
    """:func:`model_adequacy` of a fitted result: its noise parameters (all but ``b_on``) are the
    ones fitted, and its model holds from its device filter's memory on (``fit.memory_s``, s)."""
    n_fitted = sum(1 for k in fit.params if k != "b_on")
    return model_adequacy(allan, fit.noise_model, fs_hz, segment_lengths, n_fitted=n_fitted, tau_min=fit.memory_s)
