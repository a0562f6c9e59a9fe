"""IEEE Std 952-1997 Annex C coefficients from an Allan deviation curve.

The Allan variance of the standard terms adds up (IEEE 952 C.1; Zhao et al.
2011 eq. 22, Table 1; docs/reference/noise-formulas.md §5):

.. math::

    \\sigma^2(\\tau) = \\frac{3Q^2}{\\tau^2} + \\frac{N^2}{\\tau} + \\frac{2\\ln 2}{\\pi}B^2
                     + \\frac{K^2\\tau}{3} + \\frac{R^2\\tau^2}{2}

quantisation ``Q`` (unit*s, e.g. rad), angle/velocity random walk ``N``
(unit/sqrt(Hz)), bias instability ``B`` (unit; its flat floor), rate random walk
``K`` (unit/s/sqrt(Hz)), rate ramp ``R`` (unit/s). The model is linear in the
squared coefficients, so the terms are fitted together by non-negative weighted
least squares on the AVAR, weights ``edf/(2 model^2)`` (the chi-square variance
of each AVAR estimate), iterated with the weights taken from the fitted model;
terms the curve does not need are dropped by a Schwarz criterion over subsets
(counting one independent point per factor 4 in tau: neighbouring overlapping
Allan variances are correlated);
taus with fewer than 10 equivalent degrees of freedom are not fitted.
Each line's read-off (``N = sigma(1 s)`` on the -1/2 line, ``K = sigma(3 s)`` on
the +1/2 line, ``Q = sigma(sqrt 3)``, ``R = sigma(sqrt 2)``) is exactly its
coefficient in this model.

Also given, as IEEE 952 and Kalibr users read them off the measured curve:
``B_min`` = minimum ADEV / 0.664 at ``tau_B``, and the measured ADEV at
tau = 1 s and 3 s (log-log interpolation), each with a standard error from its EDF.

A device low-pass filter bends the curve below the white-noise line at the shortest
taus. Given the filter's memory ``tau_min`` (s; the model choice finds it,
:mod:`.finescale`), the fit uses the taus from there on only, where the filter adds
exactly ``-1.5 N^2 tau_lp / tau^2`` (:mod:`.sensor_terms`): a sixth column
``-3 / tau^2`` whose coefficient ``N^2 tau_lp / 2`` the fit reports as ``tau_lp`` (s),
exclusive with quantisation (same shape, other sign). Without it the filter's bend is
read as a Gauss-Markov term at the shortest correlation time and N comes out low.

Standard errors of the fitted coefficients come from the weighted least-squares
covariance treating the taus as independent; neighbouring overlapping-ADEV
points are correlated, so these are lower bounds (docs/allan-psd.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from imustation.analysis.estimators.classical.allan import AllanResult
from imustation.errors import InputError

B_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.6643: flat ADEV of flicker noise / B
TERMS = ("Q", "N", "B", "K", "R")
_IRLS_STEPS = 6
_MIN_EDF_FLOOR = 10.0
#: taus whose AVAR has fewer degrees of freedom are left out of the fit
_MIN_EDF = 10.0
#: correlation times tried for the Gauss-Markov term (log grid over the fitted taus)
_GM_GRID = 16


@dataclass(frozen=True)
class IEEECoefficients:
    """IEEE-952 coefficients and read-offs, SI units of the channel (see module docstring).

    ``*_stderr`` are standard errors (NaN where a term was fitted as zero or
    the reading is outside the curve); ``tau_B`` (s) is where the ADEV is minimal;
    ``gm_sigma`` (unit) and ``gm_T`` (s) describe a correlated (Gauss-Markov)
    term when the curve needs one (Zhao et al. Table 1 "correlated noise").
    """

    N: float
    B: float
    K: float
    tau_B: float
    Q: float = math.nan
    R: float = math.nan
    N_stderr: float = math.nan
    B_stderr: float = math.nan
    K_stderr: float = math.nan
    Q_stderr: float = math.nan
    R_stderr: float = math.nan
    gm_sigma: float = math.nan
    gm_sigma_stderr: float = math.nan
    gm_T: float = math.nan
    B_min: float = math.nan
    B_min_stderr: float = math.nan
    adev_1s: float = math.nan
    adev_1s_stderr: float = math.nan
    adev_3s: float = math.nan
    adev_3s_stderr: float = math.nan
    #: device filter: equivalent time constant (s) when fitted; the shortest tau fitted (s)
    tau_lp: float = math.nan
    tau_min: float = math.nan

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _basis(tau: np.ndarray) -> np.ndarray:
    """Columns of the AVAR model for (Q^2, N^2, B^2, K^2, R^2)."""
    return np.column_stack([3.0 / tau**2, 1.0 / tau, np.full(len(tau), B_FACTOR**2), tau / 3.0, tau**2 / 2.0])


def _irls(A: np.ndarray, avar: np.ndarray, edf: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Non-negative IRLS fit of ``avar ~ A theta``; returns theta, final weights, chi-square."""
    model = avar.copy()
    theta = np.zeros(A.shape[1])
    for _ in range(_IRLS_STEPS):
        w = np.sqrt(edf / 2.0) / model  # 1/sd of each AVAR estimate (chi-square with edf dof)
        theta, _ = nnls(A * w[:, None], avar * w)
        model = np.maximum(A @ theta, 1e-6 * avar)  # a filter deficit can take the model to 0
    w = np.sqrt(edf / 2.0) / model
    return theta, w, float(np.sum((w * (avar - model)) ** 2))


