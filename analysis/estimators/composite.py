"""ML_i-F: ML_i's exact integrated likelihood plus the fine-scale Allan variance (composite likelihood).

Why (docs/noise-model.md has the numbers): the likelihood of ML_i sees the record
only through M ~ 1000 pattern intervals, so its ``sigma_w`` rests on a few hundred
short intervals (RMSE ~2 % on a 12 h record), while the white noise is visible in
every one of the n ~ 17 M samples. GMWM uses all of them at the finest wavelet
scale (``sigma_w`` to ~0.05 %) but weighs the bias scales less efficiently.

The estimator maximises

    log L_int(theta, sigma_w; pattern)  -  (D - AVAR_model(tau_f))^2 / (2 V)

* ``L_int``: the exact diffuse likelihood of the integrated signal on a sampling
  pattern (eq. 19, :mod:`.mli`), by default a *uniform* pattern of ``m`` intervals
  (about 10 s each on a 12 h record): the bias process (correlation times of
  minutes) is fully resolved at that spacing, which the log pattern is not at the
  end of the record where its intervals exceed tau_b.
* ``D``: the overlapping Allan variance of all samples at the finest scale
  ``tau_f`` (one sample by default), ``V = 2 D^2 / edf`` its variance (chi-square,
  NIST SP 1065 EDF). Its expectation is the model's closed-form AVAR at tau_f.
  Sample-to-sample differences are nearly orthogonal to interval sums (they
  share only the interval edges), so the two terms are close to independent and
  their sum is close to the joint log-likelihood: the observed information of
  the sum gives honest intervals (tested by the Monte Carlo study).

``sigma_w^2`` is profiled per parameter point by the real root of a cubic
(vectorised), so the search runs over the same log variance ratios and log
correlation times as ML_i, from the same grid and Allan start points.

Assumption made visible: the fine-scale statistic needs noise that is white at
``tau_f``. A device low-pass filter below Nyquist lowers D (by about
``1.5 tau_c / tau_f`` for a first-order filter of time constant tau_c); the
fit then disagrees with the integrated likelihood's own sigma_w, which is
tested and reported in ``message`` and ``fine_scale_z`` (raise ``fine_samples``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields, replace

import numpy as np

from imustation.analysis.estimators.allan import oadev
from imustation.analysis.estimators.fitting import (
    Z90,
    MLiResult,
    ParamSpec,
    Problem,
    build_result,
    full_nll,
    optimise,
)
from imustation.analysis.estimators.kalman import Profile
from imustation.analysis.estimators.mli import allan_start, grid_start
from imustation.analysis.estimators.newton import fd_derivatives, stencil
from imustation.analysis.estimators.noise_models import expm1_tail, parse_model
from imustation.analysis.estimators.pattern import Increments, check_rate, integrate
from imustation.errors import InputError

ESTIMATOR = "ML_i-F"
#: default uniform pattern: 1000 intervals = 43 s on a 12 h record (2000 gave the same errors
#: at twice the cost: docs/noise-model.md)
DEFAULT_M = 1000
#: |z| above which the fine-scale and integrated sigma_w disagree (reported)
FINE_SCALE_Z_LIMIT = 4.0


@dataclass(frozen=True)
class FineScale:
    """Overlapping Allan variance of all samples at ``tau`` (s) and its variance.

    ``avar`` in (rate unit)^2, ``var`` = 2 avar^2 / edf, ``samples`` = cluster size,
    ``edf`` equivalent degrees of freedom.
    """

    tau: float
    avar: float
    var: float
    edf: float
    samples: int
    #: the noise passed the whiteness test at this scale (False: it failed at every scale tried)
    white: bool = True


#: cluster sizes tried by ``fine_samples="auto"`` (samples); each is compared with 4x itself
AUTO_SAMPLES = (1, 2, 4, 8, 16, 32, 64, 128, 256)
#: whiteness test: |tau AVAR(tau) / (4 tau AVAR(4 tau)) - 1| within this many standard deviations
WHITE_Z = 4.0


def _statistic(res, i: int, n: int, m: int) -> tuple[float, float]:
    """AVAR and its EDF at index ``i`` (cluster size ``m``) of an oadev result (white-noise EDF if none)."""
    avar = float(res.adev[i]) ** 2
    edf = float(res.edf[i])
    if not (np.isfinite(edf) and edf > 0):
        # white rate noise at cluster size m (Riley, NIST SP 1065 Table 5)
        edf = (3.0 * (n - 1) / (2.0 * m) - 2.0 * (n - 2) / n) * 4.0 * m * m / (4.0 * m * m + 5.0)
    return avar, edf


def fine_scale(
    rate: np.ndarray,
    fs_hz: float,
    *,
    samples: int | str = 1,
    scale: float = 1.0,
    segments: list[tuple[int, int]] | None = None,
) -> FineScale:
    """Fine-scale statistic of :mod:`.composite`: AVAR at ``samples / fs_hz`` s from every sample.

    ``rate`` in rad/s (or integer counts with ``scale`` units per count, summed exactly).
    ``samples="auto"``: the smallest cluster size of :data:`AUTO_SAMPLES` at which
    the noise is white, i.e. ``tau AVAR(tau)`` equals ``4 tau AVAR(4 tau)`` within
    :data:`WHITE_Z` standard deviations (a device low-pass filter lowers the first);
    ``FineScale.white`` says whether any passed.
    """
    n = len(rate)
    sizes = [k for k in AUTO_SAMPLES if 8 * k < n] if samples == "auto" else [int(samples)]
    if not sizes:
        raise InputError(f"{n} samples: too short for a fine-scale Allan variance")
    chosen, white, stats = sizes[0], False, {}
    for k in sizes:
        # one oadev call per size tried: white data stop at the first (two taus, one pass each)
        taus = [k / fs_hz, 4 * k / fs_hz] if samples == "auto" else [k / fs_hz]
        res = oadev(rate, fs_hz, taus, scale=scale, segments=segments)
        got = {int(round(t * fs_hz)): i for i, t in enumerate(res.tau)}
        if k not in got:
            break
        stats[k] = _statistic(res, got[k], n, k)
        if samples != "auto":
            break
        if 4 * k not in got:
            break
        a1, e1 = stats[k]
        a4, e4 = _statistic(res, got[4 * k], n, 4 * k)
        ratio = a1 / (4.0 * a4)
        if abs(ratio - 1.0) <= WHITE_Z * ratio * math.sqrt(2.0 / e1 + 2.0 / e4):
            chosen, white = k, True
            break
    if samples != "auto":
        white = True  # the caller chose the scale
    if chosen not in stats:
        raise InputError(f"fine scale of {chosen} sample(s): record too short")
    avar, edf = stats[chosen]
    if not np.isfinite(avar) or avar <= 0:
        raise InputError("fine-scale Allan variance is zero or undefined: the channel is constant")
    return FineScale(chosen / fs_hz, avar, 2.0 * avar * avar / edf, edf, chosen, white)


def _gm_unit_avar(tau_b: np.ndarray, tau: float, fs_hz: float) -> np.ndarray:
    """AVAR at ``tau`` (s) of the sampled Gauss-Markov bias with sigma_b = 1, for an array of tau_b (s).

    The exact sampled-AR(1) form of :meth:`~.noise_models.GaussMarkov.avar`
    (Algorithm 1), vectorised over tau_b.
    """
    dt = 1.0 / fs_hz
    n = tau / dt
    d = dt / tau_b
    phi = np.exp(-d)
    om = -np.expm1(-d)
    g = -np.expm1(-n * d) / om
    n_minus_g = (expm1_tail(n * d) - n * expm1_tail(d)) / om  # n - g without cancellation
    s2 = tau_b / 2.0
    return s2 / n**2 * (n + 2.0 * phi * n_minus_g / om - phi * g * g)


class _CompositeProblem(Problem):
    """ML_i's batched likelihood plus the fine-scale term; sigma_w^2 profiled by a cubic."""

    def __init__(self, inc: Increments, spec: ParamSpec, fine: FineScale, filt: str = "auto"):
        super().__init__(inc, spec, filt)
        self.fine = fine

    def unit_avar(self, theta: np.ndarray) -> np.ndarray:
        """Model AVAR at the fine scale with sigma_w = 1, for theta (K, d)."""
        tau_f, fs = self.fine.tau, self.inc.fs_hz
        if self.spec.fast:
            return 1.0 / tau_f + np.exp(theta[:, 0]) * _gm_unit_avar(np.exp(theta[:, 1]), tau_f, fs)
        out = np.empty(theta.shape[0])
        for i, th in enumerate(theta):
            phi = self.spec.phi_of_theta(th, 1.0)
            with np.errstate(all="ignore"):
                v = float(self.spec.model(phi, 0.0).avar(np.array([tau_f]), fs)[0])
            out[i] = v if np.isfinite(v) else np.inf
        return out

    def sigma_w2(self, prof: Profile, A: np.ndarray) -> np.ndarray:
        """Maximiser over s = sigma_w^2 of the composite likelihood: root of
        (A^2/V) s^3 - (A D/V) s^2 + dof/2 s - S/2 = 0 (Newton from s = D/A, monotone)."""
        D, V = self.fine.avar, self.fine.var
        dof = prof.m - 1
        S = prof.s_tilde
        s = D / A
        for _ in range(30):
            f = (A * A / V) * s**3 - (A * D / V) * s**2 + 0.5 * dof * s - 0.5 * S
            fp = 3.0 * (A * A / V) * s**2 - 2.0 * (A * D / V) * s + 0.5 * dof
            step = f / fp
            s = np.maximum(s - step, 0.5 * s)
            if np.all(np.abs(step) <= 1e-13 * s):
                break
        return s

    def _composite(self, prof: Profile, A: np.ndarray, s: np.ndarray) -> np.ndarray:
        fine = (self.fine.avar - s * A) ** 2 / (2.0 * self.fine.var)
        return full_nll(prof, s) + fine

    def nll(self, theta: np.ndarray) -> np.ndarray:
        theta = np.atleast_2d(theta)
        with np.errstate(all="ignore"):
            prof = self.profile(theta)
            A = self.unit_avar(theta)
            out = self._composite(prof, A, self.sigma_w2(prof, A))
        return np.where(np.isfinite(out), out, np.inf)

    def full_nll(self, phi: np.ndarray) -> np.ndarray:
        phi = np.atleast_2d(phi)
        theta = self.spec.theta_of_phi(phi)
        with np.errstate(all="ignore"):
            out = self._composite(self.profile(theta), self.unit_avar(theta), np.exp(2.0 * phi[:, 0]))
        return np.where(np.isfinite(out), out, np.inf)


