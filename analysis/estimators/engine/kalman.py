"""General diffuse Kalman filter for the integrated noise models (ML_i likelihood, eq. 12-19).

State ``x = [term states..., Omega]`` (``Omega`` the angle since the start of the
current segment), transition and process noise from the closed-form
discretisation of :mod:`imustation.analysis.estimators.models.noise_models`, observation
``Y_i = Omega(t_i) + b_on X_i + n_i`` with ``X_i`` the time since the segment
start and ``n_i`` the angle noise of variance ``R`` (white angle noise; negative
for a device low-pass filter, see :mod:`.sensor_terms`).

* **Compiled** (numba): one loop over the pattern points and the K parameter
  points. The transition is diagonal in the term states plus the angle row, and
  the process noise is an "arrow" (no cross terms between independent terms), so
  the prediction costs O(p^2) instead of the O(p^3) of dense matrix products:
  models with a dozen states (bias instability as a sum of Gauss-Markov terms)
  cost little more than the standard model.
* **Diffuse turn-on bias**: de Jong's augmented filter: the regressor column
  ``X`` is filtered with the same gains; its innovations give the GLS estimate
  of ``b_on`` and the ``log S_uu`` term of the diffuse likelihood.
* **sigma_w profiled**: all variances are given relative to ``sigma_w^2``
  (``sigma_w = 1`` units), which then has a closed-form maximiser.
* **Gaps**: at the first interval of a segment the term states are predicted
  over the gap without an update and the angle restarts at 0 (its variance is
  the angle-noise variance ``R`` of the segment's first sample).

For the standard model the scalar prefix-scan filter of :mod:`.scan` gives the
same numbers; the tests compare the two and both with dense Gaussian likelihoods.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from imustation.analysis.estimators.models.noise_models import F3_COEF, TermBlock


@dataclass
class Profile:
    """Concentrated likelihood pieces for K parameter points (arrays of shape (K,)), sigma_w = 1 units."""

    s_tilde: np.ndarray  # residual sum of squares after the GLS b_on
    logdet: np.ndarray  # sum log B_i
    log_suu: np.ndarray  # log S_uu (diffuse term)
    b_on: np.ndarray
    m: int


@dataclass(frozen=True)
class Layout:
    """Pattern data in the filter's form (all arrays (M,))."""

    Y: np.ndarray  # angle since segment start at each pattern point, (unit) s
    X: np.ndarray  # time since segment start, s  (regressor of b_on)
    dt: np.ndarray  # interval lengths, s
    new_segment: np.ndarray  # bool: interval i opens a segment
    gap: np.ndarray  # s: unobserved time before interval i (0 unless a gap precedes it)

    @staticmethod
    def from_increments(y: np.ndarray, dt: np.ndarray, new_segment: np.ndarray, gap: np.ndarray) -> Layout:
        Y = _segment_cumsum(y, new_segment)
        X = _segment_cumsum(dt, new_segment)
        return Layout(Y, X, dt, new_segment, gap)


def _segment_cumsum(v: np.ndarray, new_segment: np.ndarray) -> np.ndarray:
    """Cumulative sum of ``v`` restarting at every ``new_segment``."""
    c = np.cumsum(v)
    starts = np.flatnonzero(new_segment)
    base = c[starts] - v[starts]
    return c - base[np.cumsum(new_segment) - 1]


@dataclass(frozen=True)
class Innovations:
    """Per-interval innovations of the data (``nu``) and regressor (``u``) columns and their
    variances ``B`` (sigma_w = 1 units), arrays (M, K)."""

    nu: np.ndarray
    u: np.ndarray
    B: np.ndarray

    def profile(self) -> Profile:
        s_ee = np.sum(self.nu * self.nu / self.B, axis=0)
        s_eu = np.sum(self.nu * self.u / self.B, axis=0)
        s_uu = np.sum(self.u * self.u / self.B, axis=0)
        b_on = s_eu / s_uu
        return Profile(s_ee - s_eu * b_on, np.sum(np.log(self.B), axis=0), np.log(s_uu), b_on, self.B.shape[0])


_GM, _RW = 0, 1


@nb.njit(cache=True)
def _f3(a):
    # a - c - c^2/2 with c = 1 - e^-a, series below 0.1 (noise_models.f3)
    if a >= 0.1:
        c = -math.expm1(-a)
        return a - c - 0.5 * c * c
    acc = F3_COEF[-1]
    for i in range(len(F3_COEF) - 2, -1, -1):
        acc = acc * a + F3_COEF[i]
    return acc * a**3


@nb.njit(cache=True)
def _transition(kind, q, tau, dt, phi, c, qbb, qbo):
    """Per-term Phi_bb, Phi_Ob, Q_bb, Q_bO over ``dt``; returns the terms' Q_OO sum."""
    qoo = 0.0
    for j in range(len(kind)):
        if kind[j] == _GM:
            T = tau[j]
            a = dt / T
            cc = -math.expm1(-a)
            phi[j] = math.exp(-a)
            c[j] = T * cc
            qbb[j] = q[j] * T * 0.5 * -math.expm1(-2.0 * a)
            qbo[j] = q[j] * T * T * 0.5 * cc * cc
            qoo += q[j] * T**3 * _f3(a)
        else:
            phi[j] = 1.0
            c[j] = dt
            qbb[j] = q[j] * dt
            qbo[j] = q[j] * dt * dt / 2.0
            qoo += q[j] * dt**3 / 3.0
    return qoo