def gm_avar(tau: np.ndarray, T: float) -> np.ndarray:
    """AVAR of a first-order Gauss-Markov rate with q_c = 1 and correlation time ``T`` (s).

    (q_c T^2/tau) [1 - (T/2tau)(3 - 4 e^{-tau/T} + e^{-2tau/T})] (IEEE 952 Table B.1;
    docs/reference/noise-formulas.md §5); stationary variance s^2 = q_c T / 2.
    """
    a = tau / T
    bracket = np.where(
        a > 1e-3, 1.0 - (3.0 - 4.0 * np.exp(-a) + np.exp(-2.0 * a)) / (2.0 * np.maximum(a, 1e-3)), a / 3.0 - a**2 / 4.0
    )
    return T**2 / tau * bracket


def fit_terms(res: AllanResult, tau_min: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Squared coefficients (Q^2, N^2, B^2, K^2, R^2, q_c, c_lp) with standard errors, and the GM time T.

    Every subset of the five IEEE terms, with and without a Gauss-Markov term
    (correlation time on a log grid over the fitted taus), is fitted; the one
    with the smallest Schwarz criterion ``chi2 n_eff / n_tau + k ln(n_eff)`` (``n_eff``
    one point per factor 4 in tau) is kept, so a
    term the curve does not need stays 0 and a correlated-noise bump is not
    mistaken for a bias-instability floor. ``T`` is NaN without a GM term.
    ``tau_min`` (s) > 0: a device filter's memory; taus below it are left out and
    the filter's deficit ``c_lp`` (coefficient of ``-3/tau^2``) joins the subsets.
    """
    tau, avar = res.tau, res.adev**2
    edf = np.where(np.isfinite(res.edf) & (res.edf > 0), res.edf, 1.0)
    # points with few degrees of freedom (the last ~decade of a record) only add
    # realisation scatter that a ramp or a spurious floor would chase
    ok = (avar > 0) & (edf >= _MIN_EDF) & (tau >= tau_min * (1.0 - 1e-9))
    if np.count_nonzero(ok) < 3:
        ok = (avar > 0) & (tau >= tau_min * (1.0 - 1e-9))
    if np.count_nonzero(ok) < 3:
        ok = avar > 0
    tau, avar, edf = tau[ok], avar[ok], edf[ok]
    if len(tau) < 2:
        raise InputError(
            "the Allan variance is zero or undefined at every tau (a constant or non-finite signal): nothing to fit"
        )
    A = np.column_stack([_basis(tau), -3.0 / tau**2])
    n_terms = 6 if tau_min > 0 else 5
    grid = [math.nan] + list(np.logspace(np.log10(tau[0]), np.log10(tau[-1]), _GM_GRID))
    # neighbouring overlapping Allan variances are strongly correlated: the criterion counts
    # one independent point per factor 4 in tau, scaling chi2 to that many (a chi2 over all
    # the correlated points adds spurious terms, e.g. a Gauss-Markov term to white noise)
    n_eff = max(2.0, math.log(tau[-1] / tau[0]) / math.log(4.0) + 1.0)
    shrink = min(1.0, n_eff / len(tau))
    best = None
    for T in grid:
        G = A if math.isnan(T) else np.column_stack([A, gm_avar(tau, T)])
        for mask in range(1, 1 << n_terms):
            if mask & 1 and mask >> 5 & 1:
                continue  # quantisation and the filter deficit: one angle term
            cols = [j for j in range(n_terms) if mask >> j & 1] + ([] if math.isnan(T) else [6])
            try:
                theta_s, w, chi2 = _irls(G[:, cols], avar, edf)
            except RuntimeError:  # scipy's nnls gave up (e.g. a pure ramp's exact tau^2 curve): not a candidate
                continue
            k = int(np.count_nonzero(theta_s)) + (0 if math.isnan(T) else 1)  # T is a parameter too
            crit = chi2 * shrink + k * math.log(n_eff)
            if best is None or crit < best[0] - 1e-9:
                theta = np.zeros(7)
                theta[cols] = theta_s
                best = (crit, theta, w, T, G)
    if best is None:
        raise InputError("the IEEE-952 fit found no solution for any set of terms (non-negative least squares failed)")
    _, theta, w, T, G = best
    active = theta[: G.shape[1]] > 0
    se = np.full(7, np.nan)
    if active.any():
        Aw = G[:, active] * w[:, None]
        cov = np.linalg.pinv(Aw.T @ Aw)
        se[np.flatnonzero(active)] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    # report in the order (Q^2, N^2, B^2, K^2, R^2, q_c, c_lp)
    order = [0, 1, 2, 3, 4, 6, 5]
    return theta[order], se[order], (T if theta[6] > 0 else math.nan)


def _reading(res: AllanResult, tau: float) -> tuple[float, float]:
    """Measured ADEV at ``tau`` (log-log interpolation) and its standard error ``adev/sqrt(2 edf)``."""
    if len(res.tau) < 2 or tau < res.tau[0] or tau > res.tau[-1]:
        return math.nan, math.nan
    lt = np.log(res.tau)
    adev = float(np.exp(np.interp(math.log(tau), lt, np.log(res.adev))))
    edf = float(np.exp(np.interp(math.log(tau), lt, np.log(np.maximum(res.edf, 1e-300)))))
    return adev, adev / math.sqrt(2.0 * edf) if np.isfinite(edf) and edf > 0 else math.nan


def ieee_coefficients(res: AllanResult, tau_min: float = 0.0) -> IEEECoefficients:
    """Fit Q, N, B, K, R (+ a Gauss-Markov term) to an Allan deviation curve; read B_min, ADEV(1 s), ADEV(3 s).

    ``tau_min`` (s): a device filter's memory (module docstring); 0 fits every tau.
    """
    theta, se_all, T = fit_terms(res, tau_min)
    coef = np.sqrt(theta[:5])
    with np.errstate(divide="ignore", invalid="ignore"):
        se = np.where(coef > 0, se_all[:5] / (2.0 * coef), np.nan)  # delta method: se(c) = se(c^2) / (2c)
    # GM: stationary sigma = sqrt(q_c T / 2); se by the delta method at fixed T
    gm_sigma = math.sqrt(theta[5] * T / 2.0) if theta[5] > 0 else math.nan
    gm_sigma_se = se_all[5] * T / 4.0 / gm_sigma if theta[5] > 0 else math.nan
    # the floor is read where the estimate is usable (edf >= _MIN_EDF_FLOOR), not in the last noisy points
    usable = np.flatnonzero(~(res.edf < _MIN_EDF_FLOOR))
    i_min = int(usable[np.argmin(res.adev[usable])]) if len(usable) else int(np.argmin(res.adev))
    edf_min = float(res.edf[i_min]) if np.isfinite(res.edf[i_min]) else math.nan
    b_min = float(res.adev[i_min] / B_FACTOR)
    a1, a1_se = _reading(res, 1.0)
    a3, a3_se = _reading(res, 3.0)
    c = dict(zip(TERMS, coef.tolist(), strict=True))
    s = dict(zip(TERMS, se.tolist(), strict=True))
    return IEEECoefficients(
        N=c["N"],
        B=c["B"],
        K=c["K"],
        tau_B=float(res.tau[i_min]),
        Q=c["Q"],
        R=c["R"],
        N_stderr=s["N"],
        B_stderr=s["B"],
        K_stderr=s["K"],
        Q_stderr=s["Q"],
        R_stderr=s["R"],
        gm_sigma=gm_sigma,
        gm_sigma_stderr=gm_sigma_se,
        gm_T=T,
        B_min=b_min,
        B_min_stderr=b_min / math.sqrt(2.0 * edf_min) if edf_min > 0 else math.nan,
        adev_1s=a1,
        adev_1s_stderr=a1_se,
        adev_3s=a3,
        adev_3s_stderr=a3_se,
        tau_lp=2.0 * theta[6] / theta[1] if theta[6] > 0 and theta[1] > 0 else math.nan,
        tau_min=float(tau_min) if tau_min > 0 else math.nan,
    )
