"""Automatic choice of the noise model (``--model auto``): the simplest model of the family that fits.

The family (codes of :data:`~.noise_models.TERM_CODES`): white rate noise ``wn``
always; the angle term the fine scales show (:func:`~.finescale.fine_statistics`:
a device filter ``lp``, white angle noise ``wa``, or none), carried by every
candidate; and a bias structure, tried in stages of growing size:

1. ``gm``, ``fl``, ``rw`` (one Gauss-Markov term; bias instability; rate random walk)
2. ``fl+rw``, ``gm+rw``, ``gm+fl``, ``2gm``
3. ``gm+fl+rw``, ``2gm+rw``

Each candidate is fitted by ML_i-F with robust intervals (:mod:`.robust`) and
checked against the measured Allan deviation from the filter's memory on, by the
adequacy test every reported model gets (:func:`~.adequacy.model_adequacy`: a
candidate passes unless its verdict is "does not fit"). The first stage with a model that fits gives the
choice: among its models that fit, the smallest BIC (``2 nll + k ln M``). The
extensions of that model in the next stage are then fitted, and one that fits
replaces it when its BIC is lower by more than :data:`BIC_STRONG` (a check against
an Allan deviation with few degrees of freedom at the longest taus cannot see, for
example, a weak rate random walk beside a flicker floor; the likelihood can), and
so on. A stage where nothing fits also gets its smallest-BIC model with a bias instability
refitted once with a flicker cut-off (IEEE 952's f0: the sum starts at the cut-off, picked
from two per decade up to :data:`FLICKER_CUT_MAX_S` by the measured Allan variance,
:func:`screen_cut`), a candidate of that stage like the others; extensions of a chosen model
with a cut-off keep it (docs/noise-model.md, "Cut-off of the bias instability"). When no
candidate fits, the smallest BIC of all, with ``fits`` false and the
reason. The chosen model's intervals are mixed, weighted by BIC, with those of the
other models that fit and whose BIC is within :data:`BIC_STRONG` (``close``,
:func:`mixed_interval`): which of them is "the" model is itself uncertain, and
their spread belongs in the interval (on
repeated 12 h records with flicker and a weak random walk the flicker-only choice
alone covered B in 5 of 8; docs/noise-model.md, "Intervals"). The paper's standard model ``wn+gm``
(fine scale as in the paper's estimator, no angle term) is always fitted too,
for comparison. Every candidate reuses one integration and one set of fine-scale
Allan variances, and starts from the fits of the smaller candidates
(:func:`family_starts`).
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from scipy.special import ndtr

from imustation.analysis.estimators.classical.allan import AllanResult, oadev
from imustation.analysis.estimators.engine.fitting import Z90, MLiResult
from imustation.analysis.estimators.engine.paramspec import ParamSpec
from imustation.analysis.estimators.engine.pattern import check_rate, integrate
from imustation.analysis.estimators.ml.composite import (
    DEFAULT_M,
    CompositeProblem,
    CompositeResult,
    angle_scale,
    fine_scale,
    fit_composite_data,
)
from imustation.analysis.estimators.ml.finescale import FilterHint, FineStatistic, fine_statistics
from imustation.analysis.estimators.ml.white_guard import guard_white, later_octaves
from imustation.analysis.estimators.models.sensor_terms import FLICKER_FLOOR, flicker_times
from imustation.analysis.estimators.selection.adequacy import NO_FIT, Adequacy, fit_adequacy
from imustation.errors import InputError

#: bias structures of the family, in stages of growing size
STAGES = (("gm", "fl", "rw"), ("fl+rw", "gm+rw", "gm+fl", "2gm"), ("gm+fl+rw", "2gm+rw"))
#: the paper's standard model, always fitted for comparison
PAPER_MODEL = "wn+gm"
#: a larger model replaces a smaller one that fits when its BIC is lower by more than this
#: ("very strong" evidence, Kass & Raftery 1995, J. Am. Stat. Assoc. 90(430))
BIC_STRONG = 10.0
#: the longest cut-off tried for the bias instability, s: the cut-offs tried are the decades above the
#: sum's first term up to this (two or three fits on a record at 100..1000 Hz)
FLICKER_CUT_MAX_S = 1.0
#: a cut-off changes the model's Allan deviation only at cluster times below this many times
#: the cut-off (the dropped terms' share falls as T/tau): a misfit beyond is not the cut-off's
CUT_REACH = 100.0
#: cut-offs tried per decade: a decade grid misses a cut-off between two decades (measured: a
#: flicker that starts at 0.25 s fits neither 0.1 s nor 1 s on a 12 h record)
CUTS_PER_DECADE = 2
#: Newton steps per start of a candidate: a model that needs more has more terms than the data
#: support (its flat directions make Newton creep), it ends unconverged and is not chosen
MAX_NEWTON = 20


@dataclass(frozen=True)
class Candidate:
    """One fitted model of the family and its check against the measured Allan deviation.

    ``check`` (:func:`~.adequacy.fit_adequacy`: from the fit's filter memory on) is computed when first
    asked for: the choice tests only the candidates it needs (the smallest BIC of a stage that
    could still be chosen, and the models close to the choice), which halves the cost of the
    tests on long records; :attr:`tested` says whether it has been computed.
    """

    result: CompositeResult
    stage: int
    #: what the check needs: the measured Allan variance, rate (Hz), segment lengths (samples)
    inputs: tuple[AllanResult, float, tuple[int, ...]] = field(repr=False, compare=False)

    @cached_property
    def check(self) -> Adequacy:
        allan, fs_hz, lengths = self.inputs
        return fit_adequacy(allan, self.result, fs_hz, lengths)

    @property
    def tested(self) -> bool:
        return "check" in self.__dict__

    @property
    def cut_s(self) -> float:
        """The bias instability's cut-off, s (0: none, or no bias instability)."""
        return flicker_cut(self.result)

    @property
    def key(self) -> tuple[str, float]:
        """What tells candidates apart: the model's name and the flicker cut-off."""
        return (self.result.model, self.cut_s)

    @property
    def passes(self) -> bool:
        """The adequacy test does not reject it ("fits", or "not tested": nothing to reject on)."""
        return self.check.verdict != NO_FIT

    def as_dict(self) -> dict:
        r = self.result
        out = {"model": r.model, "flicker_cut_s": self.cut_s or None, "stage": self.stage, "k": r.k, "bic": r.bic}
        out["converged"] = r.converged
        if not self.tested:
            return out | {"fits": None, "p_value": None, "where": "not tested: not needed for the choice"}
        return out | {"fits": self.passes, "p_value": self.check.p_value, "where": self.check.summary()}


@dataclass(frozen=True)
class ModelChoice:
    """Outcome of :func:`choose_model`.

    ``chosen``: the selected fit; ``fits``: it passed the check (False: no candidate
    did, ``reason`` says so); ``paper``: the standard model ``wn+gm`` as the paper
    fits it; ``candidates``: every fitted candidate in fitting order; ``fine``: the
    fine-scale statistic and filter test; ``time_s``: the whole choice, s.
    ``chosen.ci90`` is already mixed with the intervals of the ``close`` models.
    """

    chosen: CompositeResult
    fits: bool
    reason: str
    paper: CompositeResult | None
    candidates: tuple[Candidate, ...]
    fine: FineStatistic
    time_s: float
    #: the other models that fit and whose BIC is within BIC_STRONG of the chosen one's: the
    #: chosen model's intervals are mixed with theirs (:func:`mixed_interval`)
    close: tuple[CompositeResult, ...] = ()

    def indistinct(self) -> str | None:
        """A sentence when the models that fit nearly as well have another bias structure (a Gauss-Markov
        term against flicker and random walk): the data cannot tell them apart, and N, B, K's intervals
        are mixed over them; None otherwise. A close model that only adds or drops a random walk
        (``wn+fl`` beside ``wn+fl+rw``) is the same structure: K's interval and bound say that."""
        mine = _structure(self.chosen.model)
        other = [r.model for r in self.close if _structure(r.model) != mine]
        if not other:
            return None
        return (
            f"the data cannot tell {self.chosen.model} from {', '.join(other)} (BIC within {BIC_STRONG:g}, both fit): "
            "N, B, K and the parameters they share have intervals mixed over them"
        )

    def selection_dict(self) -> dict:
        """The ``selection`` object of the JSON document (docs/analysis-json.md)."""
        f = self.fine
        return {
            "rule": "simplest model that fits (stages of growing size; smallest BIC among those that fit)",
            "chosen": self.chosen.model,
            "fits": self.fits,
            "reason": self.reason,
            "angle_term": f.term or None,
            "tau_lp": f.tau_lp if f.term == "lp" else None,
            "filter_source": f.source,
            "memory_s": f.memory_s if f.term else 0.0,
            "flicker_cut_s": flicker_cut(self.chosen) or None,
            "close_models": [r.model for r in self.close],
            "indistinct": self.indistinct(),
            "candidates": [c.as_dict() for c in self.candidates],
        }


def flicker_cut(res: MLiResult) -> float:
    """The cut-off (s) of a fit's bias instability; 0 without one (or without a bias instability)."""
    return next((float(t.cut_s) for t in res.noise_model.terms if t.code == "fl"), 0.0)


def flicker_cuts(fs_hz: float, duration_s: float) -> list[float]:
    """Cut-offs (s) tried for a bias instability: :data:`CUTS_PER_DECADE` per decade above the
    sum's first term, up to :data:`FLICKER_CUT_MAX_S`."""
    first = flicker_times(fs_hz, duration_s)[0]
    n = round(CUTS_PER_DECADE * math.log10(FLICKER_CUT_MAX_S / first))
    return [first * 10.0 ** (i / CUTS_PER_DECADE) for i in range(1, n + 1)]


def screen_cut(res: MLiResult, allan: AllanResult, cuts: list[float], duration_s: float) -> float:
    """The cut-off of ``cuts`` (s) under which the fit ``res`` to a record of ``duration_s`` s, its
    parameters kept, is nearest to the measured Allan variance (chi-square from the fit's filter
    memory on, each tau with its own error, correlation across tau ignored): one refit instead
    of one per cut-off."""
    keep = allan.tau >= max(res.memory_s, 0.0)
    tau, avar = allan.tau[keep], allan.adev[keep] ** 2
    err = avar * np.sqrt(2.0 / np.maximum(allan.edf[keep], 1.0))
    scores = []
    for cut in cuts:
        spec = ParamSpec.for_record(res.model, res.fs_hz, duration_s, cut)
        model = spec.model(res.phi, res.b_on, res.memory_s).avar(tau, res.fs_hz)
        scores.append(float(np.sum(((model - avar) / err) ** 2)))
    return cuts[int(np.argmin(scores))]


def _with(bias: str, angle: str) -> str:
    return "+".join(["wn", bias] + ([angle] if angle else []))


# ---------------------------------------------------------------------------
# start points


def _levels(kind: str, T: float) -> list[float]:
    """theta values of a new coordinate of kind ``kind`` for a record of ``T`` s: the term's
    Allan variance meets the white level (sigma_w = 1) at T/300, T/30, T/3."""
    out = []
    for tx in (T / 300.0, T / 30.0, T / 3.0):
        if kind == "r_fl":  # 0.44 B^2 = 1/tx
            out.append(math.log(1.0 / (FLICKER_FLOOR**2 * tx)))
        elif kind == "r_rw":  # K^2 tx/3 = 1/tx
            out.append(math.log(3.0 / tx**2))
    return out


def family_starts(
    problem: CompositeProblem, fine: FineStatistic, fitted: list[MLiResult], n_best: int = 2
) -> list[np.ndarray]:
    """Start points (theta) of a candidate: every combination of the values its terms take in the
    smaller fits (by name) and of default levels (:func:`_levels`; Gauss-Markov terms: correlation
    times T/300, T/30, T/3 at the white level), scored in one likelihood batch; the ``n_best`` best."""
    spec = problem.spec
    T = problem.inc.duration
    kinds = spec.theta_kinds()
    names = spec.phi_names()[1:]
    options: list[list[tuple[float, ...]]] = []
    j = 0
    ngm = spec.codes.count("gm")
    for c in spec.others:
        if c == "gm":
            opts = []
            for tx in (T / 300.0, T / 30.0, T / 3.0):
                opts.append((math.log(2.8 / tx**2), math.log(tx / 2.0)))
            for r in fitted:
                keys = [k for k in r.params if k.startswith("tau_b")]
                for k in keys:
                    sfx = k[len("tau_b") :]
                    opts.append((2.0 * math.log(r.params["sigma_b" + sfx] / r.sigma_w), math.log(r.params[k])))
            options.append(opts)
            j += 2
            continue
        kind = kinds[j]
        name = names[j]
        if c == "lp":
            opts = [(math.log(max(fine.tau_lp, 1e-12)) / spec.angle_scale,)]
        elif c == "wa":
            opts = [(math.log(max(-fine.tau_lp / 2.0, 1e-12)) / spec.angle_scale,)]
        else:
            opts = [(v,) for v in _levels(kind, T)]
            opts += [(2.0 * math.log(r.params[name] / r.sigma_w),) for r in fitted if name in r.params]
        options.append(opts)
        j += 1
    combos = [np.concatenate(c) for c in itertools.product(*options)]
    if ngm > 1:  # the likelihood is symmetric in the Gauss-Markov terms: keep one order
        gm_cols = [i for i, k in enumerate(kinds) if k == "tau"]
        combos = [x for x in combos if all(np.diff(x[gm_cols]) > 0.5)]
    pts = np.clip(np.array(combos), problem.lo, problem.hi)
    pts = np.unique(np.round(pts, 6), axis=0)
    f = problem.nll(pts)
    order = np.argsort(f)
    chosen: list[np.ndarray] = []
    for i in order:
        if not np.isfinite(f[i]):
            break
        if all(np.abs(pts[i] - x).max() > 0.5 for x in chosen):
            chosen.append(pts[i])
        if len(chosen) == n_best:
            break
    return chosen


# ---------------------------------------------------------------------------
# the choice


def choose_model(
    rate: np.ndarray,
    fs_hz: float,
    *,
    scale: float = 1.0,
    segments: list[tuple[int, int]] | None = None,
    hint: FilterHint | None = None,
    allan: AllanResult | None = None,
    m: int = DEFAULT_M,
    paper: bool = True,
) -> ModelChoice:
    """Fit the family's candidates to one channel and choose (module docstring).

    ``rate``: (n,) rad/s (m/s^2), or integer counts with ``scale`` units per count;
    ``fs_hz`` Hz; ``segments`` contiguous sample ranges; ``hint``: the device's filter
    settings; ``allan``: the channel's overlapping Allan deviation (computed if not
    given).
    """
    t0 = time.perf_counter()
    rate = check_rate(rate, fs_hz)
    fine = fine_statistics(rate, fs_hz, scale=scale, segments=segments, hint=hint)
    # pattern intervals at least 10 filter memories long (the device-filter term needs them)
    m_eff = int(min(m, max(8, len(rate) // 2)))
    if fine.term:
        m_eff = int(max(8, min(m_eff, len(rate) / (fs_hz * 10.0 * fine.memory_s))))
    inc = integrate(rate, fs_hz, m=m_eff, pattern="uniform", scale=scale, segments=segments)
    if allan is None:
        allan = oadev(rate, fs_hz, scale=scale, segments=segments)
    paper_fit = None
    if paper:
        paper_fine = fine_scale(rate, fs_hz, samples="auto", scale=scale, segments=segments, octaves=fine.octaves)
        paper_fit = fit_composite_data(inc, paper_fine, PAPER_MODEL, robust=True)
    fitted: list[MLiResult] = [paper_fit] if paper_fit is not None and paper_fit.converged else []
    cands: list[Candidate] = []
    lengths = tuple(b - a for a, b in segments) if segments else (len(rate),)

    def fit(bias: str, stage: int, cut_s: float = 0.0, start_from: MLiResult | None = None) -> None:
        name = _with(bias, fine.term)
        spec = ParamSpec.for_record(name, fs_hz, inc.duration, cut_s if "fl" in bias else 0.0)
        if any(c.key == (spec.name, spec.flicker_cut_s) for c in cands):
            return
        if fine.term:
            spec = replace(spec, angle_scale=angle_scale(fine))
        problem = CompositeProblem(inc, spec, fine)
        if start_from is not None and start_from.phi is not None:  # the same model with another setting
            starts = [np.clip(spec.theta_of_phi(start_from.phi[None, :])[0], problem.lo, problem.hi)]
        else:
            starts = family_starts(problem, fine, fitted)
        try:
            res = fit_composite_data(
                inc, fine, spec, extra_starts=starts, robust=True, starts_only=True, max_iter=MAX_NEWTON
            )
        except InputError:
            return
        cands.append(Candidate(res, stage, (allan, fs_hz, lengths)))
        fitted.append(res)

    def try_cuts(stage: int) -> None:
        """Without a model that fits in ``stage``: its smallest-BIC bias instability, refitted with the
        cut-off the Allan deviation suggests (:func:`screen_cut`; module docstring)."""
        uncut = [
            c
            for c in cands
            if c.stage == stage and c.result.converged and not c.cut_s and "fl" in _bias_of(c.result.model)
        ]
        if not uncut:
            return
        base = min(uncut, key=lambda c: c.result.bic)
        if any(m.tau_lo > CUT_REACH * FLICKER_CUT_MAX_S for m in base.check.misfit):
            return  # it misses where no cut-off changes the model: a larger model is needed
        cuts = flicker_cuts(fs_hz, inc.duration)
        if not cuts:  # sampled at 1 Hz or slower: the sum starts at 1 s already
            return
        cut = screen_cut(base.result, allan, cuts, inc.duration)
        fit(_bias_of(base.result.model).replace("gm+gm", "2gm"), stage, cut, start_from=base.result)

    def top_of(stage: int, below: float) -> Candidate | None:
        """The smallest-BIC candidate of ``stage`` that passes, if its BIC is below ``below``
        (tested in BIC order, so candidates that could not be chosen are not tested)."""
        for c in sorted((c for c in cands if c.stage == stage and c.result.converged), key=lambda c: c.result.bic):
            if c.result.bic >= below:
                return None
            if c.passes:
                return c
        return None

    def extends(bias: str, base: Candidate) -> bool:
        return set(_bias_of(base.result.model).split("+")) <= set(bias.replace("2gm", "gm+gm").split("+"))

    best = None
    lead = None  # without a model that fits: the smallest BIC so far, whose extensions are tried next
    for stage, biases in enumerate(STAGES, start=1):
        base = best or lead
        for bias in biases:
            if base is None or extends(bias, base):  # a larger model must earn its place
                fit(bias, stage, best.cut_s if best is not None else 0.0)  # a chosen cut-off stays
        if best is None and top_of(stage, math.inf) is None:
            try_cuts(stage)
        top = top_of(stage, math.inf if best is None else best.result.bic - BIC_STRONG)
        if top is not None:  # the first stage with a model that fits gives the choice
            best = top
            continue
        if best is not None:
            break
        converged = [c for c in cands if c.stage == stage and c.result.converged]
        if converged:
            top_any = min(converged, key=lambda c: c.result.bic)
            if lead is not None and top_any.result.bic >= lead.result.bic - BIC_STRONG:
                break  # nothing fits and a larger model does not help either
            lead = top_any
    if best is not None:
        cut = f" (bias instability cut off below {best.cut_s:g} s)" if best.cut_s else ""
        reason = (
            f"{best.result.model}{cut}: the simplest model that fits the Allan deviation (stage {best.stage}, "
            f"the smallest BIC there; a larger model needs a BIC {BIC_STRONG:g} lower)"
        )
        close = tuple(
            c.result
            for c in cands
            if c is not best and c.result.converged and c.result.bic <= best.result.bic + BIC_STRONG and c.passes
        )
        more = later_octaves(fine, rate, fs_hz, scale=scale, segments=segments)
        chosen = guard_white(_join_intervals(best.result, close), fine, fs_hz, more)
        return ModelChoice(chosen, True, reason, paper_fit, tuple(cands), fine, time.perf_counter() - t0, close)
    if not cands:
        raise InputError("no model of the family could be fitted")
    usable = [c for c in cands if c.result.converged] or cands
    worst = min(usable, key=lambda c: c.result.bic)
    if worst.result.converged:
        reason = (
            f"no model of the family fits the Allan deviation ({worst.check.summary()}); "
            f"{worst.result.model} has the smallest BIC"
        )
    else:  # its curve may pass the adequacy test, but no fit converged: 'NO MODEL FITS (fits)' said nothing
        reason = (
            f"no fit of the family converged ({worst.result.model}, the smallest BIC: {worst.result.message}; "
            f"its curve against the Allan deviation: {worst.check.summary()})"
        )
    more = later_octaves(fine, rate, fs_hz, scale=scale, segments=segments)
    chosen = guard_white(worst.result, fine, fs_hz, more)
    return ModelChoice(chosen, False, reason, paper_fit, tuple(cands), fine, time.perf_counter() - t0)


def mixed_interval(
    intervals: list[tuple[float, float, float]], zero_bics: tuple[float, ...] = ()
) -> tuple[float, float]:
    """90 % interval of a positive parameter over several models: ``(lo, hi, bic)`` per model.

    Each model's interval is read as a log-normal (symmetric in the log, as the fits state
    them) and weighted by ``exp(-BIC/2)`` (the BIC approximation of the posterior model
    probability); the 5 % and 95 % points of the mixture are returned. A nested model
    that did not earn its place (BIC a few units higher) widens the interval a little, not
    to its own full width. Intervals that are not finite and positive are left out.
    ``zero_bics``: the BICs of models without the term (the parameter 0 in them, a point mass
    at 0 in the mixture); when that mass reaches 5 % the interval starts at 0 — the data
    cannot tell the term from nothing, and its upper end is what they can exclude.
    """
    ok = [(lo, hi, b) for lo, hi, b in intervals if 0 < lo <= hi < math.inf and math.isfinite(b)]
    zeros = np.array([b for b in zero_bics if math.isfinite(b)], dtype=float)
    if not ok:
        return (math.nan, math.nan)
    lo, hi, bic = (np.array(v, dtype=float) for v in zip(*ok, strict=True))
    mu = 0.5 * (np.log(lo) + np.log(hi))
    sd = np.maximum((np.log(hi) - np.log(lo)) / (2.0 * Z90), 1e-12)
    ref = min(float(bic.min()), float(zeros.min()) if len(zeros) else math.inf)
    w = np.exp(-0.5 * (bic - ref))
    w0 = float(np.exp(-0.5 * (zeros - ref)).sum())
    total = w.sum() + w0
    w, p0 = w / total, w0 / total
    grid = np.linspace(float(np.min(mu - 4 * sd)), float(np.max(mu + 4 * sd)), 4001)
    cdf = (w[:, None] * ndtr((grid[None, :] - mu[:, None]) / sd[:, None])).sum(axis=0)
    if p0 >= 0.05:
        # the upper end among the models that carry the term (conservative: the atom at 0 would lower it)
        return (0.0, float(np.exp(np.interp(0.95, cdf / cdf[-1], grid))))
    q = np.interp([0.05, 0.95], p0 + cdf, grid)
    return (float(np.exp(q[0])), float(np.exp(q[1])))


def _join_intervals(res: CompositeResult, close: tuple[CompositeResult, ...]) -> CompositeResult:
    """``res`` with each parameter's 90 % interval mixed (:func:`mixed_interval`) with the same
    parameter's interval in the ``close`` models (models that fit nearly as well: which of them
    is the model is itself uncertain)."""
    ci = dict(res.ci90)
    for key in ci:
        if key not in res.params:
            continue
        items = [(*m.ci90[key], m.bic) for m in (res, *close) if key in m.ci90 and key in m.params]
        if len(items) > 1:
            lo, hi = mixed_interval(items)
            if math.isfinite(lo):
                ci[key] = (lo, hi)
    return replace(res, ci90=ci)


def _bias_of(model: str) -> str:
    """The bias structure of a family model name (``"wn+gm+fl+lp"`` -> ``"gm+fl"``; two GMs as ``gm+gm``)."""
    codes = [c for c in model.split("+") if c not in ("wn", "lp", "wa")]
    out = []
    for c in codes:
        out += ["gm", "gm"] if c == "2gm" else [c]
    return "+".join(out)


def _structure(model: str) -> tuple[bool, bool]:
    """What tells bias structures apart for :meth:`ModelChoice.indistinct`: a Gauss-Markov term, a bias
    instability (a random walk beside them is the same structure with or without)."""
    codes = set(_bias_of(model).split("+"))
    return ("gm" in codes, "fl" in codes)


def as_choice_result(choice: ModelChoice) -> CompositeResult:
    """The chosen fit with the choice named in its message."""
    r = choice.chosen
    note = f"auto: {choice.reason}"
    return replace(r, message=f"{r.message}; {note}")
