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

from imustation.analysis.estimators.engine.fitting import (
    Z90,
    MLiResult,
    ParamSpec,
    Problem,
    build_result,
    full_nll,
    optimise,
)
from imustation.analysis.estimators.engine.kalman import Profile
from imustation.analysis.estimators.engine.newton import fd_derivatives, stencil
from imustation.analysis.estimators.engine.pattern import Increments, check_rate, integrate
from imustation.analysis.estimators.ml.finescale import (  # noqa: F401 - re-exported: the statistic's old home
    AUTO_SAMPLES,
    SLOW_SHARE,
    WHITE_Z,
    FilterHint,
    FineScale,
    FineStatistic,
    fine_scale,
    fine_statistics,
)
from imustation.analysis.estimators.ml.mli import allan_start, grid_start
from imustation.analysis.estimators.models.noise_models import gm_unit_avar as _gm_unit_avar
from imustation.analysis.estimators.models.noise_models import parse_model
from imustation.errors import InputError, RecordTooShort

ESTIMATOR = "ML_i-F"
#: default uniform pattern: 1000 intervals = 43 s on a 12 h record (2000 gave the same errors
#: at twice the cost: docs/noise-model.md)
DEFAULT_M = 1000
#: |z| above which the fine-scale and integrated sigma_w disagree (reported)
FINE_SCALE_Z_LIMIT = 4.0


