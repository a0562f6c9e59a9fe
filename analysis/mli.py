"""ML_i: maximum likelihood on the integrated signal (Nikolic et al. 2016, §III).

Model (eq. 22): rate ``z = b + v + b_on``, ``db/dt = -b/tau_b + w``; the rate is
integrated once (eq. 20, exactly in int64 for raw counts), sampled on a
sampling pattern (log-spaced, m = 1000 by default) and the innovations
likelihood (eq. 19) of the angle increments is maximised.

Exact reformulation used here (the maximiser is the paper's):

* Between pattern points the angle increment is
  ``y_i = tau c b_{i-1} + dt_i b_on + e_i`` with ``a = dt_i/tau_b``,
  ``c = 1 - exp(-a)``; the discretisation (eqs. 14, 18, 21) is analytic:
  ``Var w_b = sigma_b^2 tau/2 (1 - e^{-2a})``,
  ``Cov(w_b, e) = sigma_b^2 tau^2 c^2 / 2``,
  ``Var e = sigma_w^2 dt + sigma_b^2 tau^3 (a - c - c^2/2)``.
  As the angle is observed without noise, the state reduces to the scalar ``b``.
* ``b_on`` is a diffuse initial state, handled exactly by the augmented
  (de Jong) filter: a regressor filter run on ``dt_i`` gives its GLS estimate
  and the diffuse likelihood term ``log S_uu``.
* ``sigma_w^2`` scales every covariance once ``r = sigma_b^2/sigma_w^2`` is fixed, so
  it is profiled in closed form; the search runs over ``(log r, log tau_b)`` only.
* The scalar Riccati recursion is a Moebius map with non-negative coefficients
  and the state recursions are affine maps, so the whole filter runs as a
  parallel prefix scan (Hillis-Steele doubling): O(log m) numpy operations on
  ``(m, K)`` arrays evaluate K parameter points at once.

Parameter uncertainties (beyond the paper, which gives none) come from the
observed information: the numerical Hessian of the full negative
log-likelihood in ``(log sigma_w, log sigma_b, log tau_b)``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from imustation.errors import InputError

_LOG2PI = math.log(2.0 * math.pi)
#: z-score of the two-sided 90 % interval
Z90 = 1.6448536269514722


# ---------------------------------------------------------------------------
# sampling pattern and integration


def sampling_pattern(n: int, m: int = 1000, kind: str = "log") -> np.ndarray:
    """Pattern points as angle indices ``0 = k_0 < k_1 < ... < k_M = n``.

    ``log``: geometric spacing of the points from 1 to n, forced strictly
    increasing (the first steps are single samples), so ``M = min(m, n)``.
    ``uniform``: equal steps.
    """
    if n < 2:
        raise InputError(f"{n} samples: ML_i needs a longer record")
    m = int(min(m, n))
    if kind == "log":
        k = np.floor(np.geomspace(1.0, float(n), m)).astype(np.int64)
        i = np.arange(m, dtype=np.int64)
        # strictly increasing (steps >= 1); the last point stays n because n >= m
        k = np.maximum.accumulate(k - i) + i
    elif kind == "uniform":
        k = np.round(np.linspace(0, n, m + 1)[1:]).astype(np.int64)
    else:
        raise InputError(f"pattern {kind!r}: use 'log' or 'uniform'")
    k[-1] = n
    return np.concatenate([[0], k])


def integrate_pattern(rate: np.ndarray, fs_hz: float, points: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Angle increments between pattern points (eq. 20), in rate-units x s.

    Integer counts are summed exactly in int64 before scaling.
    """
    starts = points[:-1]
    if np.issubdtype(rate.dtype, np.integer):
        sums = np.add.reduceat(rate, starts, dtype=np.int64).astype(np.float64)
    else:
        sums = np.add.reduceat(np.asarray(rate, dtype=np.float64), starts)
    return sums * (scale / fs_hz)


# ---------------------------------------------------------------------------
# the likelihood


