"""Covariance of overlapping Allan-variance estimates across cluster times, under a noise model.

The overlapping AVAR at ``tau = m dt`` averages ``M = N - 2m`` squared second
differences of the angle ``x`` (``N`` angle points per segment, pooled over
segments; :func:`.allan.oadev`)::

    avar_m = sum_i d_i^2 / (2 tau^2 M),    d_i = x_{i+2m} - 2 x_{i+m} + x_i.

For a Gaussian process the fourth moments reduce to second ones (Isserlis), so
for two cluster sizes ``m_j``, ``m_k``

    Cov(avar_j, avar_k) = 2 sum_{i,l} C_jk(l - i)^2 / (4 tau_j^2 tau_k^2 M_j M_k),
    C_jk(h) = Cov(d_i^(j), d_{i+h}^(k)) = sum_{p,q} a_p b_q K(h + s_q - s_p),

with weights ``(1, -2, 1)`` at offsets ``s = (0, m, 2m)`` and ``K`` the generalised
covariance of the angle (defined up to polynomials of degree <= 1 in the lag,
which the second differences annihilate). For ``j = k`` this is the
double sum Greenhall and Riley use for the EDF of the overlapping AVAR
("Uncertainty of stability variances based on finite differences", 35th PTTI,
2003, eq. 8 ff.); here it is evaluated for every pair of taus, which gives the
correlation of neighbouring points of an Allan curve that the usual
per-point intervals ignore (docs/noise-model.md, "Model adequacy").

``K`` of the sampled process (lag ``s`` in samples, ``dt = 1/fs``), term by term:

* white rate, PSD ``sigma_w^2``: ``-sigma_w^2 dt |s| / 2``;
* rate random walk ``sigma_k``: ``sigma_k^2 dt^3 (|s|^3 - |s|) / 12``;
* white angle / quantisation ``sigma_a``: ``sigma_a^2`` at ``s = 0`` only;
* Gauss-Markov (sampled AR(1), ``phi = e^-d``, ``d = dt/tau_b``, variance
  ``v = sigma_b^2 tau_b / 2``): ``-(v dt^2 / 2) [|s| + 2 phi (E(|s| d) - |s| E(d)) / (1 - phi)^2]``
  with ``E(x) = x + e^-x - 1``; the even polynomial part is dropped where the
  exponential is slow (it cancels, and would cost digits).

Each term's K reproduces the term's exact sampled AVAR
(``AVAR = (6 K(0) - 8 K(m) + 2 K(2m)) / (2 tau^2)``, tested).

Evaluation: ``C_jk(h)`` vanishes for the polynomial terms outside the core
``-2 m_k <= h <= 2 m_j`` (``m_j <= m_k``); the Gauss-Markov part outside it is a
sum of exponentials, summed in closed form against the (piecewise linear) count
of index pairs. Inside the core the summand is smooth between the kinks
``h = s_p - s_q`` and the ends of the segments; the sum over each smooth piece is
exact over its first and last :data:`EXACT_EDGE` integers and a midpoint-rule
integral (Gauss-Legendre on sub-intervals doubling away from both ends) in
between. Cost: a few thousand evaluations per pair of taus whatever the record length.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np

from imustation.analysis.estimators.models.noise_models import (
    GaussMarkov,
    NoiseModel,
    RandomWalk,
    WhiteAngle,
    WhiteRate,
)
from imustation.errors import InputError

#: integers summed exactly at each end of a smooth piece of the lag sum
EXACT_EDGE = 16
#: Gauss-Legendre nodes per graded sub-interval
GL_NODES = 6
_GL_X, _GL_W = np.polynomial.legendre.leggauss(GL_NODES)
#: doubling levels of the graded sub-intervals (EXACT_EDGE * 2^40 exceeds any record)
_LEVELS = 40


@dataclass(frozen=True)
class AngleKernel:
    """Generalised covariance of the sampled angle of a noise model ((rate unit * s)^2, lag in samples).

    ``lin``: coefficient of ``|s|``; ``cub``: of ``|s|^3 - |s|``; ``delta``: value at
    ``s = 0`` only; Gauss-Markov terms: ``gm_v`` their ``v dt^2`` ((unit s)^2), ``gm_d``
    ``dt/tau_b``.
    """

    lin: float
    cub: float
    delta: float
    gm_v: np.ndarray
    gm_d: np.ndarray

    @staticmethod
    def of(model: NoiseModel, fs_hz: float) -> AngleKernel:
        """The kernel of ``model`` sampled at ``fs_hz``; :class:`InputError` for a term it cannot express."""
        dt = 1.0 / float(fs_hz)
        lin = cub = delta = 0.0
        v, d = [], []
        # a bias instability is its fixed Gauss-Markov sum; a device filter beyond its memory is
        # (negative) white angle noise (analysis/estimators/models/sensor_terms.py)
        for t in (c for term in model.terms for c in term.components()):
            if isinstance(t, WhiteRate):
                lin -= t.sigma_w**2 * dt / 2.0
            elif isinstance(t, GaussMarkov):
                v.append(t.sigma_b**2 * t.tau_b / 2.0 * dt * dt)
                d.append(dt / t.tau_b)
            elif isinstance(t, RandomWalk):
                cub += t.sigma_k**2 * dt**3 / 12.0
            elif isinstance(t, WhiteAngle):  # also Quantization: the same second-order statistics
                delta += t.sigma_a**2
            elif t.code == "lp":
                delta += t.angle_variance()  # valid beyond the filter's memory only: test from there on
            else:
                raise InputError(f"no angle covariance for the {type(t).__name__} term: adequacy not computed")
        return AngleKernel(lin, cub, delta, np.asarray(v, float), np.asarray(d, float))

    def constants(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per Gauss-Markov term: ``|s|`` coefficient of the slow form, of the fast form, exponential coefficient."""
        d = self.gm_d
        phi = np.exp(-d)
        om = -np.expm1(-d)
        sinh_minus = np.array([_sinh_minus(float(x)) for x in d])
        return 2.0 * phi * sinh_minus / om**2, 1.0 + 2.0 * phi / om, 2.0 * phi / om**2

    def evaluate(self, s: np.ndarray, slow: np.ndarray) -> np.ndarray:
        """K at lags ``s`` (samples, 1-d). ``slow`` (n_gm, len(s)): per Gauss-Markov term and lag,
        use the form without the even polynomial (right where ``d * lag <= 1``: there that
        polynomial dominates and would cost digits)."""
        s = np.ascontiguousarray(s, dtype=float)
        ls, lf, ec = self.constants()
        out = np.empty(len(s))
        _kernel_values(s, np.ascontiguousarray(slow, dtype=np.bool_), self.lin, self.cub, self.delta,
                       self.gm_v, self.gm_d, ls, lf, ec, out)  # fmt: skip
        return out

    def avar(self, m: np.ndarray, fs_hz: float) -> np.ndarray:
        """Allan variance at cluster sizes ``m`` (samples) from the kernel: ``(6K(0) - 8K(m) + 2K(2m)) / (2 tau^2)``."""
        m = np.asarray(m, dtype=float)
        s = np.concatenate([np.zeros_like(m), m, 2 * m])
        slow = np.tile(self.gm_d[:, None] * 2 * m[None, :] <= 1.0, 3)
        k = self.evaluate(s, slow).reshape(3, len(m))
        tau = m / fs_hz
        return (6 * k[0] - 8 * k[1] + 2 * k[2]) / (2 * tau * tau)


