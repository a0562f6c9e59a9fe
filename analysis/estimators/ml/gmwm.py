"""Generalized Method of Wavelet Moments (GMWM; Guerrier et al. 2013, JASA 108(503)).

Haar wavelet variance (WV) of rate samples at dyadic scales ``tau_j = 2^j`` samples
(docs/reference/noise-formulas.md §4): the MODWT Haar coefficient is half the difference of two
adjacent means of ``m = 2^(j-1)`` samples, so

    nu^2(tau_j) = AVAR(m = tau_j/2) / 2

and the unbiased MODWT estimator (no boundary coefficients, ``M_j = N - tau_j + 1``
terms) is exactly half the fully overlapping Allan variance at ``m = 2^(j-1)``.
:func:`wavelet_variance` therefore reuses :func:`imustation.analysis.estimators.classical.allan.oadev`
(numba kernels, integer counts, gaps) instead of another pass over the data, and
the theoretical WV of a model is half the exact sampled AVAR of
:mod:`imustation.analysis.estimators.models.noise_models` (``avar(tau, fs_hz)``).

Confidence intervals: chi-square with the equivalent degrees of freedom
``eta_j = max(M_j / 2^j, 1)`` (Percival & Walden 2000, *Wavelet Methods for Time
Series Analysis*, eq. 314c, "eta_3").

Estimator: ``theta_hat = argmin (nu_hat - nu(theta))^T Omega (nu_hat - nu(theta))`` in
log-parameters with ``Omega = diag(1/Var nu_hat_j)``, ``Var nu_hat_j = 2 nu_j^4 / eta_j``
(chi-square). The full optimal ``Omega`` (inverse of the complete covariance of
``nu_hat`` across scales, simts' default) needs that covariance, which for a
Gaussian process is a sum over all pairs of wavelet coefficients per pair of
scales, or a parametric bootstrap of the fitted model; neither is affordable for a
12 h record at 400 Hz inside one fit, and the diagonal is the usual simplification
(docs/reference/noise-formulas.md §4). To avoid the downward bias of weights built from the noisy
``nu_hat_j`` themselves (small estimates get large weights), the weights are
recomputed from the fitted model ``nu_j(theta_hat)`` and the fit repeated
(``reweight`` times).

Starts: the model WV is linear in the variances for fixed correlation times, so
for every point of a log grid of correlation times (80 points for one
Gauss-Markov term) the variances are a weighted non-negative least-squares
solution; the best grid point starts a bounded Gauss-Newton refinement
(``scipy.optimize.least_squares``) in all log-parameters. ``starts="single"``
instead starts once, with ``tau_b`` at the scale of the smallest WV: kept to count
how often a single heuristic start ends in a worse local minimum (docs/gmwm.md).

Uncertainties: ``(J^T Omega J)^{-1}`` with ``J = d nu / d log theta`` at the optimum,
i.e. the sandwich ``(J^T W J)^-1 J^T W V W J (J^T W J)^-1`` with ``W = V^-1`` and ``V``
the (model-based, diagonal) covariance of ``nu_hat``: cross-scale correlations of
``nu_hat`` are neglected, so the intervals are approximate (coverage measured in
docs/study.md).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares, nnls

from imustation.analysis.estimators.classical.allan import chi2_bounds, oadev
from imustation.analysis.estimators.engine.fitting import MLiResult, ParamSpec, intervals
from imustation.analysis.estimators.models.noise_models import (
    GaussMarkov,
    NoiseModel,
    RandomWalk,
    WhiteAngle,
    WhiteRate,
    parse_model,
)
from imustation.analysis.estimators.models.sensor_terms import BiasInstability, LowPass
from imustation.errors import InputError

#: default probability mass inside [wv_lo, wv_hi]
WV_CONFIDENCE = 0.95
#: correlation-time grid points per Gauss-Markov term (1, 2, 3 terms)
GRID_POINTS = {1: 80, 2: 40, 3: 16}
#: variance search box relative to the variance at which a term alone explains the largest WV
_Q_BOX = (1e-10, 1e4)
START_KINDS = ("grid", "single")


@dataclass(frozen=True)
class WVResult:
    """Haar (MODWT) wavelet variance of rate samples.

    ``level`` j = 1..J; ``scale`` tau_j = 2^j in samples and ``tau`` = tau_j/fs in s;
    ``wv`` nu_hat^2 in (rate unit)^2 (per-sample units, e.g. (rad/s)^2);
    ``wv_lo``/``wv_hi`` the chi-square interval of probability ``confidence``;
    ``edf`` eta_j; ``n`` the number of MODWT coefficients M_j averaged.
    """

    level: np.ndarray
    scale: np.ndarray
    tau: np.ndarray
    wv: np.ndarray
    wv_lo: np.ndarray
    wv_hi: np.ndarray
    edf: np.ndarray
    n: np.ndarray
    fs_hz: float
    confidence: float = WV_CONFIDENCE


def wavelet_variance(
    rate: np.ndarray,
    fs_hz: float,
    *,
    scale: float = 1.0,
    segments: Sequence[tuple[int, int]] | None = None,
    confidence: float = WV_CONFIDENCE,
) -> WVResult:
    """Haar wavelet variance at every dyadic scale that fits the longest segment.

    Parameters
    ----------
    rate : (n,) rate samples (rad/s, m/s^2, ...) or integer counts with ``scale``.
    fs_hz : sampling rate, Hz.
    scale : units per count for integer input.
    segments : contiguous sample ranges ``(start, stop)`` with data; no wavelet
        coefficient spans a gap (pooled as in :func:`~imustation.analysis.estimators.classical.allan.oadev`).
    confidence : probability of the chi-square interval (0 < confidence < 1).
    """
    if not 0.0 < confidence < 1.0:
        raise InputError(f"confidence = {confidence}: must lie strictly between 0 and 1")
    rate = np.asarray(rate)
    if rate.ndim != 1:
        raise InputError(f"rate must be one-dimensional, got shape {rate.shape}")
    longest = len(rate)
    if segments is not None:
        seg = np.asarray(list(segments), dtype=np.int64).reshape(-1, 2)
        longest = int(np.max(seg[:, 1] - seg[:, 0])) if len(seg) else 0
    # oadev needs N - 2m >= 2 terms, i.e. tau_j = 2m <= longest - 1
    J = int(math.floor(math.log2(longest - 1))) if longest >= 3 else 0
    if J < 1:
        raise InputError(f"{longest} samples in the longest segment: a wavelet variance needs at least 3")
    m = 2 ** np.arange(J, dtype=np.int64)  # 2^(j-1), j = 1..J
    av = oadev(rate, fs_hz, m / float(fs_hz), scale=scale, segments=segments)
    wv = 0.5 * av.adev**2
    counts = np.asarray(av.n, dtype=float)
    tau_j = 2 * m[: len(wv)]
    edf = np.maximum(counts / tau_j, 1.0)  # Percival & Walden eq. 314c
    lo, hi = chi2_bounds(np.sqrt(wv), edf, confidence)
    level = np.arange(1, len(wv) + 1)
    return WVResult(level, tau_j, tau_j / float(fs_hz), wv, lo**2, hi**2, edf, counts, float(fs_hz), confidence)


def model_wv(model: NoiseModel, scale: np.ndarray, fs_hz: float) -> np.ndarray:
    """Theoretical Haar WV of ``model`` at ``scale`` tau_j (samples): half its exact sampled AVAR at tau_j/2."""
    scale = np.asarray(scale, dtype=float)
    return 0.5 * model.avar(0.5 * scale / fs_hz, fs_hz)


# ---------------------------------------------------------------------------
# the estimator


def _unit_terms(spec: ParamSpec, taus: Sequence[float]) -> list:
    """Terms of unit variance (sigma = 1) in the layout of ``spec``; ``taus`` for the GM terms.

    Bias instability: ``q = B^2``; device filter: ``q = sigma_w^2 tau_lp``, its
    Allan variance ``-1.5 q / tau^2`` beyond the filter's memory (a negative column).
    """
    out: list = [WhiteRate(1.0)]
    k = 0
    for c in spec.others:
        if c == "gm":
            out.append(GaussMarkov(1.0, float(taus[k])))
            k += 1
        elif c == "rw":
            out.append(RandomWalk(1.0))
        elif c == "fl":
            out.append(BiasInstability(1.0, spec.flicker_times))
        elif c == "lp":
            out.append(LowPass(1.0, 1.0, memory_s=1e-300))  # beyond the memory at every scale fitted
        else:
            out.append(WhiteAngle(1.0))
    return out


class _WVProblem:
    """Design of the WV fit: nu(theta) = A(tau_b's) q with q the term variances."""

    def __init__(self, wv: WVResult, spec: ParamSpec, duration_s: float):
        self.wv, self.spec = wv, spec
        self.t_half = 0.5 * wv.scale / wv.fs_hz  # AVAR cluster time of each scale, s
        self.n_gm = spec.codes.count("gm")
        self.gm_cols = [i for i, c in enumerate(("wn", *spec.others)) if c == "gm"]
        self.tau_lo = 2.0 / wv.fs_hz
        self.tau_hi = 100.0 * duration_s
        # variance at which each term alone reaches the largest WV (scale of the search box)
        A = np.abs(self.design([math.sqrt(self.tau_lo * duration_s)] * self.n_gm))
        ratio = wv.wv[:, None] / np.maximum(A, 1e-300)
        self.q_ref = ratio.max(axis=0)
        # lower end: 1e-10 of the level at which the term alone explains the largest WV, or, if
        # lower, of the level at which it explains the smallest one (a term like the random walk,
        # negligible at the short scales, otherwise gets a floor near its real value)
        self.q_lo = np.minimum(self.q_ref, ratio.min(axis=0)) * _Q_BOX[0]
        self.n_eval = 0

    def design(self, taus: Sequence[float]) -> np.ndarray:
        fs = self.wv.fs_hz
        return np.stack([0.5 * t.avar(self.t_half, fs) for t in _unit_terms(self.spec, taus)], axis=1)

    # x = [log q_wn, then per other term: log q (and log tau for gm)], the order of ParamSpec.phi_names
    def split(self, x: np.ndarray) -> tuple[np.ndarray, list[float]]:
        q, taus, i = [math.exp(x[0])], [], 1
        for c in self.spec.others:
            q.append(math.exp(x[i]))
            if c == "gm":
                taus.append(math.exp(x[i + 1]))
                i += 2
            else:
                i += 1
        return np.array(q), taus

    def join(self, q: np.ndarray, taus: Sequence[float]) -> np.ndarray:
        x, k = [math.log(q[0])], 0
        for j, c in enumerate(self.spec.others, start=1):
            x.append(math.log(q[j]))
            if c == "gm":
                x.append(math.log(taus[k]))
                k += 1
        return np.array(x)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = self.join(self.q_lo, [self.tau_lo] * self.n_gm)
        hi = self.join(self.q_ref * _Q_BOX[1], [self.tau_hi] * self.n_gm)
        return lo, hi

    def nu(self, x: np.ndarray) -> np.ndarray:
        q, taus = self.split(x)
        self.n_eval += 1
        return self.design(taus) @ q

    def nnls_start(self, taus: Sequence[float], w: np.ndarray) -> tuple[float, np.ndarray]:
        """Weighted NNLS variances for fixed correlation times: (objective, x clipped into the box)."""
        A = self.design(taus)
        q, rnorm = nnls(A * w[:, None], self.wv.wv * w)
        q = np.clip(q, self.q_lo * 10.0, self.q_ref * _Q_BOX[1] / 10.0)
        self.n_eval += 1
        return rnorm**2, self.join(q, taus)


def _grid_starts(problem: _WVProblem, w: np.ndarray) -> np.ndarray:
    k = problem.n_gm
    if k == 0:
        return problem.nnls_start([], w)[1]
    grid = np.geomspace(problem.tau_lo, problem.tau_hi / 10.0, GRID_POINTS[k])
    best = (math.inf, None)
    for taus in itertools.combinations(grid, k):  # increasing: the WV is symmetric in the GM terms
        f, x = problem.nnls_start(taus, w)
        if f < best[0]:
            best = (f, x)
    return best[1]


def _single_start(problem: _WVProblem, w: np.ndarray) -> np.ndarray:
    """One heuristic start: every tau_b at the scale of the smallest WV, variances by NNLS."""
    wv = problem.wv
    t0 = float(np.clip(wv.tau[int(np.argmin(wv.wv))], problem.tau_lo, problem.tau_hi))
    return problem.nnls_start([t0 * 4.0**i for i in range(problem.n_gm)], w)[1]


def _refine(problem: _WVProblem, x0: np.ndarray, w: np.ndarray):
    lo, hi = problem.bounds()
    x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)

    def resid(x):
        return w * (problem.wv.wv - problem.nu(x))

    return least_squares(resid, x0, bounds=(lo, hi), x_scale=1.0, xtol=1e-10, ftol=1e-12, gtol=1e-12, max_nfev=400)