def _f3(a: np.ndarray) -> np.ndarray:
    """a - c - c^2/2 with c = 1 - e^{-a}  (= integral_0^a (1 - e^{-u})^2 du).

    The direct form cancels for small ``a``; there the series
    ``sum_{k>=2} (-1)^k (2^k - 2) a^{k+1} / ((k+1) k!)`` is used (terms beyond
    k = 12 are below 1e-16 relative for a < 0.1).
    """
    out = np.empty_like(a)
    small = a < 0.1
    big = ~small
    c = -np.expm1(-a[big])
    out[big] = a[big] - c - 0.5 * c * c
    s = a[small]
    acc = np.full_like(s, _F3_COEF[-1])
    for coef in _F3_COEF[-2::-1]:
        acc = acc * s + coef
    out[small] = acc * s**3
    return out


_F3_COEF = tuple((-1) ** k * (2**k - 2) / ((k + 1) * math.factorial(k)) for k in range(2, 13))


def _scan_moebius(mats: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
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


def _scan_affine(g: np.ndarray, k: np.ndarray) -> np.ndarray:
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


@dataclass
class _Profile:
    """Concentrated quantities for K parameter points (arrays of shape (K,))."""

    s_tilde: np.ndarray  # residual sum of squares (sigma_w^2 = 1 units)
    logdet: np.ndarray  # sum log B_i (sigma_w^2 = 1 units)
    log_suu: np.ndarray  # log S_uu (diffuse term)
    b_on: np.ndarray
    m: int


def _filter(y: np.ndarray, dt: np.ndarray, r: np.ndarray, tau: np.ndarray) -> _Profile:
    """Run the reduced diffuse filter for K points ``(r_k, tau_k)`` at once.

    ``y``, ``dt``: (M,) increments and interval lengths (s); ``r``, ``tau``: (K,).
    """
    a = dt[:, None] / tau[None, :]  # (M, K)
    e = np.exp(-a)
    c = -np.expm1(-a)
    T = tau[None, :]
    R = r[None, :]
    h = T * c
    q_bb = R * T * 0.5 * (-np.expm1(-2.0 * a))
    q_bo = R * T * T * 0.5 * c * c
    q_oo = dt[:, None] + R * T**3 * _f3(a)
    p0 = r * tau * 0.5
    # Riccati p_i = (alpha p_{i-1} + beta) / (gamma p_{i-1} + delta) as Moebius maps
    alpha = e * e * q_oo + q_bb * h * h - 2.0 * e * h * q_bo
    beta = np.maximum(q_bb * q_oo - q_bo * q_bo, 0.0)
    gamma = h * h
    delta = q_oo
    A, Bm, C, D = _scan_moebius((alpha, beta, gamma, delta))
    p_post = (A * p0 + Bm) / (C * p0 + D)  # p after step i
    p_prev = np.vstack([p0[None, :], p_post[:-1]])  # p before step i
    B = h * h * p_prev + q_oo
    gain = (e * p_prev * h + q_bo) / B
    g = e - gain * h
    # data filter: bhat_i = g_i bhat_{i-1} + K_i y_i ; innovation y_i - h_i bhat_{i-1}
    bhat = _scan_affine(g, gain * y[:, None])
    bprev = np.vstack([np.zeros_like(r)[None, :], bhat[:-1]])
    nu = y[:, None] - h * bprev
    # regressor filter for the diffuse b_on (its effect on y_i is dt_i)
    uhat = _scan_affine(g, gain * dt[:, None])
    uprev = np.vstack([np.zeros_like(r)[None, :], uhat[:-1]])
    u = dt[:, None] - h * uprev
    s_ee = np.sum(nu * nu / B, axis=0)
    s_eu = np.sum(nu * u / B, axis=0)
    s_uu = np.sum(u * u / B, axis=0)
    b_on = s_eu / s_uu
    return _Profile(s_ee - s_eu * b_on, np.sum(np.log(B), axis=0), np.log(s_uu), b_on, len(y))


def _profile_nll(prof: _Profile) -> np.ndarray:
    """-log L with sigma_w^2 and b_on profiled out (diffuse likelihood)."""
    dof = prof.m - 1
    s2 = prof.s_tilde / dof
    return 0.5 * (dof * (np.log(s2) + 1.0) + prof.logdet + prof.log_suu + dof * _LOG2PI)


def _full_nll(prof: _Profile, sigma_w2: np.ndarray) -> np.ndarray:
    dof = prof.m - 1
    return 0.5 * (dof * np.log(sigma_w2) + prof.logdet + prof.log_suu + prof.s_tilde / sigma_w2 + dof * _LOG2PI)


# ---------------------------------------------------------------------------
# public API


@dataclass(frozen=True)
class MLiResult:
    """ML_i estimate of the standard model with turn-on bias (SI units).

    ``stderr`` holds delta-method standard errors from the observed
    information; ``ci90`` the 90 % intervals, symmetric in log-parameters.
    ``nll`` is the negative diffuse log-likelihood at the optimum.
    """

    model: str
    sigma_w: float
    sigma_b: float
    tau_b: float
    b_on: float
    stderr: dict[str, float]
    ci90: dict[str, tuple[float, float]]
    nll: float
    pattern: str
    m: int
    n: int
    fs_hz: float
    converged: bool
    message: str
    n_eval: int
    fit_time_s: float
    starts: int = 1
    at_bound: tuple[str, ...] = field(default_factory=tuple)

    def as_dict(self) -> dict:
        return {
            "model": self.model,
            "sigma_w": self.sigma_w,
            "sigma_b": self.sigma_b,
            "tau_b": self.tau_b,
            "b_on": self.b_on,
            "stderr": dict(self.stderr),
            "ci90": {k: list(v) for k, v in self.ci90.items()},
            "pattern": self.pattern,
            "m": self.m,
            "nll": self.nll,
            "converged": self.converged,
            "message": self.message,
        }


def fit_increments(
    y: np.ndarray,
    dt: np.ndarray,
    *,
    n: int,
    fs_hz: float,
    pattern: str = "log",
    starts: int = 3,
) -> MLiResult:
    """Fit the standard model to angle increments ``y`` over intervals ``dt`` (s)."""
    t0 = time.perf_counter()
    y = np.asarray(y, dtype=float)
    dt = np.asarray(dt, dtype=float)
    m = len(y)
    if m < 8:
        raise InputError(f"only {m} pattern intervals: ML_i needs at least 8")
    total = float(dt.sum())
    dt_min = float(dt.min())
    # search box in (log r, log tau): tau from 2 samples to 100 x the record;
    # r = sigma_b^2/sigma_w^2 from "no visible bias" to "bias dominates at 1 sample"
    log_tau_lo, log_tau_hi = math.log(2.0 / fs_hz), math.log(100.0 * total)
    log_r_lo, log_r_hi = math.log(1e-6 / total**2), math.log(10.0 / dt_min**2)

    def nll_batch(log_r: np.ndarray, log_tau: np.ndarray) -> np.ndarray:
        prof = _filter(y, dt, np.exp(log_r), np.exp(log_tau))
        out = _profile_nll(prof)
        return np.where(np.isfinite(out), out, np.inf)

    # 1) coarse grid over the whole box, in one batched pass
    gr = np.linspace(log_r_lo, log_r_hi, 24)
    gt = np.linspace(log_tau_lo, log_tau_hi, 16)
    RR, TT = np.meshgrid(gr, gt, indexing="ij")
    grid_nll = nll_batch(RR.ravel(), TT.ravel())
    n_eval = grid_nll.size
    order = np.argsort(grid_nll)
    # 2) local refinement from the best distinct grid points (several starts)
    chosen: list[int] = []
    for idx in order:
        if all(abs(RR.ravel()[idx] - RR.ravel()[j]) + abs(TT.ravel()[idx] - TT.ravel()[j]) > 3.0 for j in chosen):
            chosen.append(int(idx))
        if len(chosen) == starts:
            break
    lo = np.array([log_r_lo, log_tau_lo])
    hi = np.array([log_r_hi, log_tau_hi])
    best = None
    for idx in chosen:
        x0 = np.array([RR.ravel()[idx], TT.ravel()[idx]])
        res = _newton(nll_batch, x0, lo, hi)
        n_eval += res.n_eval
        if best is None or res.fun < best.fun:
            best = res
    assert best is not None
    log_r, log_tau = best.x
    prof = _filter(y, dt, np.exp([log_r]), np.exp([log_tau]))
    sigma_w2 = float(prof.s_tilde[0] / (m - 1))
    sigma_w = math.sqrt(sigma_w2)
    sigma_b = math.sqrt(math.exp(log_r) * sigma_w2)
    tau_b = math.exp(log_tau)
    nll = float(_full_nll(prof, np.array([sigma_w2]))[0])
    at_bound = tuple(
        name
        for name, v, lo, hi in (("sigma_b", log_r, log_r_lo, log_r_hi), ("tau_b", log_tau, log_tau_lo, log_tau_hi))
        if min(v - lo, hi - v) < 1e-3
    )
    stderr, ci90 = _uncertainty(y, dt, sigma_w, sigma_b, tau_b)
    n_eval += 19
    converged = best.converged and not at_bound
    message = best.message if not at_bound else f"at search bound: {', '.join(at_bound)}"
    return MLiResult(
        model="wn+gm",
        sigma_w=sigma_w,
        sigma_b=sigma_b,
        tau_b=tau_b,
        b_on=float(prof.b_on[0]),
        stderr=stderr,
        ci90=ci90,
        nll=nll,
        pattern=pattern,
        m=m,
        n=n,
        fs_hz=fs_hz,
        converged=converged,
        message=message,
        n_eval=n_eval,
        fit_time_s=time.perf_counter() - t0,
        starts=len(chosen),
        at_bound=at_bound,
    )


@dataclass
class _NewtonResult:
    x: np.ndarray
    fun: float
    converged: bool
    message: str
    n_eval: int


#: finite-difference step in log-parameters: the nll is computed to ~1e-10
#: relative (~1e-7 absolute), so curvature from h = 0.02 is good to ~1e-4
_FD_STEP = 0.02
_STENCIL = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [1, -1], [-1, 1], [-1, -1]], float)