def _sinh_minus(d: float) -> float:
    """``sinh(d) - d`` without cancellation."""
    if d > 0.1:
        return math.sinh(d) - d
    return sum(d ** (2 * k + 1) / math.factorial(2 * k + 1) for k in range(1, 8))


_E3_COEF = np.array([(-1) ** k / math.factorial(k) for k in range(3, 16)])


@nb.njit(cache=True)
def _k_at(s, slow, g_col, lin, cub, delta, gv, gd, ls, lf, ec):
    # K(s) at one lag; slow[:, g_col] chooses each Gauss-Markov term's form (no fastmath: the
    # second differences of K cancel, reassociation would cost the digits they keep)
    s = abs(s)
    out = lin * s + cub * (s * s * s - s)
    if s == 0.0:
        out += delta
    for g in range(len(gd)):
        x = s * gd[g]
        if slow[g, g_col]:
            if x < 0.1:  # x + e^-x - 1 - x^2/2 by its series (-x^3/6 + ...)
                acc = 0.0
                for c in _E3_COEF[::-1]:
                    acc = acc * x + c
                e3 = acc * x * x * x
            else:
                e3 = x + math.expm1(-x) - 0.5 * x * x
            out -= 0.5 * gv[g] * (ls[g] * s + ec[g] * e3)
        else:
            out -= 0.5 * gv[g] * (lf[g] * s + ec[g] * math.expm1(-x))
    return out