@dataclass(frozen=True)
class CompositeResult(MLiResult):
    """:class:`~.mli.MLiResult` of the composite estimator plus its fine-scale diagnostics.

    ``fine_scale_tau`` (s) and ``fine_scale_avar`` ((rate unit)^2): the statistic
    used; ``integrated_sigma_w`` the integrated likelihood's own sigma_w at the
    optimum; ``fine_scale_z`` the standardised difference of the two (|z| >
    ``FINE_SCALE_Z_LIMIT``: the noise is not white at the fine scale).
    ``data_time_s``: the data passes (integration and fine-scale AVAR), s.
    ``as_dict`` keeps the keys of ML_i's block (the JSON contract); a fine-scale
    disagreement shows in ``message`` and ``converged``.
    """

    fine_scale_tau: float = math.nan
    fine_scale_avar: float = math.nan
    integrated_sigma_w: float = math.nan
    fine_scale_z: float = math.nan
    data_time_s: float = math.nan


def fit_composite_data(
    inc: Increments,
    fine: FineScale,
    model: str = "wn+gm",
    *,
    single_start: bool = False,
) -> CompositeResult:
    """Fit ``model`` to a pattern-integrated record plus its fine-scale statistic.

    ``single_start``: search from the Allan start point alone (what a one-start
    fit would do; the Monte Carlo study counts how often that ends elsewhere).
    """
    t0 = time.perf_counter()
    spec = ParamSpec(parse_model(model))
    if len(inc.y) < 4 + 2 * spec.d:
        raise InputError(f"only {len(inc.y)} pattern intervals: too few for model {spec.name!r}")
    problem = _CompositeProblem(inc, spec, fine)
    allan = allan_start(inc, spec, quick=spec.fast)
    if single_start:
        starts = allan[:1]
    else:
        starts = (grid_start(problem) + allan) if spec.fast else allan
    best, n_starts = optimise(problem, starts)
    theta = best.x
    prof = problem.profile(theta[None, :])
    A = problem.unit_avar(theta[None, :])
    s = float(problem.sigma_w2(prof, A)[0])
    res = build_result(problem, theta, best, n_starts, t0, ESTIMATOR, len(inc.y), inc.pattern, inc.n, inc.fs_hz, s)
    ci90 = dict(res.ci90)
    if spec.fast:
        # profile-likelihood intervals for the bias parameters: the likelihood in
        # log tau_b is skewed, the symmetric (Wald) interval under-covers (docs/noise-model.md)
        (lo_r, hi_r), (lo_t, hi_t) = _profile_intervals(problem, theta, best.fun)
        if math.isfinite(lo_r) or math.isfinite(hi_r):
            sw = math.sqrt(s)
            ci90["sigma_b"] = (sw * math.exp(0.5 * lo_r), sw * math.exp(0.5 * hi_r))
        if math.isfinite(lo_t) or math.isfinite(hi_t):
            ci90["tau_b"] = (math.exp(lo_t), math.exp(hi_t))
    # the integrated likelihood's own sigma_w and its standard error (chi-square, M - 1 dof)
    s_int = float(prof.s_tilde[0] / (prof.m - 1))
    se_int = s_int * math.sqrt(2.0 / (prof.m - 1))
    s_fine = fine.avar / float(A[0])
    z = (s_fine - s_int) / math.hypot(se_int, math.sqrt(fine.var) / float(A[0]))
    message = res.message
    if not fine.white:
        message += (
            f"; noise not white at any fine scale up to {4 * fine.samples} samples (device filter?): "
            "sigma_w is biased - give fine_samples"
        )
    elif fine.samples > 1:
        message += f"; fine scale raised to {fine.samples} samples: noise not white at the sample scale"
    if abs(z) > FINE_SCALE_Z_LIMIT:
        message += (
            f"; fine-scale AVAR disagrees with the integrated signal (z = {z:+.1f}): noise not white at "
            f"{fine.tau:.3g} s (device low-pass filter?) - raise fine_samples"
        )
    base = {f.name: getattr(res, f.name) for f in fields(MLiResult)}
    base |= {
        "ci90": ci90,
        "message": message,
        "converged": res.converged and abs(z) <= FINE_SCALE_Z_LIMIT and fine.white,
        "fit_time_s": time.perf_counter() - t0,
    }
    return CompositeResult(
        **base,
        fine_scale_tau=fine.tau,
        fine_scale_avar=fine.avar,
        integrated_sigma_w=math.sqrt(s_int),
        fine_scale_z=z,
    )