def _newton(fun, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_iter: int = 60) -> _NewtonResult:
    """Damped Newton in 2-D; gradient and Hessian from one batched 9-point stencil.

    Converged when the Hessian is positive definite and the predicted decrease
    of the Newton step is below 1e-7 (nats); a step that does not decrease the
    function is halved and the damping raised (Levenberg-Marquardt style).
    """
    h = _FD_STEP
    x = np.clip(x0, lo, hi)
    n_eval = 0
    lam = 0.0
    f0 = np.inf
    for _ in range(max_iter):
        pts = np.clip(x[None, :] + h * _STENCIL, lo, hi)
        f = fun(pts[:, 0], pts[:, 1])
        n_eval += len(f)
        f0 = float(f[0])
        g = np.array([(f[1] - f[2]) / (pts[1, 0] - pts[2, 0]), (f[3] - f[4]) / (pts[3, 1] - pts[4, 1])])
        H = np.empty((2, 2))
        H[0, 0] = (f[1] - 2 * f0 + f[2]) / h**2
        H[1, 1] = (f[3] - 2 * f0 + f[4]) / h**2
        H[0, 1] = H[1, 0] = (f[5] - f[6] - f[7] + f[8]) / (4 * h * h)
        pd = bool(np.all(np.linalg.eigvalsh(H) > 0))
        for _attempt in range(30):
            Hd = H + (lam + (0.0 if pd else abs(np.linalg.eigvalsh(H)).max() + 1.0)) * np.eye(2)
            step = -np.linalg.solve(Hd, g)
            norm = float(np.hypot(*step))
            if norm > 2.0:
                step *= 2.0 / norm
            predicted = -float(g @ step + 0.5 * step @ H @ step)
            if pd and lam == 0.0 and 0 <= predicted < 1e-7:
                return _NewtonResult(x, f0, True, "converged", n_eval)
            x_new = np.clip(x + step, lo, hi)
            f_new = float(fun(x_new[:1], x_new[1:])[0])
            n_eval += 1
            if f_new <= f0:
                x = x_new
                lam = lam / 4.0 if lam > 1e-6 else 0.0
                break
            lam = max(4.0 * lam, 1e-3 * float(np.abs(np.diag(H)).max() + 1.0))
        else:
            return _NewtonResult(x, f0, pd, "no further decrease (flat optimum)", n_eval)
        if np.any(x <= lo) or np.any(x >= hi):
            pass  # the caller reports parameters at their bound
    return _NewtonResult(x, f0, False, f"no convergence in {max_iter} Newton steps", n_eval)