@nb.njit(cache=True)
def _kernel_values(s, slow, lin, cub, delta, gv, gd, ls, lf, ec, out):
    for i in range(len(s)):
        out[i] = _k_at(s[i], slow, i, lin, cub, delta, gv, gd, ls, lf, ec)


@nb.njit(cache=True)
def _core_values(h, w, pr, mj, mk, cj, ck, slow, lin, cub, delta, gv, gd, ls, lf, ec, out):
    # w n(h) C(h)^2 at every node: C from the 9 shifted kernels, n summed over the segments
    for i in range(len(h)):
        p = pr[i]
        c = 0.0
        for a in range(3):
            wa = 1.0 if a != 1 else -2.0
            for b in range(3):
                wb = 1.0 if b != 1 else -2.0
                c += wa * wb * _k_at(h[i] + b * mk[p] - a * mj[p], slow, p, lin, cub, delta, gv, gd, ls, lf, ec)
        n = 0.0
        for t in range(cj.shape[1]):
            v = min(cj[p, t], ck[p, t] - h[i]) - max(0.0, -h[i])
            if v > 0.0:
                n += v
        out[i] = w[i] * n * c * c


# ---------------------------------------------------------------------------
# the lag sum


def _integer_sum_nodes(a: np.ndarray, b: np.ndarray, edge: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes and weights with ``sum_{h=a}^{b} f(h) ~ sum w f(node)`` for f smooth on ``[a, b+1)``.

    Returns (piece index, node, weight). Pieces up to ``4 edge`` long are summed
    exactly; longer ones exactly over ``edge`` integers at each end and by the
    midpoint-rule integral in between (Gauss-Legendre on sub-intervals of length
    ``edge``, ``2 edge``, ``4 edge``, ... from both ends).
    """
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    length = b - a + 1
    short = length <= 4 * edge
    # exact integers: whole short pieces, `edge` at each end of long ones
    cnt_lo = np.where(short, length, edge)
    cnt_hi = np.where(short, 0, edge)
    start_hi = b - edge + 1
    idx = np.arange(len(a))
    p1 = np.repeat(idx, cnt_lo)
    h1 = a[p1] + _ramp(cnt_lo)
    p2 = np.repeat(idx, cnt_hi)
    h2 = start_hi[p2] + _ramp(cnt_hi)
    pieces = [p1, p2]
    nodes = [h1.astype(float), h2.astype(float)]
    weights = [np.ones(len(h1)), np.ones(len(h2))]
    long_ = np.nonzero(~short)[0]
    if len(long_):
        lo = (a[long_] + edge).astype(float) - 0.5
        hi = (b[long_] - edge).astype(float) + 0.5
        mid = 0.5 * (lo + hi)
        lev = 2.0 ** np.arange(_LEVELS)
        # left sub-intervals [lo + e(2^l - 1), lo + e(2^{l+1} - 1)] clipped to mid, and their mirror images
        l0 = np.minimum(lo[:, None] + edge * (lev - 1.0), mid[:, None])
        l1 = np.minimum(lo[:, None] + edge * (2 * lev - 1.0), mid[:, None])
        r0 = np.maximum(hi[:, None] - edge * (2 * lev - 1.0), mid[:, None])
        r1 = np.maximum(hi[:, None] - edge * (lev - 1.0), mid[:, None])
        x0 = np.concatenate([l0, r0], axis=1)
        x1 = np.concatenate([l1, r1], axis=1)
        keep = x1 > x0
        piece = np.broadcast_to(long_[:, None], x0.shape)[keep]
        x0, x1 = x0[keep], x1[keep]
        half = 0.5 * (x1 - x0)
        centre = 0.5 * (x1 + x0)
        pieces.append(np.repeat(piece, GL_NODES))
        nodes.append((centre[:, None] + half[:, None] * _GL_X[None, :]).ravel())
        weights.append((half[:, None] * _GL_W[None, :]).ravel())
    return np.concatenate(pieces), np.concatenate(nodes), np.concatenate(weights)


def _ramp(counts: np.ndarray) -> np.ndarray:
    """``0, 1, ..., c-1`` for every count ``c``, concatenated."""
    counts = np.asarray(counts, dtype=np.int64)
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    starts = np.repeat(np.cumsum(counts) - counts, counts)
    return np.arange(total, dtype=np.int64) - starts


def _tail_sums(c: np.ndarray, length: np.ndarray) -> np.ndarray:
    """``sum_{t=0}^{L} (L + 1 - t) e^{-c (t + 1)}`` for ``c > 0``, ``L >= 0`` (arrays, broadcast)."""
    L = np.asarray(length, dtype=float)
    c = np.asarray(c, dtype=float)
    # S0 = sum r^t, S1 = sum t r^t (t = 0..L), r = e^-c;  result = r ((L+1) S0 - S1)
    small = c * (L + 1.0) < 1e-3
    cs = np.where(small, 1.0, c)
    em = -np.expm1(-cs)  # 1 - r
    r = np.exp(-cs)
    s0 = -np.expm1(-cs * (L + 1.0)) / em
    a = -np.expm1(-cs * L) / em  # sum_{t<L} r^t
    s1 = r * (a - L * np.exp(-cs * L)) / em
    exact = r * ((L + 1.0) * s0 - s1)
    # c (L+1) small: expand e^{-c(t+1)} to second order
    n1 = L + 1.0
    m0 = n1 * (n1 + 1.0) / 2.0  # sum (L+1-t)
    m1 = n1 * (n1 + 1.0) * (n1 + 2.0) / 6.0  # sum (L+1-t)(t+1)
    m2 = n1 * (n1 + 1.0) ** 2 * (n1 + 2.0) / 12.0  # sum (L+1-t)(t+1)^2
    series = m0 - c * m1 + 0.5 * c * c * m2
    return np.where(small, series, exact)


def avar_covariance(
    model: NoiseModel,
    fs_hz: float,
    m: Sequence[int] | np.ndarray,
    segment_lengths: Sequence[int] | np.ndarray,
    *,
    diagonal: bool = False,
    edge: int = EXACT_EDGE,
) -> np.ndarray:
    """Covariance of the overlapping AVAR estimates at cluster sizes ``m`` (samples) under ``model``.

    model : the noise model (terms white rate, Gauss-Markov, random walk, white angle).
    fs_hz : sampling rate, Hz.
    segment_lengths : rate samples of each contiguous segment (the estimates pool them,
        :func:`.allan.oadev` with ``segments``).
    diagonal : only the variances (a vector), not the whole matrix.

    Returns ``(len(m), len(m))`` (or ``(len(m),)``) in (rate unit)^4. Raises
    :class:`InputError` for a model term without a kernel, or an ``m`` no segment holds.
    """
    kern = AngleKernel.of(model, fs_hz)
    m = np.asarray(m, dtype=np.int64)
    n_x = np.asarray(segment_lengths, dtype=np.int64) + 1  # angle points per segment
    if len(m) == 0:
        return np.zeros(0 if diagonal else (0, 0))
    counts = np.maximum(0, n_x[None, :] - 2 * m[:, None])  # (taus, segments)
    total = counts.sum(axis=1)
    if np.any(total == 0):
        raise InputError(f"cluster size {int(m[np.argmin(total)])} is longer than half of every segment")
    if diagonal:
        jj = kk = np.arange(len(m))
    else:
        jj, kk = np.triu_indices(len(m))
    # order each pair so that m_j <= m_k
    swap = m[jj] > m[kk]
    jj, kk = np.where(swap, kk, jj), np.where(swap, jj, kk)
    mj, mk = m[jj].astype(float), m[kk].astype(float)
    s = _core_sums(kern, mj, mk, counts[jj], counts[kk], edge) + _tail_total(kern, mj, mk, counts[jj], counts[kk])
    dt = 1.0 / float(fs_hz)
    cov = 2.0 * s / (4.0 * (mj * dt) ** 2 * (mk * dt) ** 2 * total[jj] * total[kk])
    if diagonal:
        return cov
    out = np.zeros((len(m), len(m)))
    out[jj, kk] = cov
    out[kk, jj] = cov
    return out


def _tail_total(kern: AngleKernel, mj, mk, cj, ck) -> np.ndarray:
    """Sum of n(h) C(h)^2 over h > 2 m_j and h < -2 m_k (Gauss-Markov terms only), per pair."""
    if len(kern.gm_d) == 0:
        return np.zeros(len(mj))
    d = kern.gm_d
    phi = np.exp(-d)
    om = -np.expm1(-d)
    # C(h) = -sum_g A_g e^{-(h - 2 m_j) d_g} for h >= 2 m_j (mirror image below -2 m_k)
    amp = (kern.gm_v * phi / om**2)[None, :] * np.expm1(-mj[:, None] * d) ** 2 * np.expm1(-mk[:, None] * d) ** 2
    out = np.zeros(len(mj))
    G = len(d)
    for g in range(G):
        for g2 in range(G):
            c = d[g] + d[g2]
            w = amp[:, g] * amp[:, g2]
            # h = 2 m_j + 1 + t, t = 0..L: n(h) = (M_k - 2 m_j - 1) - t  (M_j >= M_k)
            lp = ck - 2.0 * mj[:, None] - 2.0
            # h = -2 m_k - 1 - t: n(h) = (M_j - 2 m_k - 1) - t
            ln = cj - 2.0 * mk[:, None] - 2.0
            tp = np.where(lp >= 0, _tail_sums(c, np.maximum(lp, 0.0)), 0.0).sum(axis=1)
            tn = np.where(ln >= 0, _tail_sums(c, np.maximum(ln, 0.0)), 0.0).sum(axis=1)
            out += w * (tp + tn)
    return out


def _core_sums(kern: AngleKernel, mj, mk, cj, ck, edge: int) -> np.ndarray:
    """Sum of n(h) C(h)^2 over the core -2 m_k <= h <= 2 m_j, per pair (m_j <= m_k)."""
    n_pairs = len(mj)
    # the core, cut to lags some segment holds
    lo = np.maximum(-2.0 * mk, -(cj.max(axis=1) - 1.0))
    hi = np.minimum(2.0 * mj, ck.max(axis=1) - 1.0)
    # breakpoints: kinks of C (h = s_p - s_q), of the pair count (0, M_k - M_j, segment ends)
    sp = np.stack([0 * mj, mj, 2 * mj], axis=1)
    sq = np.stack([0 * mk, mk, 2 * mk], axis=1)
    kinks = (sp[:, :, None] - sq[:, None, :]).reshape(n_pairs, 9)
    ends = np.concatenate([-(cj - 1.0), ck - 1.0 + 1.0], axis=1)  # n(h) reaches 0 beyond these
    bp = np.concatenate([kinks, np.zeros((n_pairs, 1)), (ck - cj)[:, :1], ends, lo[:, None]], axis=1)
    bp = np.where((bp >= lo[:, None]) & (bp <= hi[:, None]), bp, lo[:, None])
    bp = np.sort(bp, axis=1)
    new = np.concatenate([np.ones((n_pairs, 1), bool), np.diff(bp, axis=1) > 0], axis=1)
    pair_of_piece = np.broadcast_to(np.arange(n_pairs)[:, None], bp.shape)[new]
    starts = bp[new]
    # each piece runs to the next start - 1, the last of a pair to hi
    nxt = np.append(starts[1:], np.inf)
    last = np.append(pair_of_piece[1:] != pair_of_piece[:-1], True)
    stops = np.where(last, hi[pair_of_piece], nxt - 1.0)
    ok = stops >= starts
    pair_of_piece, starts, stops = pair_of_piece[ok], starts[ok], stops[ok]
    piece, h, w = _integer_sum_nodes(starts.astype(np.int64), stops.astype(np.int64), edge)
    pr = pair_of_piece[piece]
    # slow (polynomial-free) Gauss-Markov form where the exponential is slow over the pair's lags
    span = np.maximum(np.abs(lo), np.abs(hi)) + 2.0 * mk
    slow = np.ascontiguousarray(kern.gm_d[:, None] * span[None, :] <= 1.0)
    ls, lf, ec = kern.constants()
    vals = np.empty(len(h))
    _core_values(h, w, pr, mj, mk, np.ascontiguousarray(cj, float), np.ascontiguousarray(ck, float), slow,
                 kern.lin, kern.cub, kern.delta, kern.gm_v, kern.gm_d, ls, lf, ec, vals)  # fmt: skip
    return np.bincount(pr, weights=vals, minlength=n_pairs)
