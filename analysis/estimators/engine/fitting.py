"""The fitting engine shared by ML_i, ML_i-F, ML on rates and GMWM.

* :class:`ParamSpec` (:mod:`.paramspec`, re-exported here): a model's parameter layout.
* :class:`Problem`: the innovations likelihood (Nikolic et al. 2016, eq. 19) of one
  model on one integrated record, batched over parameter points. ``b_on`` is a
  diffuse initial state, handled exactly by the augmented (de Jong) filter (GLS
  estimate and the ``log S_uu`` term); the standard model runs the prefix-scan filter
  of :mod:`.scan`, other models the batched Kalman filter of :mod:`.kalman`; gaps
  predict the bias across without an update. Estimators with other data or other
  terms subclass it (``profile``, ``nll``, ``full_nll``).
* :func:`optimise`: damped Newton (:mod:`.newton`) from each distinct start; a start
  that reaches an optimum already found is stopped.
* :func:`intervals`: delta-method standard errors and 90 % intervals from the observed
  information (beyond the paper, which gives none).
* :class:`MLiResult` and :func:`build_result`: the result every estimator returns.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from imustation.analysis.estimators.engine.kalman import Innovations, Profile, kalman_innovations
from imustation.analysis.estimators.engine.newton import NewtonResult, fd_derivatives, newton, stencil
from imustation.analysis.estimators.engine.paramspec import FOLD_FRACTION, ParamSpec
from imustation.analysis.estimators.engine.pattern import Increments
from imustation.analysis.estimators.engine.robust import sandwich
from imustation.analysis.estimators.engine.scan import standard_innovations
from imustation.analysis.estimators.models.noise_models import NoiseModel
from imustation.errors import InputError

_LOG2PI = math.log(2.0 * math.pi)
#: z-score of the two-sided 90 % interval
Z90 = 1.6448536269514722


def profiled_nll(prof: Profile) -> np.ndarray:
    """-log L with sigma_w^2 and b_on profiled out (diffuse likelihood)."""
    dof = prof.m - 1
    s2 = prof.s_tilde / dof
    return 0.5 * (dof * (np.log(s2) + 1.0) + prof.logdet + prof.log_suu + dof * _LOG2PI)


def full_nll(prof: Profile, sigma_w2: np.ndarray) -> np.ndarray:
    """-log L at ``sigma_w2`` ((rate unit)^2/Hz, one per profile column) with b_on profiled out."""
    dof = prof.m - 1
    return 0.5 * (dof * np.log(sigma_w2) + prof.logdet + prof.log_suu + prof.s_tilde / sigma_w2 + dof * _LOG2PI)


class Problem:
    """Likelihood of one model on one integrated record, batched over parameter points."""

    def __init__(self, inc: Increments, spec: ParamSpec, filt: str = "auto"):
        self.inc = inc
        self.spec = spec = spec.with_record(inc.fs_hz, inc.duration)
        #: flicker components this much shorter than every interval are folded (paramspec.FOLD_FRACTION)
        self.fold_below = FOLD_FRACTION * float(inc.dt.min())
        if filt == "auto":
            filt = "scan" if spec.fast else "kalman"
        if filt == "scan" and not spec.fast:
            raise InputError(f"filter 'scan' exists for 'wn+gm' only, not {spec.name!r}")
        self.filt = filt
        self.layout = inc.layout() if filt == "kalman" else None
        self.lo, self.hi = spec.bounds(inc)
        self.n_eval = 0

    def innovations(self, theta: np.ndarray) -> Innovations:
        """Per-interval innovations of the filter at theta (K, d) (sigma_w = 1 units)."""
        theta = np.atleast_2d(theta)
        self.n_eval += theta.shape[0]
        if self.filt == "scan":
            gap = self.inc.gap if np.any(self.inc.gap > 0) else None
            return standard_innovations(self.inc.y, self.inc.dt, np.exp(theta[:, 0]), np.exp(theta[:, 1]), gap)
        blocks, r_angle = self.spec.blocks(theta, self.fold_below)
        return kalman_innovations(blocks, r_angle, self.layout)

    def profile(self, theta: np.ndarray) -> Profile:
        return self.innovations(theta).profile()

    def nll(self, theta: np.ndarray) -> np.ndarray:
        """Profiled negative log-likelihood at theta (K, d)."""
        with np.errstate(all="ignore"):
            out = profiled_nll(self.profile(theta))
        return np.where(np.isfinite(out), out, np.inf)

    def full_nll(self, phi: np.ndarray) -> np.ndarray:
        """Negative log-likelihood at physical log-parameters phi (K, 1 + d) (b_on diffuse)."""
        phi = np.atleast_2d(phi)
        with np.errstate(all="ignore"):
            out = full_nll(self.profile(self.spec.theta_of_phi(phi)), np.exp(2.0 * phi[:, 0]))
        return np.where(np.isfinite(out), out, np.inf)


# ---------------------------------------------------------------------------
# optimisation


def optimise(problem: Problem, starts: list[np.ndarray], max_iter: int = 50) -> tuple[NewtonResult, int]:
    """Newton from each distinct start (at most ``max_iter`` steps each); a start stops when it
    reaches an optimum already found or is still far worse than the best (50 nats after 3 steps,
    5 after 6)."""
    found: list[NewtonResult] = []

    def stop(x, f, it):
        for r in found:
            if np.abs(x - r.x).max() < 0.3 and r.converged:
                return "same optimum as an earlier start"
        best = min((r.fun for r in found), default=math.inf)
        if (it >= 3 and f > best + 50.0) or (it >= 6 and f > best + 5.0):
            return "abandoned: far worse than the best start"
        return None

    unique: list[np.ndarray] = []
    for x0 in starts:
        if all(np.abs(x0 - u).max() > 0.1 for u in unique):
            unique.append(x0)
    kinds = problem.spec.theta_kinds()
    # only extra terms may vanish: the standard model's own bias is kept (its search box decides)
    probe = tuple(j for j, k in enumerate(kinds) if k in ("r_rw", "r_wa", "r_fl")) if problem.spec.d > 2 else ()
    if problem.spec.codes.count("gm") > 1:
        probe += tuple(j for j, k in enumerate(kinds) if k == "r")
    for x0 in unique:
        halt = stop if found else None
        found.append(newton(problem.nll, x0, problem.lo, problem.hi, stop=halt, max_iter=max_iter, probe=probe))
    candidates = [r for r in found if not r.message.startswith("same optimum")]
    best = min(candidates, key=lambda r: r.fun)
    return best, len(unique)


# ---------------------------------------------------------------------------
# uncertainty


def observed_information(problem: Problem, phi: np.ndarray, h: float = 1e-2) -> np.ndarray:
    """Numerical Hessian of the full nll in physical log-parameters (observed information)."""
    D = len(phi)
    f = problem.full_nll(phi[None, :] + stencil(D) * h)
    return fd_derivatives(f, D, h)[2]


def information_cov(H: np.ndarray) -> np.ndarray:
    """``H^-1``, or NaN where the information ``H`` is not positive definite."""
    try:
        if np.all(np.linalg.eigvalsh(H) > 0):
            return np.linalg.inv(H)
    except np.linalg.LinAlgError:
        pass
    return np.full(H.shape, np.nan)


def identified(H: np.ndarray, free: list[int]) -> list[int]:
    """The coordinates of ``free`` (the first, sigma_w, always kept) on which the information ``H`` is
    positive definite: while it is not, the coordinate that loads most on its least-curved direction is
    held fixed (a term the data do not determine; its own interval is then not stated, the others are)."""
    free = list(free)
    while len(free) > 1:
        try:
            w, v = np.linalg.eigh(H[np.ix_(free, free)])
        except np.linalg.LinAlgError:
            return free[:1]
        if np.all(np.isfinite(w)) and w[0] > 0:
            break
        load = np.abs(v[:, 0]) if np.all(np.isfinite(v)) else np.ones(len(free))
        load[0] = -1.0
        free.pop(int(np.argmax(load)))
    return free


def _embed(cov: np.ndarray, free: list[int], d: int) -> np.ndarray:
    """The (d, d) covariance with ``cov`` at the ``free`` coordinates and 0 at the others (held fixed)."""
    out = np.zeros((d, d))
    out[np.ix_(free, free)] = cov
    return out


def intervals(
    names: list[str], phi: np.ndarray, H: np.ndarray, cov: np.ndarray | None = None
) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """Delta-method standard errors and 90 % intervals symmetric in log-parameters, from the
    information ``H`` (or, if given, the covariance ``cov`` of the log-parameters)."""
    var = np.diag(information_cov(H) if cov is None else cov)
    stderr, ci90 = {}, {}
    for name, p, v in zip(names, phi, var, strict=True):
        value = math.exp(p)
        se_log = math.sqrt(v) if v > 0 and np.isfinite(v) else float("nan")
        stderr[name] = value * se_log if se_log < 700.0 else math.inf
        half = min(Z90 * se_log, 700.0) if math.isfinite(se_log) else math.nan  # exp() range
        ci90[name] = (value * math.exp(-half), value * math.exp(half))
    return stderr, ci90


# ---------------------------------------------------------------------------
# results and public API


@dataclass(frozen=True)
class MLiResult:
    """ML_i (or classical ML) estimate of a noise model with turn-on bias (SI units).

    ``sigma_w`` (rad s^-1/sqrt(Hz)), ``sigma_b`` (rad s^-2/sqrt(Hz)), ``tau_b`` (s)
    and ``b_on`` (rad/s) follow the paper. For ``wn+rw`` ``sigma_b`` is the random
    walk's ``sigma_k`` and ``tau_b = inf``; with several Gauss-Markov terms they are
    the slowest one's; models without a bias term give NaN. ``params`` holds
    every parameter by name (``sigma_b1, tau_b1, ...`` ordered by tau for 2gm,
    ``sigma_k``, ``sigma_a`` in rad). ``stderr`` holds delta-method standard errors
    from the observed information; ``ci90`` 90 % intervals, symmetric in log-parameters.
    ``nll`` is the negative diffuse log-likelihood at the optimum (nats);
    ``aic = 2 nll + 2 k``, ``bic = 2 nll + k log M`` with ``k`` the number of
    noise parameters plus b_on and M the number of pattern intervals.
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
    params: dict[str, float] = field(default_factory=dict)
    k: int = 0
    aic: float = math.nan
    bic: float = math.nan
    estimator: str = "ML_i"
    noise_model: NoiseModel | None = field(default=None, compare=False, repr=False)
    #: intervals account for model misfit (the wider of sandwich and model-based); ``ci90_model``
    #: then holds the model-based ones
    robust: bool = False
    ci90_model: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: physical log-parameters (order of ``ParamSpec.phi_names``) and the covariance behind ``stderr``
    phi: np.ndarray | None = field(default=None, compare=False, repr=False)
    cov_log: np.ndarray | None = field(default=None, compare=False, repr=False)
    #: cluster time (s) from which the model holds: a device filter's memory (0: from the sample time)
    memory_s: float = 0.0

    def as_dict(self) -> dict:
        return {
            "model": self.model,
            "estimator": self.estimator,
            "sigma_w": self.sigma_w,
            "sigma_b": self.sigma_b,
            "tau_b": self.tau_b,
            "b_on": self.b_on,
            "params": dict(self.params),
            "stderr": dict(self.stderr),
            "ci90": {k: list(v) for k, v in self.ci90.items()},
            "pattern": self.pattern,
            "m": self.m,
            "nll": self.nll,
            "k": self.k,
            "aic": self.aic,
            "bic": self.bic,
            "converged": self.converged,
            "message": self.message,
            **({"robust": True, "ci90_model": {k: list(v) for k, v in self.ci90_model.items()}} if self.robust else {}),
        }