@dataclass(frozen=True)
class GMWMResult(MLiResult):
    """GMWM estimate with the public fields of :class:`~imustation.analysis.estimators.ml.mli.MLiResult`.

    ``estimator = "GMWM"``, ``pattern = "wv-haar"``, ``m`` the number of wavelet
    scales used; ``nll``/``aic``/``bic`` are NaN (no likelihood); ``b_on`` is the
    record mean (the WV does not see a constant). Extra: ``objective`` (the
    weighted sum of squares at the optimum, ~chi-square with m - k degrees of
    freedom under the model), ``wv`` (the empirical WV), ``wv_model`` (the fitted
    model's WV at the same scales).
    """

    objective: float = math.nan
    wv: WVResult | None = field(default=None, compare=False, repr=False)
    wv_model: np.ndarray | None = field(default=None, compare=False, repr=False)


def fit_gmwm(
    rate: np.ndarray,
    fs_hz: float,
    model: str = "wn+gm",
    *,
    scale: float = 1.0,
    segments: Sequence[tuple[int, int]] | None = None,
    starts: str = "grid",
    reweight: int = 2,
    tau_min: float = 0.0,
) -> GMWMResult:
    """GMWM fit of a rate noise model (Guerrier et al. 2013) to rate samples.

    Parameters
    ----------
    rate : (n,) rate samples in rad/s (or m/s^2), or integer counts with ``scale``.
    fs_hz : sampling rate, Hz.
    model : ``"wn+gm"`` (standard model), ``"wn+rw"``, ``"wn+gm+rw"``, ``"wn+2gm"``,
        ``"wa+wn+gm"``, ... (see :func:`~imustation.analysis.estimators.models.noise_models.parse_model`).
    segments : contiguous sample ranges with data (gaps between them).
    starts : ``"grid"`` (correlation-time grid + NNLS, default) or ``"single"``.
    reweight : refits with weights from the fitted model's WV (0 = weights from nu_hat only).
    tau_min : a device filter's memory, s: scales whose Allan cluster time (half the
        scale) is shorter are left out (the model, with ``lp``, holds from there on).

    Returns
    -------
    GMWMResult with ``sigma_w`` (rad s^-1/sqrt(Hz)), ``sigma_b`` (rad s^-2/sqrt(Hz)),
    ``tau_b`` (s), ``params``, ``stderr``, ``ci90`` as for ML_i.
    """
    t0 = time.perf_counter()
    rate = np.asarray(rate)
    kept = len(rate) if segments is None else int(sum(b - a for a, b in segments))
    spec = ParamSpec.for_record(parse_model(model), float(fs_hz), kept / float(fs_hz))
    if starts not in START_KINDS:
        raise InputError(f"starts {starts!r}: use one of {', '.join(START_KINDS)}")
    if int(reweight) < 0:
        raise InputError(f"reweight = {reweight}: must be 0 or more")
    wv = wavelet_variance(rate, fs_hz, scale=scale, segments=segments)
    if tau_min > 0:
        keep = 0.5 * wv.tau >= tau_min * (1.0 - 1e-9)
        wv = replace(
            wv, **{f: getattr(wv, f)[keep] for f in ("level", "scale", "tau", "wv", "wv_lo", "wv_hi", "edf", "n")}
        )
    k = 1 + spec.d
    if len(wv.wv) <= k:
        raise InputError(f"only {len(wv.wv)} wavelet scales: too few for model {spec.name!r} ({k} parameters)")
    if not np.all(wv.wv > 0):
        raise InputError("the wavelet variance is zero at some scale (constant record?): nothing to fit")
    problem = _WVProblem(wv, spec, kept / float(fs_hz))
    eta = wv.edf
    w = np.sqrt(eta / 2.0) / wv.wv  # 1/sd of nu_hat_j (chi-square), from nu_hat first
    x = _grid_starts(problem, w) if starts == "grid" else _single_start(problem, w)
    sol = _refine(problem, x, w)
    for _ in range(int(reweight)):
        w = np.sqrt(eta / 2.0) / problem.nu(sol.x)
        x = _grid_starts(problem, w) if starts == "grid" else sol.x
        cand = [_refine(problem, x, w)]
        if starts == "grid":
            cand.append(_refine(problem, sol.x, w))  # the previous optimum under the new weights
        sol = min(cand, key=lambda s: s.cost)
    return _gmwm_result(problem, sol, w, rate, scale, t0, segments)


