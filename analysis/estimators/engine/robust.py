"""Parameter covariance that survives model misfit: the sandwich estimator of ML_i-F.

The observed information ``H`` (the curvature of the negative log-likelihood) gives
honest intervals only when the model is the process that made the data. A real
sensor never is exactly (a flicker floor a sum of Gauss-Markov terms only
approximates, temperature drifts, a filter's shape below its memory), and its
repeated recordings then scatter more than ``H^-1`` says. The sandwich (White 1982,
"Maximum likelihood estimation of misspecified models", Econometrica 50(1))
``H^-1 J H^-1`` replaces the model's own information in the middle by the observed
variance ``J`` of the score:

* integrated likelihood: the score is a sum over the pattern intervals of the
  innovations' log-density derivatives (central differences in the physical
  log-parameters, b_on held at its estimate). Under the model they are
  uncorrelated; under misfit they are not, so ``J`` is their long-run variance,
  the Bartlett-weighted (Newey & West 1987, Econometrica 55(3)) sum of their
  autocovariances up to ``HAC_LAGS(M)`` intervals;
* fine-scale term: its score's variance ``G^T C^-1 G`` with ``G`` the derivative of the
  model's fine-scale Allan variances (the chi-square covariance ``C`` is the data's).

Under the model ``J ~ H`` and the sandwich equals ``H^-1``; the intervals the
estimators report take the wider of the two (docs/noise-model.md, "Intervals").
"""

from __future__ import annotations

import math

import numpy as np

from imustation.analysis.estimators.engine.newton import FD_STEP

_LOG2PI = math.log(2.0 * math.pi)


def hac_lags(m: int) -> int:
    """Autocovariance lags of the long-run score variance for ``m`` intervals: ``ceil(m^(1/3))``."""
    return max(1, math.ceil(m ** (1.0 / 3.0)))


def long_run_variance(scores: np.ndarray, lags: int) -> np.ndarray:
    """Bartlett-weighted long-run covariance (D, D) of the rows of ``scores`` (M, D) (Newey-West)."""
    S = scores - scores.mean(axis=0)
    J = S.T @ S
    for lag in range(1, min(lags, len(S) - 1) + 1):
        G = S[lag:].T @ S[:-lag]
        J += (1.0 - lag / (lags + 1.0)) * (G + G.T)
    return J


def interval_scores(problem, phi: np.ndarray, h: float = FD_STEP) -> np.ndarray:
    """Scores (M, D) of the integrated likelihood's per-interval terms at physical log-parameters ``phi``.

    ``problem``: a :class:`~.fitting.Problem` (or ML_i-F's); each interval's term is
    ``(log(2 pi s B_i) + (nu_i - u_i b_on)^2 / (s B_i)) / 2`` with ``s = sigma_w^2``.
    """
    D = len(phi)
    pts = np.repeat(phi[None, :], 2 * D, axis=0)
    for j in range(D):
        pts[2 * j, j] += h
        pts[2 * j + 1, j] -= h
    centre = problem.innovations(problem.spec.theta_of_phi(phi[None, :]))
    b_on = float(centre.profile().b_on[0])
    inn = problem.innovations(problem.spec.theta_of_phi(pts))
    s = np.exp(2.0 * pts[:, 0])[None, :]
    e = inn.nu - inn.u * b_on
    terms = 0.5 * (np.log(s * inn.B) + e * e / (s * inn.B) + _LOG2PI)  # (M, 2D)
    return (terms[:, 0::2] - terms[:, 1::2]) / (2.0 * h)


def fine_information(problem, phi: np.ndarray, h: float = FD_STEP) -> np.ndarray:
    """``G^T C^-1 G`` (D, D) of the fine-scale term of an ML_i-F problem at ``phi`` (0 without one)."""
    if not hasattr(problem, "unit_avar"):
        return np.zeros((len(phi), len(phi)))
    D = len(phi)
    pts = np.repeat(phi[None, :], 2 * D, axis=0)
    for j in range(D):
        pts[2 * j, j] += h
        pts[2 * j + 1, j] -= h
    model = np.exp(2.0 * pts[:, 0])[:, None] * problem.unit_avar(problem.spec.theta_of_phi(pts))  # (2D, J)
    G = ((model[0::2] - model[1::2]) / (2.0 * h)).T  # (J, D)
    return G.T @ problem.Cinv @ G


def sandwich(
    problem, phi: np.ndarray, H: np.ndarray, lags: int | None = None, free: list[int] | None = None
) -> np.ndarray:
    """Robust covariance ``H^-1 J H^-1`` of the physical log-parameters ``phi``.

    ``H``: the observed information at ``phi`` (D, D); ``lags``: autocovariance lags
    of the integrated score (default :func:`hac_lags` of the number of intervals);
    ``free``: the coordinates that vary (the others are held fixed: 0 in the result).
    NaN where ``H`` is not positive definite on them.
    """
    D = len(phi)
    idx = list(range(D)) if free is None else list(free)
    sub = np.ix_(idx, idx)
    out = np.zeros((D, D))
    try:
        if not np.all(np.linalg.eigvalsh(H[sub]) > 0):
            return np.full((D, D), np.nan)
        Hinv = np.linalg.inv(H[sub])
    except np.linalg.LinAlgError:
        return np.full((D, D), np.nan)
    scores = interval_scores(problem, phi)
    J = long_run_variance(scores, hac_lags(len(scores)) if lags is None else lags)
    J = J + fine_information(problem, phi)
    out[sub] = Hinv @ J[sub] @ Hinv
    return out
