"""Autoregressive AR(p) models by least squares with SBC order selection; Gauss-Markov from AR(1).

Zhao, Horemuz and Sjoeberg (2011), "Stochastic modelling and analysis of IMU
sensor errors", sec. 2.1-2.2, after Neumaier and Schneider (2001, ARfit):

.. math::

    v_k = w + \\sum_{l=1}^p \\phi_l v_{k-l} + \\varepsilon_k   \\quad\\text{(eq. 1)}

with moment matrices ``U = sum u u^T``, ``V = sum v^2``, ``W = sum v u^T`` over
``u_k = (1, v_{k-1}, ..., v_{k-p})``: ``B = W U^-1`` (eq. 6), innovation
variance ``C = (V - W U^-1 W^T) / (N - n_p)`` (eq. 7), ``n_p = p + 1``.
The order minimises Schwarz's Bayesian criterion (eq. 4, m = 1)
``SBC(p) = log(RSS_p) - (1 - n_p/N) log N``, every order fitted on the same
``N`` samples (those after the first ``max_order``).

A first-order Gauss-Markov process ``x_k = e^{-beta dt} x_{k-1} + w_k``
(eq. 10) is an AR(1) with ``phi = e^{-beta dt}``: ``beta = -ln(phi)/dt``
(eq. 13), stationary variance ``sigma^2 = sigma_w^2 / (1 - phi^2)`` (eq. 11).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from imustation.errors import InputError


@dataclass(frozen=True)
class ARResult:
    """AR(p) fit of a series in (unit).

    ``phi`` (p,) coefficients, ``phi_stderr`` their standard errors, ``intercept``
    ``w`` (unit), ``sigma2`` innovation variance (unit^2), ``sbc`` the criterion for
    orders 0..max_order (the chosen ``order`` is its minimum unless fixed), ``n``
    the samples in the fit.
    """

    order: int
    phi: np.ndarray
    phi_stderr: np.ndarray
    intercept: float
    sigma2: float
    sbc: np.ndarray
    n: int


@dataclass(frozen=True)
class GaussMarkovFit:
    """First-order Gauss-Markov parameters estimated from an AR(1) fit (:func:`gauss_markov_from_ar1`):
    ``beta`` (1/s), correlation time ``T = 1/beta`` (s), stationary standard deviation ``sigma``
    and innovation standard deviation ``sigma_w`` (unit), with standard errors (delta method).
    The noise-model term of the same process is :class:`~.noise_models.GaussMarkov`."""

    beta: float
    T: float
    sigma: float
    sigma_w: float
    beta_stderr: float
    T_stderr: float


def _moments(v: np.ndarray, p_max: int) -> tuple[np.ndarray, np.ndarray, float, int]:
    """U (p_max+1, p_max+1), W (p_max+1,), V over k = p_max .. n-1 (lags by dot products, no lag matrix)."""
    n = len(v) - p_max
    cols = [np.ones(n)] + [v[p_max - l : len(v) - l] for l in range(1, p_max + 1)]
    target = v[p_max:]
    k = p_max + 1
    U = np.empty((k, k))
    for a in range(k):
        for b in range(a, k):
            U[a, b] = U[b, a] = n if a == b == 0 else float(np.dot(cols[a], cols[b]))
    W = np.array([float(np.dot(target, c)) for c in cols])
    return U, W, float(np.dot(target, target)), n


def fit_ar(series: np.ndarray, *, order: int | None = None, max_order: int = 10, scale: float = 1.0) -> ARResult:
    """Least-squares AR(p) fit; ``order=None`` selects p in 0..max_order by SBC.

    Parameters
    ----------
    series : (n,) samples (unit), or integer counts with ``scale`` (unit per count).
    order : fixed order, or None to choose by SBC.
    max_order : largest order considered (also how many initial samples are set aside).
    """
    v = np.asarray(series)
    if v.ndim != 1 or v.dtype.kind not in "iuf":
        raise InputError(f"series must be a one-dimensional numeric array, got {v.dtype} {v.shape}")
    p_max = max_order if order is None else int(order)
    if p_max < 0 or len(v) < 3 * (p_max + 2):
        raise InputError(f"AR order up to {p_max} needs at least {3 * (p_max + 2)} samples, got {len(v)}")
    v = v.astype(np.float64) * scale
    mean = float(v.mean())
    v = v - mean  # conditioning only: the intercept absorbs the mean
    U, W, V, n = _moments(v, p_max)
    orders = range(p_max + 1) if order is None else [p_max]
    sbc = np.full(p_max + 1, np.nan)
    fits = {}
    for p in orders:
        Up, Wp = U[: p + 1, : p + 1], W[: p + 1]
        B = np.linalg.solve(Up, Wp)  # eq. 6
        rss = V - float(Wp @ B)
        n_p = p + 1
        # eq. 4 with m = 1, l_p = log det (residual cross-product) = log RSS
        sbc[p] = math.log(rss) - (1.0 - n_p / n) * math.log(n)
        fits[p] = (B, rss, Up)
    p = int(np.nanargmin(sbc)) if order is None else p_max
    B, rss, Up = fits[p]
    sigma2 = rss / (n - (p + 1))  # eq. 7
    cov = sigma2 * np.linalg.inv(Up)
    phi = B[1:]
    intercept = float(B[0]) + mean * (1.0 - float(phi.sum()))
    return ARResult(p, phi, np.sqrt(np.diag(cov))[1:], intercept, float(sigma2), sbc, n)


def gauss_markov_from_ar1(ar: ARResult, fs_hz: float) -> GaussMarkovFit:
    """GM parameters from an AR(1) fit (Zhao et al. eqs. 11-13); ``fs_hz`` the sampling rate."""
    if ar.order != 1:
        raise InputError(f"Gauss-Markov parameters need an AR(1) fit, got order {ar.order}")
    phi = float(ar.phi[0])
    if not 0.0 < phi < 1.0:
        raise InputError(f"AR(1) coefficient {phi:.4g} is not in (0, 1): no Gauss-Markov process")
    dt = 1.0 / fs_hz
    beta = -math.log(phi) / dt  # eq. 13
    sigma = math.sqrt(ar.sigma2 / (1.0 - phi**2))  # eq. 11
    beta_se = float(ar.phi_stderr[0]) / (phi * dt)  # d beta / d phi = -1/(phi dt)
    return GaussMarkovFit(beta, 1.0 / beta, sigma, math.sqrt(ar.sigma2), beta_se, beta_se / beta**2)
