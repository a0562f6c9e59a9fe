"""Monte Carlo study of the noise-model estimators (Nikolic et al. Fig. 10 and Table III).

Records of the standard model (Algorithm 1) are simulated with the BMX055
z-gyro parameters of Table III; the bias diffusion can be scaled by several
``levels`` (Fig. 10 varies sigma_b at fixed sigma_w, tau_b). Every record is
fitted by each estimator:

``mli-log``, ``mli-uniform``
    ML_i on the integrated record, log / uniform sampling pattern (m points);
``ml-log``, ``ml-uniform``
    classical ML on rate samples picked with the same patterns;
``gmwm``, ``gmwm-single``
    GMWM on the Haar wavelet variance of all samples (:mod:`.gmwm`), with the
    default correlation-time grid start / one heuristic start;
``mli-f``
    ML_i-F (:mod:`.composite`): the integrated likelihood on a uniform pattern
    plus the fine-scale Allan variance of every sample.

With ``check_starts`` every multi-start estimator is also run from its single
default start (ML_i and ML_i-F: the Allan start; GMWM: the heuristic start of
the R package), and the study counts how often that ends in another optimum
(sigma_w, sigma_b or tau_b more than 5 % away from the multi-start fit).

The summary gives, per estimator, level and parameter: mean, median, relative bias,
spread (std), RMSE, coverage of the 90 % intervals, and the mean time per fit.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from imustation.analysis.estimators.engine.pattern import integrate
from imustation.analysis.estimators.ml.composite import DEFAULT_M as F_DEFAULT_M
from imustation.analysis.estimators.ml.composite import fine_scale, fit_composite_data
from imustation.analysis.estimators.ml.gmwm import fit_gmwm
from imustation.analysis.estimators.ml.ml_rate import fit_ml_rate
from imustation.analysis.estimators.ml.mli import fit_integrated
from imustation.analysis.estimators.models.noise_models import standard
from imustation.analysis.estimators.models.standard import StandardModel
from imustation.analysis.pipeline.choices import DEFAULT_STUDY_ESTIMATORS
from imustation.analysis.pipeline.choices import STUDY_ESTIMATORS as ESTIMATORS
from imustation.errors import InputError

#: estimators with a multi-start default whose single start the study can check
MULTI_START = ("mli-log", "mli-uniform", "gmwm", "mli-f")
PARAMS = ("sigma_w", "sigma_b", "tau_b")


@dataclass(frozen=True)
class StudyFit:
    estimator: str
    level: float
    seed: int
    truth: dict[str, float]
    estimate: dict[str, float]
    ci90: dict[str, tuple[float, float]]
    converged: bool
    fit_time_s: float
    #: the single default start ended in another optimum (None: not checked)
    other_optimum: bool | None = None


def _other_optimum(a, b) -> bool:
    return any(abs(getattr(b, p) / getattr(a, p) - 1.0) > 0.05 for p in PARAMS)


def _fit(est: str, x: np.ndarray, fs_hz: float, m: int, single: bool = False):
    kind, _, pattern = est.partition("-")
    if kind == "gmwm":
        return fit_gmwm(x, fs_hz, "wn+gm", starts="single" if single else (pattern or "grid"))
    if est == "mli-f":
        inc = integrate(x, fs_hz, m=F_DEFAULT_M, pattern="uniform")
        return fit_composite_data(inc, fine_scale(x, fs_hz), "wn+gm", single_start=single)
    if kind == "mli":
        return fit_integrated(integrate(x, fs_hz, m=m, pattern=pattern), "wn+gm", single_start=single)
    return fit_ml_rate(x, fs_hz, pattern=pattern, m=m)


def run_study(
    truth: StandardModel,
    *,
    records: int,
    duration_s: float,
    fs_hz: float = 400.0,
    seed: int = 0,
    estimators: tuple[str, ...] = DEFAULT_STUDY_ESTIMATORS,
    levels: tuple[float, ...] = (1.0,),
    m: int = 1000,
    progress=None,
    check_starts: bool = False,
) -> list[StudyFit]:
    """Simulate ``records`` records per level (seeds ``seed, seed+1, ...``) and fit each.

    ``duration_s`` s at ``fs_hz`` Hz; ``levels`` multiply ``truth.sigma_b``;
    ``m`` pattern points of ML_i / classical ML (ML_i-F keeps its own default).
    ``progress(text)`` is called once per record when given. ``check_starts``:
    also fit from the single default start (see the module docstring).
    """
    bad = [e for e in estimators if e not in ESTIMATORS]
    if bad:
        raise InputError(f"estimator {bad[0]!r}: choose from {', '.join(ESTIMATORS)}")
    n = int(round(duration_s * fs_hz))
    out: list[StudyFit] = []
    for level in levels:
        model = standard(truth.sigma_w, truth.sigma_b * level, truth.tau_b, truth.b_on)
        tv = {"sigma_w": truth.sigma_w, "sigma_b": truth.sigma_b * level, "tau_b": truth.tau_b}
        for r in range(records):
            s = seed + r
            x = model.simulate(n, fs_hz, np.random.default_rng([s, int(round(level * 1000))]))
            for est in estimators:
                t0 = time.perf_counter()
                res = _fit(est, x, fs_hz, m)
                dt = time.perf_counter() - t0
                other = None
                if check_starts and est in MULTI_START:
                    other = _other_optimum(res, _fit(est, x, fs_hz, m, single=True))
                out.append(
                    StudyFit(
                        est,
                        level,
                        s,
                        tv,
                        {p: getattr(res, p) for p in PARAMS},
                        {p: res.ci90.get(p, (math.nan, math.nan)) for p in PARAMS},
                        res.converged,
                        dt,
                        other,
                    )
                )
            if progress is not None:
                progress(f"level {level:g} record {r + 1}/{records} done")
    return out


@dataclass(frozen=True)
class SummaryRow:
    estimator: str
    level: float
    param: str
    truth: float
    mean: float
    median: float
    bias_rel: float
    std: float
    rmse_rel: float
    coverage90: float
    converged: int
    count: int
    time_per_fit_s: float
    #: records whose single default start ended in another optimum (-1: not checked)
    other_optimum: int = -1


def summarize(fits: list[StudyFit]) -> list[SummaryRow]:
    """Bias, spread, RMSE and 90 % interval coverage per estimator, level and parameter."""
    rows = []
    keys = sorted({(f.estimator, f.level) for f in fits}, key=lambda k: (ESTIMATORS.index(k[0]), k[1]))
    for est, level in keys:
        group = [f for f in fits if f.estimator == est and f.level == level]
        t = float(np.mean([f.fit_time_s for f in group]))
        checked = [f.other_optimum for f in group if f.other_optimum is not None]
        other = int(sum(checked)) if checked else -1
        for p in PARAMS:
            truth = group[0].truth[p]
            v = np.array([f.estimate[p] for f in group], dtype=float)
            lo = np.array([f.ci90[p][0] for f in group], dtype=float)
            hi = np.array([f.ci90[p][1] for f in group], dtype=float)
            ok = np.isfinite(lo) & np.isfinite(hi)
            cover = float(np.mean((lo <= truth) & (truth <= hi) & ok)) if len(v) else math.nan
            rows.append(
                SummaryRow(
                    est,
                    level,
                    p,
                    truth,
                    float(np.mean(v)),
                    float(np.median(v)),
                    float(np.mean(v) / truth - 1.0),
                    float(np.std(v, ddof=1)) if len(v) > 1 else math.nan,
                    float(np.sqrt(np.mean((v / truth - 1.0) ** 2))),
                    cover,
                    int(sum(f.converged for f in group)),
                    len(group),
                    t,
                    other,
                )
            )
    return rows


def _pct(x: float) -> str:
    """A relative number in %, with two decimals below 1 % (sigma_w errors are hundredths of a percent)."""
    return f"{100 * x:.2f} %" if abs(x) < 0.01 else f"{100 * x:.1f} %"


def markdown(rows: list[SummaryRow], header: str = "") -> str:
    """The summary as a Markdown table (relative numbers in %)."""
    lines = [header, ""] if header else []
    lines += [
        "| estimator | sigma_b level | parameter | truth | mean | median | bias | std | RMSE | 90 % CI coverage "
        "| converged | s/fit | 1 start: other optimum |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.estimator} | x{r.level:g} | {r.param} | {r.truth:.4g} | {r.mean:.4g} | {r.median:.4g} "
            f"| {'+' if r.bias_rel >= 0 else ''}{_pct(r.bias_rel)} "
            f"| {r.std:.3g} ({_pct(r.std / r.truth)}) | {_pct(r.rmse_rel)} | {100 * r.coverage90:.0f} % "
            f"| {r.converged}/{r.count} | {r.time_per_fit_s:.3f} "
            f"| {f'{r.other_optimum}/{r.count}' if r.other_optimum >= 0 else '-'} |"
        )
    return "\n".join(lines) + "\n"