def _uncertainty(
    y: np.ndarray, dt: np.ndarray, sigma_w: float, sigma_b: float, tau_b: float
) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """Observed information in log-parameters -> stderr and 90 % intervals."""
    theta = np.log([sigma_w, sigma_b, tau_b])
    h = 1e-2  # see _FD_STEP: nll noise ~1e-7 absolute
    offsets = [np.zeros(3)]
    for i in range(3):
        for s in (1, -1):
            v = np.zeros(3)
            v[i] = s * h
            offsets.append(v)
    for i in range(3):
        for j in range(i + 1, 3):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                v = np.zeros(3)
                v[i], v[j] = si * h, sj * h
                offsets.append(v)
    pts = theta[None, :] + np.array(offsets)
    sw2 = np.exp(2 * pts[:, 0])
    prof = _filter(y, dt, np.exp(2 * pts[:, 1]) / sw2, np.exp(pts[:, 2]))
    f = _full_nll(prof, sw2)
    f0 = f[0]
    H = np.zeros((3, 3))
    k = 1
    for i in range(3):
        H[i, i] = (f[k] - 2 * f0 + f[k + 1]) / h**2
        k += 2
    for i in range(3):
        for j in range(i + 1, 3):
            fpp, fpm, fmp, fmm = f[k : k + 4]
            H[i, j] = H[j, i] = (fpp - fpm - fmp + fmm) / (4 * h * h)
            k += 4
    names = ("sigma_w", "sigma_b", "tau_b")
    values = (sigma_w, sigma_b, tau_b)
    try:
        cov = np.linalg.inv(H)
        var = np.diag(cov)
    except np.linalg.LinAlgError:
        var = np.full(3, np.nan)
    stderr, ci90 = {}, {}
    for name, value, v in zip(names, values, var, strict=True):
        se_log = math.sqrt(v) if v > 0 and np.isfinite(v) else float("nan")
        stderr[name] = value * se_log
        ci90[name] = (value * math.exp(-Z90 * se_log), value * math.exp(Z90 * se_log))
    return stderr, ci90