class CompositeProblem(Problem):
    """ML_i's batched likelihood plus the fine-scale term; sigma_w^2 profiled by a cubic.

    The fine-scale term is ``(D - s A)^T W (D - s A) / 2`` for the Allan variances ``D``
    at the fine cluster times and the model's ``A`` at sigma_w = 1: with one scale
    ``(D - s A)^2 / (2 V)``; with the model family's statistic (five octaves) ``W`` is
    their inverse covariance with a floor and a rising term projected out
    (:meth:`~.finescale.FineStatistic.weight`).
    """

    def __init__(self, inc: Increments, spec: ParamSpec, fine: FineScale | FineStatistic, filt: str = "auto"):
        super().__init__(inc, spec, filt)
        self.fine = fine
        if isinstance(fine, FineScale):
            self.taus, self.D = np.array([fine.tau]), np.array([fine.avar])
            self.Cinv = np.array([[1.0 / fine.var]])
        else:
            self.taus, self.D, self.Cinv = fine.taus, fine.avar, fine.weight()

    def unit_avar(self, theta: np.ndarray) -> np.ndarray:
        """Model AVAR at the fine scales with sigma_w = 1, for theta (K, d): (K, J)."""
        fs = self.inc.fs_hz
        if self.spec.fast and len(self.taus) == 1:
            tau_f = float(self.taus[0])
            return (1.0 / tau_f + np.exp(theta[:, 0]) * _gm_unit_avar(np.exp(theta[:, 1]), tau_f, fs))[:, None]
        out = self.spec.unit_avar(theta, self.taus, fs)
        return np.where(np.isfinite(out), out, np.inf)

    def _forms(self, A: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``A^T C^-1 A``, ``A^T C^-1 D`` (K,) and ``D^T C^-1 D``."""
        AC = A @ self.Cinv
        return np.sum(AC * A, axis=1), AC @ self.D, float(self.D @ self.Cinv @ self.D)

    def sigma_w2(self, prof: Profile, A: np.ndarray) -> np.ndarray:
        """Maximiser over s = sigma_w^2 of the composite likelihood: root of
        a s^3 - b s^2 + dof/2 s - S/2 = 0 with a = A^T C^-1 A, b = A^T C^-1 D
        (Newton from s = b/a, monotone)."""
        a, b, _ = self._forms(A)
        dof = prof.m - 1
        S = prof.s_tilde
        s = b / a
        for _ in range(30):
            f = a * s**3 - b * s**2 + 0.5 * dof * s - 0.5 * S
            fp = 3.0 * a * s**2 - 2.0 * b * s + 0.5 * dof
            step = f / fp
            s = np.maximum(s - step, 0.5 * s)
            if np.all(np.abs(step) <= 1e-13 * s):
                break
        return s

    def fine_nll(self, A: np.ndarray, s: np.ndarray) -> np.ndarray:
        """The fine-scale term at sigma_w^2 = s (K,)."""
        a, b, c = self._forms(A)
        return 0.5 * (c - 2.0 * s * b + s * s * a)

    def _composite(self, prof: Profile, A: np.ndarray, s: np.ndarray) -> np.ndarray:
        return full_nll(prof, s) + self.fine_nll(A, s)

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
    used (its first scale); ``integrated_sigma_w`` the integrated likelihood's own
    sigma_w at the optimum; ``fine_scale_z`` the standardised difference of the two
    (|z| > ``FINE_SCALE_Z_LIMIT``: the noise is not white at the fine scale).
    ``data_time_s``: the data passes (integration and fine-scale AVAR), s.
    The robust intervals, ``ci90_model``, ``cov_log`` and ``memory_s`` are
    :class:`~.fitting.MLiResult`'s. ``as_dict`` keeps the keys of ML_i's block (the
    JSON contract); a fine-scale disagreement shows in ``message`` and ``converged``.
    """

    fine_scale_tau: float = math.nan
    fine_scale_avar: float = math.nan
    integrated_sigma_w: float = math.nan
    fine_scale_z: float = math.nan
    data_time_s: float = math.nan


def fit_composite_data(
    inc: Increments,
    fine: FineScale | FineStatistic,
    model: str | ParamSpec = "wn+gm",
    *,
    single_start: bool = False,
    extra_starts: list[np.ndarray] | None = None,
    starts_only: bool = False,
    robust: bool = False,
    max_iter: int = 50,
) -> CompositeResult:
    """Fit ``model`` (a name, or a :class:`ParamSpec` for settings such as a flicker cut-off) to a
    pattern-integrated record plus its fine-scale statistic.

    ``fine``: :func:`fine_scale` (one scale) or :func:`~.finescale.fine_statistics`
    (needed by models with a device filter ``lp``). ``single_start``: search from the
    Allan start point alone (what a one-start fit would do; the Monte Carlo study
    counts how often that ends elsewhere). ``extra_starts``: more start points
    (theta); ``starts_only``: search from those alone. ``robust``: intervals that
    account for model misfit (:mod:`.robust`). ``max_iter``: Newton steps per start.
    """
    t0 = time.perf_counter()
    spec = model.with_record(inc.fs_hz, inc.duration) if isinstance(model, ParamSpec) else (
        ParamSpec.for_record(model, inc.fs_hz, inc.duration)
    )  # fmt: skip
    if len(inc.y) < 4 + 2 * spec.d:
        raise InputError(f"only {len(inc.y)} pattern intervals: too few for model {spec.name!r}")
    multi = isinstance(fine, FineStatistic)
    # the model holds from the statistic's first scale on: a filter's memory, or beyond a resonance
    memory = fine.memory_s if multi and (fine.term or fine.excluded_s > 0) else 0.0
    if "lp" in spec.codes:
        if not (multi and len(fine.taus) > 1):
            raise InputError(
                f"model {spec.name!r}: the data show no device filter at the fine scales (the two-scale statistic "
                f"finds the sample-scale noise white: nothing to fit an lp term to): use the model without lp, or auto"
            )
        if float(inc.dt.min()) < 10.0 * memory:
            raise RecordTooShort(f"pattern intervals of {inc.dt.min():.3g} s: too short against the filter's memory")
    if multi and fine.term and ("lp" in spec.codes or "wa" in spec.codes):
        spec = replace(spec, angle_scale=angle_scale(fine))
    problem = CompositeProblem(inc, spec, fine)
    spec = problem.spec
    if starts_only:
        starts = []
    elif single_start:
        starts = allan_start(inc, spec, quick=spec.fast)[:1]
    else:
        allan = allan_start(inc, spec, quick=spec.fast)
        starts = (grid_start(problem) + allan) if spec.fast else allan
    starts += [np.clip(x, problem.lo, problem.hi) for x in extra_starts or []]
    if not starts:
        raise InputError(f"model {spec.name!r}: no start point")
    best, n_starts = optimise(problem, starts, max_iter)
    theta = best.x
    prof = problem.profile(theta[None, :])
    A = problem.unit_avar(theta[None, :])
    s = float(problem.sigma_w2(prof, A)[0])
    res = build_result(
        problem, theta, best, n_starts, t0, ESTIMATOR, len(inc.y), inc.pattern, inc.n, inc.fs_hz, s,
        robust=robust, memory_s=memory,
    )  # fmt: skip
    ci90, ci90_model = dict(res.ci90), dict(res.ci90_model)
    if spec.fast:
        # profile-likelihood intervals for the bias parameters: the likelihood in
        # log tau_b is skewed, the symmetric (Wald) interval under-covers (docs/noise-model.md);
        # a robust fit keeps the wider of the profile interval and its sandwich one
        ends = _profile_intervals(problem, theta, best.fun)
        sw = math.sqrt(s)
        for key, (lo, hi), f in (("sigma_b", ends[0], lambda x: sw * math.exp(0.5 * x)), ("tau_b", ends[1], math.exp)):
            if not (math.isfinite(lo) or math.isfinite(hi)):
                continue
            ci90_model[key] = (f(lo), f(hi))
            ci90[key] = ci90_model[key]
            if robust:
                ci90[key] = (min(f(lo), res.ci90[key][0]), max(f(hi), res.ci90[key][1]))
    # the integrated likelihood's own sigma_w and its standard error (chi-square, M - 1 dof)
    s_int = float(prof.s_tilde[0] / (prof.m - 1))
    se_int = s_int * math.sqrt(2.0 / (prof.m - 1))
    a, b, _ = problem._forms(A)
    s_fine = float(b[0] / a[0])
    z = (s_fine - s_int) / math.hypot(se_int, 1.0 / math.sqrt(float(a[0])))
    message = res.message + _fine_message(fine)
    if multi and fine.slow_share > SLOW_SHARE and math.isfinite(fine.white_bound[0]):
        # sigma_w rests on the slow terms' shape below the fine scales, which nothing measures: its
        # interval reaches up to the bound that needs no model of them (finescale.white_bound)
        U, se = fine.white_bound
        top = math.sqrt(max(U + Z90 * se, 0.0))
        lo, hi = ci90.get("sigma_w", (math.nan, math.nan))
        ci90["sigma_w"] = (lo, top if not math.isfinite(hi) else max(hi, top))
        message += (
            f"; sigma_w <= {top:.4g} (90 % upper end) from the Allan variances at {fine.bound_samples} and "
            f"{2 * fine.bound_samples} samples, where the slow terms can only add: its interval reaches it"
        )
    if abs(z) > FINE_SCALE_Z_LIMIT:
        message += (
            f"; fine-scale AVAR disagrees with the integrated signal (z = {z:+.1f}): noise not white at "
            f"{problem.taus[0]:.3g} s (device low-pass filter?) - raise fine_samples"
        )
    white = fine.linear if multi else fine.white
    base = {f.name: getattr(res, f.name) for f in fields(MLiResult)}
    base |= {
        "ci90": ci90,
        "ci90_model": ci90_model if robust else {},
        "message": message,
        "converged": res.converged and abs(z) <= FINE_SCALE_Z_LIMIT and white,
        "fit_time_s": time.perf_counter() - t0,
    }
    return CompositeResult(
        **base,
        fine_scale_tau=float(problem.taus[0]),
        fine_scale_avar=float(problem.D[0]),
        integrated_sigma_w=math.sqrt(s_int),
        fine_scale_z=z,
    )


def angle_scale(fine: FineStatistic) -> float:
    """Stretch of the angle-noise search coordinate (:class:`~.paramspec.ParamSpec`): the Newton's
    finite-difference step then moves it by a tenth of its standard error (~1/z in log)."""
    return float(np.clip(5.0 / max(abs(fine.angle_z), 1.0), 1e-3, 1.0))


def _fine_message(fine: FineScale | FineStatistic) -> str:
    if isinstance(fine, FineScale):
        if not fine.white:
            return (
                f"; noise not white at any fine scale up to {4 * fine.samples} samples (device filter?): "
                "sigma_w is biased - give fine_samples"
            )
        if fine.samples > 1:
            return f"; fine scale raised to {fine.samples} samples: noise not white at the sample scale"
        return ""
    out = ""
    if fine.slow_share > SLOW_SHARE:
        out += (
            f"; slow terms reach the fine scales ({100 * fine.slow_share:.0f} % of the white noise at "
            f"{fine.taus[0]:.3g} s): sigma_w rests on their shape below that scale - check it"
        )
    if not fine.linear:
        out += f"; noise not white up to an angle term at any fine scale up to {4 * fine.samples} samples"
    if fine.term == "lp":
        out += (
            f"; device filter: tau_lp {fine.tau_lp * 1e3:.3g} ms from the Allan variance at {fine.samples} and "
            f"{2 * fine.samples} samples ({fine.source}); model exact from {fine.memory_s:.3g} s"
        )
    elif fine.samples > 1:
        out += f"; fine scale at {fine.samples} samples: noise not white at the sample scale"
    return out


#: profile points, in observed-information standard errors of the fixed coordinate
_PROFILE_AT = np.array([-3.0, -2.0, -1.2, 1.2, 2.0, 3.0])
#: nll rise (nats) standing in for an undefined likelihood at a profile point (a 90 % end is at 1.35)
_DROP_CAP = 1e6


def _profile_intervals(problem: CompositeProblem, theta: np.ndarray, f_hat: float) -> list[tuple[float, float]]:
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
    robust: bool = False,
    hint: FilterHint | None = None,
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
        Models with a device filter (``lp``) or white angle noise (``wa``) use the
        two-scale statistic of :func:`~.finescale.fine_statistics` instead, which
        finds its scale itself (``hint``: the device's filter settings).
    segments : contiguous sample ranges ``[start, end)`` with data.
    robust : intervals that account for model misfit (:mod:`.robust`).

    Returns
    -------
    CompositeResult: ``sigma_w`` (rad s^-1/sqrt(Hz)), ``sigma_b`` (rad s^-2/sqrt(Hz)),
    ``tau_b`` (s), ``b_on`` (rad/s), ``stderr``, ``ci90``, diagnostics.
    """
    codes = parse_model(model)
    rate = check_rate(rate, fs_hz)
    if fine_samples != "auto" and not (isinstance(fine_samples, int) and fine_samples >= 1):
        raise InputError(f"fine_samples = {fine_samples!r}: use 'auto' or a whole number of samples >= 1")
    t0 = time.perf_counter()
    m_eff = int(min(m, max(8, len(rate) // 2)))
    inc = integrate(rate, fs_hz, m=m_eff, pattern=pattern, scale=scale, segments=segments)
    if "lp" in codes or "wa" in codes:
        fine = fine_statistics(rate, fs_hz, scale=scale, segments=segments, hint=hint)
    else:
        fine = fine_scale(rate, fs_hz, samples=fine_samples, scale=scale, segments=segments)
    data_time = time.perf_counter() - t0
    res = fit_composite_data(inc, fine, model, single_start=single_start, robust=robust)
    return replace(res, data_time_s=data_time)
