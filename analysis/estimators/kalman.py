"""General batched Kalman filter for the integrated noise models (ML_i likelihood, eq. 12-19).

State ``x = [term states..., Omega]`` (``Omega`` the angle since the start of the
current segment), transition and process noise from the closed-form
discretisation of :mod:`imustation.analysis.estimators.noise_models`, observation
``Y_i = Omega(t_i) + b_on X_i + n_i`` with ``X_i`` the time since the segment
start and ``n_i`` the white angle noise (variance ``R``, 0 without a ``wa`` term).

* **Batched**: K parameter points run at once; every step is a handful of numpy
  operations on ``(K, p, p)`` arrays, the loop runs over the m pattern points.
* **Diffuse turn-on bias**: de Jong's augmented filter: the regressor column
  ``X`` is filtered with the same gains; its innovations give the GLS estimate
  of ``b_on`` and the ``log S_uu`` term of the diffuse likelihood.
* **sigma_w profiled**: all variances are given relative to ``sigma_w^2``
  (``sigma_w = 1`` units), which then has a closed-form maximiser.
* **Gaps**: at the first interval of a segment the term states are predicted
  over the gap without an update and the angle restarts at 0 (its variance is
  the angle-noise variance ``R`` of the segment's first sample).

For the standard model the scalar prefix-scan filter of :mod:`.scan` gives the
same numbers much faster; the tests compare the two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imustation.analysis.estimators.noise_models import TermBlock, discretize_blocks


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


def kalman_profile(blocks: list[TermBlock], r_angle: np.ndarray, lay: Layout) -> Profile:
    """Run the diffuse filter for K parameter points.

    ``blocks``: the model's terms with ``q`` (variance relative to sigma_w^2) and
    ``tau`` as (K,) arrays (white rate: q = 1); ``r_angle`` (K,): white angle
    noise variance relative to sigma_w^2 (s).
    """
    K = len(r_angle)
    Phi, Qd = discretize_blocks(blocks, lay.dt[:, None])  # (M, K, p, p)
    M, _, p, _ = Phi.shape
    a = p - 1
    ns = p - 1
    R = np.asarray(r_angle, dtype=float)
    # stationary start for Gauss-Markov states, 0 for random walks (absorbed by b_on)
    P = np.zeros((K, p, p))
    j = 0
    for b in blocks:
        if b.code == "gm":
            P[:, j, j] = np.broadcast_to(b.q * b.tau / 2.0, (K,))
            j += 1
        elif b.code == "rw":
            j += 1
    gap_idx = np.flatnonzero(lay.new_segment & (lay.gap > 0))
    if len(gap_idx):
        Phi_g, Q_g = discretize_blocks(blocks, lay.gap[gap_idx][:, None])
    # data and regressor columns share the gains: one (K, p, 2) state array
    x = np.zeros((K, p, 2))
    nu = np.empty((M, K))
    u = np.empty((M, K))
    B = np.empty((M, K))
    obs = np.stack([lay.Y, lay.X], axis=1)  # (M, 2)
    PhiT = np.swapaxes(Phi, -1, -2)
    g = 0
    for i in range(M):
        if lay.new_segment[i]:
            if g < len(gap_idx) and gap_idx[g] == i:
                Pg, Qg = Phi_g[g][:, :ns, :ns], Q_g[g][:, :ns, :ns]
                x[:, :ns] = Pg @ x[:, :ns]
                P[:, :ns, :ns] = Pg @ P[:, :ns, :ns] @ np.swapaxes(Pg, -1, -2) + Qg
                g += 1
            x[:, a] = 0.0
            P[:, a, :] = 0.0
            P[:, :, a] = 0.0
            P[:, a, a] = R
        x = Phi[i] @ x
        P = Phi[i] @ P @ PhiT[i] + Qd[i]
        Bi = P[:, a, a] + R
        inn = obs[i] - x[:, a]  # (K, 2): data and regressor innovations
        G = P[:, :, a] / Bi[:, None]
        x += G[:, :, None] * inn[:, None, :]
        P -= G[:, :, None] * P[:, a, None, :]
        nu[i], u[i], B[i] = inn[:, 0], inn[:, 1], Bi
    s_ee = np.sum(nu * nu / B, axis=0)
    s_eu = np.sum(nu * u / B, axis=0)
    s_uu = np.sum(u * u / B, axis=0)
    b_on = s_eu / s_uu
    return Profile(s_ee - s_eu * b_on, np.sum(np.log(B), axis=0), np.log(s_uu), b_on, M)