def _gmwm_result(
    problem: _WVProblem, sol, w: np.ndarray, rate: np.ndarray, scale: float, t0: float, segments
) -> GMWMResult:
    spec = problem.spec
    names = spec.phi_names()
    x = sol.x
    # x = log q (variances; the filter's q = sigma_w^2 tau_lp) or log tau_b; dx/dphi
    T = np.diag([1.0 if nm.startswith("tau_b") else 2.0 for nm in names])
    if "tau_lp" in names:
        j = names.index("tau_lp")
        T[j, j], T[j, 0] = 1.0, 2.0
    phi = np.linalg.solve(T, x)
    Jr = sol.jac  # d resid / dx = -w d nu/dx
    H = (Jr @ T).T @ (Jr @ T)  # J^T Omega J in phi
    stderr, ci90 = intervals(names, phi, H)
    params = dict(zip(names, np.exp(phi).tolist(), strict=True))
    lo, hi = problem.bounds()
    at_bound = tuple(sorted(names[i] for i in range(len(x)) if min(x[i] - lo[i], hi[i] - x[i]) < 1e-3))
    ngm = problem.n_gm
    if ngm:
        sfx = "" if ngm == 1 else str(ngm)
        order = sorted(range(1, ngm + 1), key=lambda i: params[f"tau_b{i}"]) if ngm > 1 else [1]
        if ngm > 1:  # order by correlation time, as ML_i does
            for dct in (params, stderr, ci90):
                old = dict(dct)
                for new_i, old_i in enumerate(order, start=1):
                    for key in ("sigma_b", "tau_b"):
                        dct[f"{key}{new_i}"] = old[f"{key}{old_i}"]
            for key in ("sigma_b", "tau_b"):
                stderr[key], ci90[key] = stderr[f"{key}{sfx}"], ci90[f"{key}{sfx}"]
        sigma_b, tau_b = params[f"sigma_b{sfx}"], params[f"tau_b{sfx}"]
    elif "rw" in spec.codes:
        sigma_b, tau_b = params["sigma_k"], math.inf
    else:
        sigma_b = tau_b = math.nan
    if segments is None:
        b_on = float(np.mean(rate, dtype=np.float64)) * scale
    else:
        b_on = float(sum(np.sum(rate[a:b], dtype=np.float64) for a, b in segments)) * scale
        b_on /= sum(b - a for a, b in segments)
    params["b_on"] = b_on
    converged = bool(sol.success) and not at_bound
    message = sol.message if not at_bound else f"at search bound: {', '.join(at_bound)}"
    objective = float(2.0 * sol.cost)
    return GMWMResult(
        model=spec.name,
        sigma_w=params["sigma_w"],
        sigma_b=sigma_b,
        tau_b=tau_b,
        b_on=b_on,
        stderr=stderr,
        ci90=ci90,
        nll=math.nan,
        pattern="wv-haar",
        m=len(problem.wv.wv),
        n=len(rate),
        fs_hz=problem.wv.fs_hz,
        converged=converged,
        message=message,
        n_eval=problem.n_eval,
        fit_time_s=time.perf_counter() - t0,
        starts=1,
        at_bound=at_bound,
        params=params,
        k=len(names),
        estimator="GMWM",
        noise_model=spec.model(phi, b_on),
        objective=objective,
        wv=problem.wv,
        wv_model=problem.nu(x),
    )
