"""Classical maximum likelihood on rate samples ("ML uniform" / "ML log" of Nikolic et al. Fig. 10).

The standard model (eq. 22) observed directly in the rate: at sample indices
``k_0 < k_1 < ...`` (every sample, a uniform subsample or a log-spaced one),
``z_i = b(t_i) + b_on + v_i`` with ``Var v_i = sigma_w^2 fs`` (white noise
band-limited to Nyquist, eq. 9) and the exact Gauss-Markov transition between
observation times. The same exact reformulation as ML_i is used (diffuse b_on,
sigma_w profiled, scalar Riccati as a Moebius prefix scan), so only the data
differ: the estimator sees rate samples, not the integrated angle.
"""

from __future__ import annotations

import math
import time

import numpy as np

from imustation.analysis.estimators.engine.fitting import MLiResult, ParamSpec, Problem, build_result, optimise
from imustation.analysis.estimators.engine.kalman import Profile
from imustation.analysis.estimators.engine.newton import NewtonResult
from imustation.analysis.estimators.engine.pattern import check_rate, sampling_pattern
from imustation.analysis.estimators.engine.scan import scan_affine, scan_moebius
from imustation.analysis.estimators.models.noise_models import parse_model
from imustation.errors import InputError


def rate_filter(z: np.ndarray, gaps: np.ndarray, fs_hz: float, r: np.ndarray, tau: np.ndarray) -> Profile:
    """Diffuse filter on rate samples ``z`` (M,) for K points; ``gaps`` (M,) times since
    the previous observation (s, the first ignored); ``r = sigma_b^2/sigma_w^2``, ``tau`` (K,)."""
    Rv = float(fs_hz)  # Var v / sigma_w^2
    a = gaps[:, None] / tau[None, :]
    e = np.exp(-a)
    q = r[None, :] * tau[None, :] * 0.5 * -np.expm1(-2.0 * a)
    e[0] = 0.0  # first sample: stationary prior
    q[0] = r * tau * 0.5
    # posterior p_i = (e^2 p + q) R / (e^2 p + q + R): Moebius [[e^2 R, q R], [e^2, q + R]]
    A, Bm, C, D = scan_moebius((e * e * Rv, q * Rv, e * e, q + Rv))
    p_post = Bm / D  # prefix maps applied to p = 0 (e_0 = 0 makes the start irrelevant)
    p_prev = np.vstack([np.zeros_like(r)[None, :], p_post[:-1]])
    p_pred = e * e * p_prev + q
    B = p_pred + Rv
    gain = p_pred / B
    g = (1.0 - gain) * e
    bhat = scan_affine(g, gain * z[:, None])
    bprev = np.vstack([np.zeros_like(r)[None, :], bhat[:-1]])
    nu = z[:, None] - e * bprev
    ones = np.ones_like(z)
    uhat = scan_affine(g, gain * ones[:, None])
    uprev = np.vstack([np.zeros_like(r)[None, :], uhat[:-1]])
    u = 1.0 - e * uprev
    s_ee = np.sum(nu * nu / B, axis=0)
    s_eu = np.sum(nu * u / B, axis=0)
    s_uu = np.sum(u * u / B, axis=0)
    b_on = s_eu / s_uu
    return Profile(s_ee - s_eu * b_on, np.sum(np.log(B), axis=0), np.log(s_uu), b_on, len(z))


class _RateProblem(Problem):
    """Likelihood of the standard model on subsampled rate, batched.

    Shares :class:`~.fitting.Problem`'s ``nll``/``full_nll`` and
    optimiser; only the data, the search box and ``profile`` (the rate filter) differ.
    """

    def __init__(self, z: np.ndarray, gaps: np.ndarray, fs_hz: float, duration: float):
        self.z, self.gaps, self.fs_hz = z, gaps, fs_hz
        self.spec = ParamSpec(parse_model("wn+gm"))
        # r = sigma_b^2/sigma_w^2 from "invisible over the record" to "bias variance
        # 10 x the white variance per sample (sigma_w^2 fs) at the shortest tau"
        self.lo = np.array([math.log(1e-6 / duration**2), math.log(2.0 / fs_hz)])
        self.hi = np.array([math.log(10.0 * fs_hz**2), math.log(100.0 * duration)])
        self.n_eval = 0
        # chunk the parameter batch so (M, K) arrays stay near 50 MB
        self.chunk = max(1, int(6e6 // max(len(z), 1)))

    def profile(self, theta: np.ndarray) -> Profile:
        theta = np.atleast_2d(theta)
        self.n_eval += theta.shape[0]
        parts = [
            rate_filter(self.z, self.gaps, self.fs_hz, np.exp(t[:, 0]), np.exp(t[:, 1]))
            for t in np.array_split(theta, math.ceil(theta.shape[0] / self.chunk))
        ]
        return Profile(
            *(np.concatenate([getattr(p, f) for p in parts]) for f in ("s_tilde", "logdet", "log_suu", "b_on")),
            parts[0].m,
        )


def fit_ml_rate(
    rate: np.ndarray,
    fs_hz: float,
    *,
    pattern: str = "uniform",
    m: int | None = 1000,
    scale: float = 1.0,
) -> MLiResult:
    """Classical ML of the standard model on rate samples (SI units, as :func:`fit_mli`).

    ``pattern``: ``uniform`` (every (n/m)-th sample) or ``log`` (log-spaced
    sample indices); ``m=None`` uses every sample (affordable on short records).
    """
    t0 = time.perf_counter()
    rate = check_rate(rate, fs_hz)
    n = len(rate)
    if m is None:
        idx = np.arange(n)
    else:
        idx = sampling_pattern(n, m, pattern)[1:] - 1  # last sample of each pattern interval
    if len(idx) < 8:
        raise InputError(f"only {len(idx)} rate samples selected: classical ML needs at least 8")
    z = rate[idx].astype(np.float64) * scale
    gaps = np.r_[0.0, np.diff(idx) / fs_hz]
    problem = _RateProblem(z, gaps, fs_hz, n / fs_hz)
    # starts: a coarse grid over the box (as the ML_i fast path)
    gr = np.linspace(problem.lo[0], problem.hi[0], 12)
    gt = np.linspace(problem.lo[1], problem.hi[1], 8)
    RR, TT = np.meshgrid(gr, gt, indexing="ij")
    pts = np.column_stack([RR.ravel(), TT.ravel()])
    f = problem.nll(pts)
    starts = [pts[i] for i in np.argsort(f)[:3]]
    best, n_starts = optimise(problem, starts)
    assert isinstance(best, NewtonResult)
    label = "all" if m is None else pattern
    return build_result(problem, best.x, best, n_starts, t0, "ML", len(idx), label, n, fs_hz)