@nb.njit(cache=True)
def _filter(Y, X, dt, new_segment, gap, kind, q, tau, q_wn, R, nu, u, B):
    M = len(Y)
    K, s = q.shape
    a = s  # index of the angle
    P = np.zeros((s + 1, s + 1))
    x = np.zeros((s + 1, 2))
    phi = np.empty(s)
    c = np.empty(s)
    qbb = np.empty(s)
    qbo = np.empty(s)
    v = np.empty(s)
    w = np.empty(s + 1)
    for k in range(K):
        last_dt = -1.0  # the transition is recomputed only when the interval length changes
        qoo = 0.0
        P[:, :] = 0.0
        x[:, :] = 0.0
        for j in range(s):
            if kind[j] == _GM:
                P[j, j] = q[k, j] * tau[k, j] / 2.0  # stationary start; random walks start at 0
        for i in range(M):
            if new_segment[i]:
                if gap[i] > 0.0:  # predict the term states over the gap, no update
                    _transition(kind, q[k], tau[k], gap[i], phi, c, qbb, qbo)
                    last_dt = -1.0
                    for j in range(s):
                        x[j, 0] *= phi[j]
                        x[j, 1] *= phi[j]
                        for l in range(s):
                            P[j, l] *= phi[j] * phi[l]
                        P[j, j] += qbb[j]
                for j in range(s + 1):
                    P[a, j] = 0.0
                    P[j, a] = 0.0
                x[a, 0] = 0.0
                x[a, 1] = 0.0
                P[a, a] = R[k]
            if dt[i] != last_dt:  # uniform patterns: once per parameter point
                qoo = _transition(kind, q[k], tau[k], dt[i], phi, c, qbb, qbo) + q_wn[k] * dt[i]
                last_dt = dt[i]
            # prediction with Phi = [[diag(phi), 0], [c^T, 1]] and the arrow-shaped Qd
            pa = P[a, a]
            for j in range(s):
                acc = 0.0
                for l in range(s):
                    acc += c[l] * P[j, l]
                v[j] = acc
            cross = 0.0
            quad = 0.0
            for j in range(s):
                cross += c[j] * P[j, a]
                quad += c[j] * v[j]
            for j in range(s):
                P[j, a] = phi[j] * (P[j, a] + v[j]) + qbo[j]
                P[a, j] = P[j, a]
                for l in range(s):
                    P[j, l] *= phi[j] * phi[l]
                P[j, j] += qbb[j]
            P[a, a] = pa + 2.0 * cross + quad + qoo
            for col in range(2):
                acc = x[a, col]
                for j in range(s):
                    acc += c[j] * x[j, col]
                    x[j, col] *= phi[j]
                x[a, col] = acc
            # update with the angle observed (plus angle noise R)
            Bi = P[a, a] + R[k]
            e0 = Y[i] - x[a, 0]
            e1 = X[i] - x[a, 1]
            for j in range(s + 1):
                w[j] = P[j, a]
            for j in range(s + 1):
                g = w[j] / Bi
                x[j, 0] += g * e0
                x[j, 1] += g * e1
                for l in range(s + 1):
                    P[j, l] -= g * w[l]
            nu[i, k] = e0
            u[i, k] = e1
            B[i, k] = Bi


def kalman_innovations(blocks: list[TermBlock], r_angle: np.ndarray, lay: Layout) -> Innovations:
    """Run the diffuse filter for K parameter points; per-interval innovations.

    ``blocks``: the model's terms with ``q`` (variance relative to sigma_w^2) and
    ``tau`` (s) as scalars or (K,) arrays (white rate ``"wn"`` blocks add their q;
    ``"gm"`` and ``"rw"`` blocks are states); ``r_angle`` (K,): angle-noise variance
    relative to sigma_w^2 (s; negative for a device filter's angle deficit).
    """
    R = np.asarray(r_angle, dtype=float).ravel()
    K = len(R)
    states = [b for b in blocks if b.code in ("gm", "rw")]
    s = len(states)
    q = np.empty((K, s))
    tau = np.ones((K, s))
    for j, b in enumerate(states):
        q[:, j] = np.broadcast_to(np.asarray(b.q, dtype=float), (K,))
        if b.code == "gm":
            tau[:, j] = np.broadcast_to(np.asarray(b.tau, dtype=float), (K,))
    kind = np.array([_GM if b.code == "gm" else _RW for b in states], dtype=np.int64)
    q_wn = np.zeros(K)
    for b in blocks:
        if b.code == "wn":
            q_wn += np.broadcast_to(np.asarray(b.q, dtype=float), (K,))
    M = len(lay.Y)
    nu, u, B = np.empty((M, K)), np.empty((M, K)), np.empty((M, K))
    _filter(
        np.ascontiguousarray(lay.Y, dtype=float),
        np.ascontiguousarray(lay.X, dtype=float),
        np.ascontiguousarray(lay.dt, dtype=float),
        np.ascontiguousarray(lay.new_segment, dtype=np.bool_),
        np.ascontiguousarray(lay.gap, dtype=float),
        kind, q, tau, q_wn, R, nu, u, B,
    )  # fmt: skip
    return Innovations(nu, u, B)


def kalman_profile(blocks: list[TermBlock], r_angle: np.ndarray, lay: Layout) -> Profile:
    """:func:`kalman_innovations` summed into the concentrated likelihood pieces."""
    return kalman_innovations(blocks, r_angle, lay).profile()
