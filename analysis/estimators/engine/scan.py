"""The standard model's diffuse filter as parallel prefix scans (ML_i's fast path).

For ``"wn+gm"`` observed without angle noise the state reduces to the scalar bias:
the Riccati recursion is a Moebius map with non-negative coefficients and the state
recursions are affine, so the filter runs as prefix products (O(log M) numpy
operations on ``(M, K)`` arrays, for K parameter points at once) instead of a loop
over the M pattern intervals. :func:`standard_profile` returns the same
:class:`~.kalman.Profile` as the general filter of :mod:`.kalman` (the tests check
both give the same likelihood); :func:`scan_moebius` and :func:`scan_affine` are
the two scans, shared with the rate filter of :mod:`.ml_rate`.
"""

from __future__ import annotations

import numpy as np

from imustation.analysis.estimators.engine.kalman import Innovations, Profile
from imustation.analysis.estimators.models.noise_models import f3


def scan_moebius(mats: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """Inclusive prefix products M_i ... M_1 of 2x2 matrices along axis 0.

    Entries are non-negative (no cancellation); each level is rescaled, which
    a projective (Moebius) map does not notice.
    """
    a, b, c, d = (x.copy() for x in mats)
    n = a.shape[0]
    s = 1
    while s < n:
        # new[i] = old[i] @ old[i-s] for i >= s
        a2 = a[s:] * a[:-s] + b[s:] * c[:-s]
        b2 = a[s:] * b[:-s] + b[s:] * d[:-s]
        c2 = c[s:] * a[:-s] + d[s:] * c[:-s]
        d2 = c[s:] * b[:-s] + d[s:] * d[:-s]
        norm = np.maximum(np.maximum(a2, d2), np.maximum(b2, c2))
        norm[norm == 0] = 1.0
        a[s:], b[s:], c[s:], d[s:] = a2 / norm, b2 / norm, c2 / norm, d2 / norm
        s *= 2
    return a, b, c, d


def scan_affine(g: np.ndarray, k: np.ndarray) -> np.ndarray:
    """x_i = g_i x_{i-1} + k_i with x_0 = 0, for all i, by prefix doubling."""
    g = g.copy()
    k = k.copy()
    n = g.shape[0]
    s = 1
    while s < n:
        k[s:] = g[s:] * k[:-s] + k[s:]
        g[s:] = g[s:] * g[:-s]
        s *= 2
    return k


def standard_profile(
    y: np.ndarray,
    dt: np.ndarray,
    r: np.ndarray,
    tau: np.ndarray,
    gap: np.ndarray | None = None,
) -> Profile:
    """Reduced diffuse filter of the standard model for K points ``(r_k, tau_k)`` at once
    (:func:`standard_innovations` summed)."""
    return standard_innovations(y, dt, r, tau, gap).profile()


def standard_innovations(
    y: np.ndarray,
    dt: np.ndarray,
    r: np.ndarray,
    tau: np.ndarray,
    gap: np.ndarray | None = None,
) -> Innovations:
    """Per-interval innovations of the reduced diffuse filter of the standard model, K points at once.

    ``y``, ``dt``: (M,) increments and interval lengths (s); ``r = sigma_b^2/sigma_w^2``
    and ``tau`` (s): (K,); ``gap`` (M,): unobserved time before each interval (s),
    over which the bias is predicted without an update.
    """
    a = dt[:, None] / tau[None, :]  # (M, K)
    e = np.exp(-a)
    c = -np.expm1(-a)
    T = tau[None, :]
    R = r[None, :]
    h = T * c
    q_bb = R * T * 0.5 * (-np.expm1(-2.0 * a))
    q_bo = R * T * T * 0.5 * c * c
    q_oo = dt[:, None] + R * T**3 * f3(a)
    p0 = r * tau * 0.5
    # Riccati p_i = (alpha p_{i-1} + beta) / (gamma p_{i-1} + delta) as Moebius maps
    alpha = e * e * q_oo + q_bb * h * h - 2.0 * e * h * q_bo
    beta = np.maximum(q_bb * q_oo - q_bo * q_bo, 0.0)
    gamma = h * h
    delta = q_oo
    if gap is not None and np.any(gap > 0):
        # prediction over the gap before the step: p -> eg^2 p + qg, composed into the map
        ag = gap[:, None] / T
        eg = np.exp(-ag)
        qg = R * T * 0.5 * (-np.expm1(-2.0 * ag))
        alpha, beta, gamma, delta = alpha * eg * eg, alpha * qg + beta, gamma * eg * eg, gamma * qg + delta
    else:
        eg = qg = None
    A, Bm, C, D = scan_moebius((alpha, beta, gamma, delta))
    p_post = (A * p0 + Bm) / (C * p0 + D)  # p after step i
    p_prev = np.vstack([p0[None, :], p_post[:-1]])  # p before step i
    gfac = e
    if eg is not None:
        p_prev = eg * eg * p_prev + qg
    B = h * h * p_prev + q_oo
    gain = (e * p_prev * h + q_bo) / B
    g = gfac - gain * h
    if eg is not None:
        g = g * eg
        hh = h * eg
    else:
        hh = h
    # data filter: bhat_i = g_i bhat_{i-1} + K_i y_i ; innovation y_i - h_i eg_i bhat_{i-1}
    bhat = scan_affine(g, gain * y[:, None])
    bprev = np.vstack([np.zeros_like(r)[None, :], bhat[:-1]])
    nu = y[:, None] - hh * bprev
    # regressor filter for the diffuse b_on (its effect on y_i is dt_i)
    uhat = scan_affine(g, gain * dt[:, None])
    uprev = np.vstack([np.zeros_like(r)[None, :], uhat[:-1]])
    u = dt[:, None] - hh * uprev
    return Innovations(nu, u, B)