#: profile points, in observed-information standard errors of the fixed coordinate
_PROFILE_AT = np.array([-3.0, -2.0, -1.2, 1.2, 2.0, 3.0])
#: nll rise (nats) standing in for an undefined likelihood at a profile point (a 90 % end is at 1.35)
_DROP_CAP = 1e6


def _profile_intervals(problem: _CompositeProblem, theta: np.ndarray, f_hat: float) -> list[tuple[float, float]]:
    """90 % profile-likelihood intervals of both search coordinates (log r, log tau) of the standard model.

    For each coordinate the other one is re-optimised (batched 1-d Newton, both
    coordinates and all points in one likelihood batch) at -3..3 observed-information
    standard errors; the ends are where the signed root of 2 (profile nll - min)
    crosses +-Z90 (interpolated, extrapolated past 3 se from the last two points).
    An end beyond the search box is the box edge; (nan, nan) when the curvature
    at the optimum is not usable.
    """
    h = 0.02
    f = problem.nll(theta[None, :] + stencil(2) * h)
    H = fd_derivatives(f, 2, h)[2]
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return [(math.nan, math.nan)] * 2
    lo, hi = problem.lo, problem.hi
    P = len(_PROFILE_AT)
    fixed = np.empty((2, P))  # coordinate j's value at each point
    free = np.empty((2, P))  # the other coordinate, optimised
    usable = [bool(cov[j, j] > 0 and np.isfinite(cov[j, j])) for j in range(2)]
    for j in range(2):
        o = 1 - j
        se = math.sqrt(cov[j, j]) if usable[j] else 1.0
        fixed[j] = np.clip(theta[j] + _PROFILE_AT * se, lo[j], hi[j])
        # the conditional optimum of the free coordinate along the quadratic model; where the
        # likelihood is flat or curved down along it (a fit at a bound) the model has none: start at theta
        tilt = H[o, j] / H[o, o] if H[o, o] > 0 else 0.0
        free[j] = np.clip(theta[o] - tilt * (fixed[j] - theta[j]), lo[o], hi[o])

    def points(offset: float) -> np.ndarray:
        pts = np.empty((2, P, 2))
        pts[0, :, 0], pts[0, :, 1] = fixed[0], free[0] + offset
        pts[1, :, 1], pts[1, :, 0] = fixed[1], free[1] + offset
        return pts.reshape(-1, 2)

    for _ in range(4):
        v = problem.nll(np.vstack([points(0.0), points(h), points(-h)])).reshape(3, 2, P)
        # a stencil touching the likelihood's undefined region (nll = inf) gives no Newton step: the point stays
        fin = np.isfinite(v).all(axis=0)
        v = np.where(fin, v, 0.0)
        g = (v[1] - v[2]) / (2 * h)
        c = (v[1] - 2 * v[0] + v[2]) / h**2
        step = np.where(c > 0, -g / np.where(c > 0, c, 1.0), -np.sign(g) * 0.5) * fin
        for j in range(2):
            o = 1 - j
            free[j] = np.clip(free[j] + np.clip(step[j], -1.0, 1.0), lo[o], hi[o])
    prof = problem.nll(points(0.0)).reshape(2, P)
    out = []
    for j in range(2):
        if not usable[j]:
            out.append((math.nan, math.nan))
            continue
        # points clipped onto the optimum (a coordinate at its bound) carry no side: left out
        off = fixed[j] != theta[j]
        x = np.concatenate([fixed[j][off], [theta[j]]])
        pj = prof[j][off]
        # an undefined likelihood (inf) is far outside any interval: capped, so the interpolation stays finite
        drop = np.minimum(
            np.maximum(np.concatenate([pj, [f_hat]]) - min(f_hat, float(pj.min(initial=f_hat))), 0), _DROP_CAP
        )
        r = np.sign(x - theta[j]) * np.sqrt(2.0 * drop)
        ends = []
        for side, target in ((x <= theta[j], -Z90), (x >= theta[j], Z90)):
            xs, rs = x[side], r[side]
            order = np.argsort(rs)
            xs, rs = xs[order], rs[order]
            if len(xs) < 2:  # no profile point on this side: the optimum is at the box edge
                ends.append(float(lo[j] if target < 0 else hi[j]))
                continue
            if rs[0] <= target <= rs[-1]:
                ends.append(float(np.interp(target, rs, xs)))
                continue
            # beyond the outermost point: extrapolate from the two outermost ones
            i0, i1 = (0, 1) if target < 0 else (-1, -2)
            slope = (rs[i0] - rs[i1]) / (xs[i0] - xs[i1]) if xs[i0] != xs[i1] else 0.0
            edge = float(lo[j] if target < 0 else hi[j])
            ends.append(float(np.clip(xs[i0] + (target - rs[i0]) / slope, lo[j], hi[j])) if slope > 0 else edge)
        out.append((ends[0], ends[1]))
    return out