def build_result(
    problem: Problem,
    theta: np.ndarray,
    newton: NewtonResult,
    n_starts: int,
    t0: float,
    estimator: str,
    m_intervals: int,
    pattern: str,
    n: int,
    fs_hz: float,
    sigma_w2: float | None = None,
    *,
    robust: bool = False,
    memory_s: float = 0.0,
) -> MLiResult:
    """The result at search point ``theta``: physical parameters, intervals, criteria.

    ``sigma_w2`` (rate unit^2/Hz): given by estimators whose likelihood does not
    profile it in closed form (ML_i-F); the nll is then ``problem.full_nll``'s.
    ``robust``: intervals that hold under model misfit, the wider of the model-based
    and the sandwich interval (:mod:`.robust`). ``memory_s`` (s): a device filter's
    memory, for the model's ``lp`` term.
    """
    spec = problem.spec
    prof = problem.profile(theta[None, :])
    M = prof.m
    if sigma_w2 is None:
        sigma_w2 = float(prof.s_tilde[0] / (M - 1))
        phi = spec.phi_of_theta(theta, math.sqrt(sigma_w2))
        nll = float(full_nll(prof, np.array([sigma_w2]))[0])
    else:
        phi = spec.phi_of_theta(theta, math.sqrt(sigma_w2))
        nll = float(problem.full_nll(phi[None, :])[0])
    b_on = float(prof.b_on[0])
    names = spec.phi_names()
    lo, hi = problem.lo, problem.hi
    edge = [j for j in range(spec.d) if min(theta[j] - lo[j], hi[j] - theta[j]) < 1e-3]
    # a coordinate at its search bound (a term the data do not support) is held there for the
    # intervals of the others: its flat or one-sided likelihood would leave every interval undefined
    free = [0] + [1 + j for j in range(spec.d) if j not in edge]
    H = observed_information(problem, phi)
    free = identified(H, free)
    cov = _embed(information_cov(H[np.ix_(free, free)]), free, len(phi))
    stderr, ci90 = intervals(names, phi, H, cov)
    ci90_model = dict(ci90)
    if robust:
        cov_r = sandwich(problem, phi, H, free=free)
        se_r, ci_r = intervals(names, phi, H, cov_r)
        for name in names:
            if math.isfinite(se_r[name]) and se_r[name] > stderr[name]:
                stderr[name] = se_r[name]
            lo_r, hi_r = ci_r[name]
            if math.isfinite(lo_r):
                ci90[name] = (min(ci90[name][0], lo_r), max(ci90[name][1], hi_r))
        # the covariance behind the reported standard errors: the larger variance per coordinate
        with np.errstate(all="ignore"):  # NaN where either covariance is not usable; 1 where held fixed
            scale = np.where(np.diag(cov) != 0, np.sqrt(np.maximum(np.diag(cov_r), np.diag(cov)) / np.diag(cov)), 1.0)
        if np.all(np.isfinite(scale)):
            cov = cov * np.outer(scale, scale)
    params = dict(zip(names, np.exp(phi).tolist(), strict=True))
    at_bound = {names[1 + j] for j in edge}
    # order several Gauss-Markov terms by correlation time (the likelihood is symmetric)
    ngm = spec.codes.count("gm")
    if ngm > 1:
        order = sorted(range(1, ngm + 1), key=lambda i: params[f"tau_b{i}"])
        for dct in (params, stderr, ci90, ci90_model):
            old = dict(dct)
            for new_i, old_i in enumerate(order, start=1):
                for key in ("sigma_b", "tau_b"):
                    dct[f"{key}{new_i}"] = old[f"{key}{old_i}"]
        rename = {f"{k}{o}": f"{k}{i}" for i, o in enumerate(order, 1) for k in ("sigma_b", "tau_b")}
        at_bound = {rename.get(b, b) for b in at_bound}
    at_bound = tuple(sorted(at_bound))
    if "gm" in spec.codes:
        sfx = "" if ngm == 1 else str(ngm)
        sigma_b, tau_b = params[f"sigma_b{sfx}"], params[f"tau_b{sfx}"]
        if ngm > 1:
            stderr["sigma_b"], stderr["tau_b"] = stderr[f"sigma_b{sfx}"], stderr[f"tau_b{sfx}"]
            ci90["sigma_b"], ci90["tau_b"] = ci90[f"sigma_b{sfx}"], ci90[f"tau_b{sfx}"]
            ci90_model["sigma_b"], ci90_model["tau_b"] = ci90_model[f"sigma_b{sfx}"], ci90_model[f"tau_b{sfx}"]
    elif "rw" in spec.codes:
        sigma_b, tau_b = params["sigma_k"], math.inf
    else:
        sigma_b = tau_b = math.nan
    params["b_on"] = b_on
    k = len(names) + 1
    converged = newton.converged and not at_bound
    message = newton.message if not at_bound else f"at search bound: {', '.join(at_bound)}"
    return MLiResult(
        model=spec.name,
        sigma_w=math.sqrt(sigma_w2),
        sigma_b=sigma_b,
        tau_b=tau_b,
        b_on=b_on,
        stderr=stderr,
        ci90=ci90,
        nll=nll,
        pattern=pattern,
        m=m_intervals,
        n=n,
        fs_hz=fs_hz,
        converged=converged,
        message=message,
        n_eval=problem.n_eval,
        fit_time_s=time.perf_counter() - t0,
        starts=n_starts,
        at_bound=at_bound,
        params=params,
        k=k,
        aic=2.0 * nll + 2.0 * k,
        bic=2.0 * nll + k * math.log(M),
        estimator=estimator,
        noise_model=spec.model(phi, b_on, memory_s),
        robust=robust,
        ci90_model=ci90_model if robust else {},
        phi=phi,
        cov_log=cov,
        memory_s=memory_s,
    )