def fit_mli(
    rate: np.ndarray,
    fs_hz: float,
    model: str = "wn+gm",
    *,
    pattern: str = "log",
    m: int = 1000,
    scale: float = 1.0,
    starts: int = 3,
) -> MLiResult:
    """ML_i fit of the standard model with turn-on bias (Algorithm 2).

    Parameters
    ----------
    rate : (n,) rate samples in rad/s (or m/s^2), unfiltered, at the sampling
        rate; or integer counts with ``scale`` (units per count), integrated exactly.
    fs_hz : sampling rate, Hz.
    model : ``"wn+gm"``, white noise + Gauss-Markov bias (+ turn-on bias).
    pattern : ``"log"`` (the paper's) or ``"uniform"`` sampling pattern.
    m : number of pattern intervals (1000 in the paper).
    starts : local refinements started from the best distinct grid points.

    Returns
    -------
    MLiResult with ``sigma_w`` (rad s^-1/sqrt(Hz)), ``sigma_b`` (rad s^-2/sqrt(Hz)),
    ``tau_b`` (s), ``b_on`` (rad/s), ``stderr``, ``ci90``, ``nll``.
    """
    if model != "wn+gm":
        raise InputError(f"model {model!r}: available models are 'wn+gm'")
    rate = np.asarray(rate)
    if rate.ndim != 1:
        raise InputError(f"rate must be one-dimensional, got shape {rate.shape}")
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise InputError(f"fs_hz = {fs_hz}: must be a positive sampling rate")
    if rate.dtype.kind == "f" and not np.all(np.isfinite(rate)):
        raise InputError("rate holds NaN or infinite values")
    n = len(rate)
    points = sampling_pattern(n, m, pattern)
    y = integrate_pattern(rate, fs_hz, points, scale)
    dt = np.diff(points) / fs_hz
    return fit_increments(y, dt, n=n, fs_hz=fs_hz, pattern=pattern, starts=starts)