def fit_composite(
    rate: np.ndarray,
    fs_hz: float,
    model: str = "wn+gm",
    *,
    pattern: str = "uniform",
    m: int = DEFAULT_M,
    fine_samples: int | str = "auto",
    scale: float = 1.0,
    segments: list[tuple[int, int]] | None = None,
    single_start: bool = False,
) -> CompositeResult:
    """ML_i-F fit of a rate noise model with turn-on bias.

    Parameters
    ----------
    rate : (n,) rate samples in rad/s (or m/s^2), or integer counts with ``scale``
        (units per count), summed exactly.
    fs_hz : sampling rate, Hz.
    model : as :func:`~.mli.fit_mli` (``"wn+gm"`` the paper's standard model).
    pattern, m : sampling pattern of the integrated likelihood (``"uniform"``,
        1000 intervals by default; ``"log"`` is ML_i's).
    fine_samples : cluster size of the fine-scale AVAR, samples, or ``"auto"``: the
        smallest of 1, 2, 4, ... 256 at which the noise passes a whiteness test
        (a device filter below Nyquist makes the sample scale non-white); a size
        above 1 is named in ``message``.
    segments : contiguous sample ranges ``[start, end)`` with data.

    Returns
    -------
    CompositeResult: ``sigma_w`` (rad s^-1/sqrt(Hz)), ``sigma_b`` (rad s^-2/sqrt(Hz)),
    ``tau_b`` (s), ``b_on`` (rad/s), ``stderr``, ``ci90``, diagnostics.
    """
    parse_model(model)
    rate = check_rate(rate, fs_hz)
    if fine_samples != "auto" and not (isinstance(fine_samples, int) and fine_samples >= 1):
        raise InputError(f"fine_samples = {fine_samples!r}: use 'auto' or a whole number of samples >= 1")
    t0 = time.perf_counter()
    m_eff = int(min(m, max(8, len(rate) // 2)))
    inc = integrate(rate, fs_hz, m=m_eff, pattern=pattern, scale=scale, segments=segments)
    fine = fine_scale(rate, fs_hz, samples=fine_samples, scale=scale, segments=segments)
    data_time = time.perf_counter() - t0
    res = fit_composite_data(inc, fine, model, single_start=single_start)
    return replace(res, data_time_s=data_time)
