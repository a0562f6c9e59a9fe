"""Per-channel analysis and the ``imustation-analysis`` JSON document (v1)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from imustation.analysis.estimators.classical.allan import AllanResult, oadev
from imustation.analysis.estimators.classical.allan_bounds import ieee_usability, with_bounds
from imustation.analysis.estimators.classical.ieee import IEEECoefficients, ieee_coefficients
from imustation.analysis.estimators.classical.periodic import Component, find_sinusoids, remove_sinusoids
from imustation.analysis.estimators.classical.resonance import Resonance, find_resonances
from imustation.analysis.estimators.engine.fitting import MLiResult
from imustation.analysis.estimators.engine.pattern import integrate
from imustation.analysis.estimators.ml.composite import fit_composite
from imustation.analysis.estimators.ml.finescale import FilterHint
from imustation.analysis.estimators.ml.gmwm import fit_gmwm
from imustation.analysis.estimators.ml.mli import compare_models, fit_integrated
from imustation.analysis.estimators.selection.adequacy import Adequacy
from imustation.analysis.estimators.selection.adequacy import fit_adequacy as result_adequacy
from imustation.analysis.estimators.selection.coefficients import ieee952_summary
from imustation.analysis.estimators.selection.model_choice import ModelChoice, as_choice_result, choose_model
from imustation.analysis.estimators.selection.screen import screen
from imustation.analysis.pipeline.choices import (
    DEFAULT_ESTIMATOR,
    DEFAULT_METHOD,
    DEFAULT_MODEL,
    ESTIMATORS,
    FILTER_TERM,
    METHODS,
    MODEL_AUTO,
    PAPER_MODEL,
)
from imustation.analysis.pipeline.devicefilter import filter_hint
from imustation.analysis.pipeline.loaders import Channel
from imustation.analysis.pipeline.verdict import Verdict, channel_verdict
from imustation.errors import InputError, RecordTooShort
from imustation.units import sensor_kind

DOC_FORMAT = "imustation-analysis"
DOC_VERSION = 1


@dataclass(frozen=True)
class ChannelAnalysis:
    channel: Channel
    allan: AllanResult
    ieee: IEEECoefficients
    mli: MLiResult | None
    models: tuple[MLiResult, ...] = ()
    gmwm: MLiResult | None = None
    verdict: Verdict | None = None
    #: the default estimator's result (``noise_model`` block); reports and exports use it
    noise_model: MLiResult | None = None
    noise_method: str = ""
    #: model adequacy of every fitted block, by block key ("noise_model", "mli", "gmwm", "models/<model>")
    adequacy: dict[str, Adequacy] = field(default_factory=dict)
    #: ``--model auto``: the candidates, the check of each and the paper's wn+gm fit
    choice: ModelChoice | None = None
    #: spectral peaks found (:mod:`.periodic`): sinusoids were removed before every fit, resonances named
    periodic: tuple[Component, ...] = ()
    #: resonances (:mod:`.resonance`): with ``--model auto`` the white noise is read beyond them
    resonances: tuple[Resonance, ...] = ()

    def adequacy_of(self, fit: MLiResult | None) -> Adequacy | None:
        """The adequacy of one of this channel's fits (None for a fit without one)."""
        if fit is None:
            return None
        for key, block in self.blocks().items():
            if block is fit:
                return self.adequacy.get(key)
        return None

    def ieee952(self, fit: MLiResult) -> dict:
        """N, B, K and the Gauss-Markov terms of ``fit`` (:func:`ieee952_summary`); for the automatic
        choice's own fit, B's interval mixed with the models that fit nearly as well (not for another
        fit, e.g. ``--estimator mli``'s or the model ``fleet`` keeps for a device); with the upper bounds
        on K and B the Allan deviation sets (:func:`.allan_bounds.with_bounds`)."""
        chosen = self.choice is not None and fit.noise_model is self.choice.chosen.noise_model
        summary = ieee952_summary(fit, self.channel.n / self.channel.fs_hz, self.choice.close if chosen else ())
        return with_bounds(summary, self.allan, self.choice.fits if chosen else True)

    def blocks(self) -> dict[str, MLiResult]:
        """Every fitted model block by its key (the JSON's block names; compared models as ``models/<name>``)."""
        out = {k: f for k, f in (("noise_model", self.noise_model), ("mli", self.mli), ("gmwm", self.gmwm)) if f}
        out.update({f"models/{r.model}": r for r in self.models})
        if self.choice is not None and self.choice.paper is not None:
            out["paper_model"] = self.choice.paper
        return out


#: ``skipped`` kind of a channel whose pieces between logged holes are each too short for any estimate
FRAGMENTED = "fragmented"


class DegenerateChannel(InputError):
    """A channel with nothing to characterise (constant, saturated, stuck, all quantisation):
    skipped with its reason (:mod:`imustation.analysis.estimators.selection.screen`); ``kind`` names which."""

    def __init__(self, message: str, kind: str) -> None:
        super().__init__(message)
        self.kind = kind

    def __reduce__(self):  # travels back from cluster workers intact
        return (type(self), (str(self), self.kind))


def check_channel(ch: Channel) -> None:
    """Raise :class:`DegenerateChannel` when the channel's samples are degenerate."""
    deg = screen(ch.data, scale=ch.scale, units=ch.units)
    if deg is not None:
        raise DegenerateChannel(f"skipped {ch.id}: {deg.reason}", deg.kind)


def fit_adequacy(ch: Channel, allan: AllanResult, fit: MLiResult) -> Adequacy | None:
    """Adequacy of ``fit`` against the channel's measured Allan variance (None without a model)."""
    if fit.noise_model is None:
        return None
    return result_adequacy(allan, fit, ch.fs_hz, [b - a for a, b in ch.segments])


def without_sinusoids(ch: Channel) -> tuple[tuple[Component, ...], Channel]:
    """The spectral peaks of ``ch`` (:func:`.periodic.find_sinusoids`) and the channel to analyse: ``ch``
    itself, or, when sinusoids were found, a float copy with them subtracted (same id, segments, metadata)."""
    found = tuple(find_sinusoids(ch.data, ch.fs_hz, ch.scale))
    if not any(c.kind == "sinusoid" for c in found):
        return found, ch
    clean = remove_sinusoids(ch.data, ch.fs_hz, list(found), ch.scale)
    work = Channel(ch.id, ch.fs_hz, ch.units, clean, 1.0, source=ch.source, gaps=ch.gaps, meta=ch.meta,
                   segments=list(ch.segments))  # fmt: skip
    return found, work


def beyond_resonances(hint: FilterHint | None, resonances: tuple[Resonance, ...]) -> FilterHint | None:
    """``hint`` (the device's filter settings, or None) with the fine scales starting beyond the
    resonances' bands (:attr:`.Resonance.start_s`); ``hint`` itself without resonances."""
    start = max((r.start_s for r in resonances), default=0.0)
    if start <= 0:
        return hint
    return replace(hint, start_s=start) if hint is not None else FilterHint(False, 0.0, "", start_s=start)


def _reported(resonances: tuple[Resonance, ...], why: str) -> tuple[Resonance, ...]:
    """``resonances`` as reported only (the white noise not read beyond them), with ``why``."""
    return tuple(replace(r, start_s=0.0, reason=f"{r.reason.split(': the white')[0]}: reported only ({why}); "
                         "sigma_w's interval takes in the later scales' reading") for r in resonances)  # fmt: skip


def _within(c: Component, resonances: tuple[Resonance, ...]) -> bool:
    """Whether the peak test's narrow-band ``c`` is one of ``resonances`` (a sinusoid never is)."""
    return c.kind == "resonance" and any(r.band_hz[0] <= c.frequency_hz <= r.band_hz[1] for r in resonances)


def analyze_channel(
    ch: Channel,
    *,
    pattern: str | None = None,
    m: int = 1000,
    model: str = DEFAULT_MODEL,
    compare: tuple[str, ...] = (),
    method: str = DEFAULT_METHOD,
    estimator: str = DEFAULT_ESTIMATOR,
    need: tuple[str, ...] | None = None,
) -> ChannelAnalysis:
    """Allan deviation, IEEE-952 coefficients and the noise-model fits of one channel.

    Raises :class:`DegenerateChannel` (an :class:`InputError`) for a channel with nothing to
    characterise, before any fit.

    ``estimator`` (``"mli-f"``, ``"mli"`` or ``"gmwm"``) fills ``noise_model``,
    the result reports and exports use. ``method``: the comparison blocks
    ``"mli"``, ``"gmwm"`` or ``"both"``; ``pattern`` and ``m`` are ML_i's (``pattern`` None: the
    paper's ``"log"``, or ``"uniform"`` for a model with a device filter, which the log pattern
    cannot hold).
    ``compare``: further models fitted by ML_i to the same integrated record (AIC/BIC).
    ``need``: the parameters the "enough data?" verdict judges (:func:`.verdict.channel_verdict`).
    ``model="auto"``: ML_i-F chooses the model (:func:`choose_model`, the device's
    filter settings from the run file as a hint); GMWM then fits the chosen model from
    the filter's memory on, ML_i (the paper's estimator) the paper's model, and the
    IEEE-952 fit starts beyond the filter's memory.
    """
    if method not in METHODS:
        raise InputError(f"method {method!r}: use one of {', '.join(METHODS)}")
    if estimator not in ESTIMATORS:
        raise InputError(f"estimator {estimator!r}: use one of {', '.join(ESTIMATORS)}")
    check_channel(ch)
    try:
        return _analyze_checked(ch, pattern, m, model, compare, method, estimator, need)
    except RecordTooShort as exc:
        if len(ch.segments) < 2:
            raise
        # every estimate is pooled over the pieces between logged holes; when they are all too short
        # for it, no estimate exists, and the channel is skipped with why instead of failing the run
        why = str(exc).removeprefix(f"{ch.n} samples: ")  # the count is in the reason already
        raise DegenerateChannel(f"skipped {ch.id}: {fragmented_reason(ch)}: {why}", FRAGMENTED) from exc


def fragmented_reason(ch: Channel) -> str:
    """How a channel is split by its logged holes: pieces, the longest (samples and seconds), samples lost."""
    lengths = np.array([b - a for a, b in ch.segments])
    longest = int(lengths.max())
    return (
        f"{ch.n} samples in {len(lengths)} pieces between {ch.gaps} logged holes, the longest "
        f"{longest} samples ({longest / ch.fs_hz:.3g} s)"
    )


def _analyze_checked(ch, pattern, m, model, compare, method, estimator, need) -> ChannelAnalysis:
    """:func:`analyze_channel` of a channel :func:`check_channel` passed."""
    original = ch
    # sinusoids are not noise: measured, removed and named before anything is fitted (issue 32)
    periodic, ch = without_sinusoids(ch)
    # resonances are no term of the family: the model choice reads the white noise beyond them
    resonances = tuple(find_resonances(ch.data, ch.fs_hz, ch.scale))
    periodic = tuple(c for c in periodic if not _within(c, resonances))
    allan = oadev(ch.data, ch.fs_hz, scale=ch.scale, segments=ch.segments)
    choice, tau_min = None, 0.0
    if model == MODEL_AUTO:
        hint = beyond_resonances(filter_hint(ch.meta, ch.fs_hz), resonances)
        choice = choose_model(ch.data, ch.fs_hz, scale=ch.scale, segments=ch.segments, hint=hint, allan=allan)
        model = choice.chosen.model
        tau_min = choice.fine.memory_s if choice.fine.term or choice.fine.excluded_s > 0 else 0.0
        if resonances and choice.fine.excluded_s <= 0:  # the fine statistic found the slow terms beyond it
            resonances = _reported(resonances, choice.fine.source.rsplit("; a resonance: ", 1)[-1])
    else:  # a model the user named is fitted as named: the resonance is reported, nothing moved
        resonances = _reported(
            resonances, "a named model is fitted as named; --model auto reads the white noise beyond it"
        )
    ieee = ieee_coefficients(allan, tau_min=tau_min)
    mli, models, gmwm = None, (), None
    if method in ("mli", "both") or estimator == "mli":
        mli_model = PAPER_MODEL if choice is not None else model  # the paper's estimator with its model
        if pattern is None:
            pattern = "uniform" if FILTER_TERM in mli_model.split("+") else "log"
        inc = integrate(ch.data, ch.fs_hz, m=m, pattern=pattern, scale=ch.scale, segments=ch.segments)
        mli = fit_integrated(inc, mli_model)
        models = tuple(compare_models(inc, tuple(dict.fromkeys((mli_model, *compare))))) if compare else ()
    if method in ("gmwm", "both") or estimator == "gmwm":
        gmwm = fit_gmwm(ch.data, ch.fs_hz, model, scale=ch.scale, segments=ch.segments, tau_min=tau_min)
    if estimator == "mli-f":
        if choice is not None:
            best = as_choice_result(choice)
        else:
            # the device's filter settings, as --model auto gets them: a model with lp needs its scale
            best = fit_composite(
                ch.data, ch.fs_hz, model, scale=ch.scale, segments=ch.segments, hint=filter_hint(ch.meta, ch.fs_hz)
            )
    else:
        best = mli if estimator == "mli" else gmwm
    # only the requested comparison blocks are reported
    mli_block = mli if method in ("mli", "both") else None
    gmwm_block = gmwm if method in ("gmwm", "both") else None
    # the classic Allan-curve fit is checked against what any noise term allows and the model's N interval
    ieee = ieee_usability(ieee, allan, best.ci90.get("sigma_w") if best is not None else None)
    summary = None
    if choice is not None and best is not None and estimator == "mli-f":  # N, B, K judge the record
        summary = with_bounds(ieee952_summary(best, ch.n / ch.fs_hz, choice.close), allan, choice.fits)
    verdict = channel_verdict(ch, allan, best, need, summary)
    res = ChannelAnalysis(original, allan, ieee, mli_block, models, gmwm_block, verdict, best, estimator,
                          choice=choice, periodic=periodic, resonances=resonances)  # fmt: skip
    done: dict[int, Adequacy | None] = {}  # a fit shared by two blocks is tested once
    if choice is not None:  # the choice tested its candidates against this Allan variance already
        tested = {id(c.result.noise_model): c.check for c in choice.candidates if c.tested}
        for fit in res.blocks().values():
            if id(fit.noise_model) in tested:
                done[id(fit)] = tested[id(fit.noise_model)]
    for key, fit in res.blocks().items():
        if id(fit) not in done:
            done[id(fit)] = fit_adequacy(ch, allan, fit)
        if done[id(fit)] is not None:
            res.adequacy[key] = done[id(fit)]
    return res


def _num(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _clean(obj):
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [_num(v) for v in obj.tolist()]
    if isinstance(obj, (float, np.floating)):
        return _num(float(obj))
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def _block(res: ChannelAnalysis, key: str, fit: MLiResult, extra: dict | None = None) -> dict:
    """A fitted model block: the fit's keys, ``adev_model`` at ``allan.tau`` and its ``adequacy``."""
    out = {**fit.as_dict(), **(extra or {})}
    adq = res.adequacy.get(key)
    if adq is not None:
        out["adev_model"] = adq.adev_model
        out["adequacy"] = adq.as_dict()
    return out


def channel_document(res: ChannelAnalysis) -> dict:
    ch = res.channel
    return _clean(
        {
            "id": ch.id,
            "fs_hz": ch.fs_hz,
            "n": ch.n,
            "units": ch.units,
            "duration_s": ch.n / ch.fs_hz,
            "source": ch.source,
            "gaps": ch.gaps,
            # the start left out (--warmup; analysis/pipeline/warmup.py): what was cut and why
            **({"warmup": ch.meta["warmup"].as_dict()} if "warmup" in ch.meta else {}),
            **(_noise_blocks(res) if res.noise_model is not None else {}),
            **({"mli": _block(res, "mli", res.mli)} if res.mli is not None else {}),
            **({"gmwm": _block(res, "gmwm", res.gmwm)} if res.gmwm is not None else {}),
            **({"models": [_block(res, f"models/{r.model}", r) for r in res.models]} if res.models else {}),
            "allan": {
                "tau": res.allan.tau,
                "adev": res.allan.adev,
                "adev_lo": res.allan.adev_lo,
                "adev_hi": res.allan.adev_hi,
                "edf": res.allan.edf,
                "alpha": res.allan.alpha,
            },
            "ieee": res.ieee.as_dict(),
            "periodic": [c.as_dict() for c in res.periodic],
            "resonances": [r.as_dict() for r in res.resonances],
            **({"verdict": res.verdict.as_dict()} if res.verdict is not None else {}),
        }
    )


def _noise_blocks(res: ChannelAnalysis) -> dict:
    """``noise_model`` (with ``ieee952``, and ``selection`` for ``--model auto``) and ``paper_model``."""
    nm = res.noise_model
    extra = {"method": nm.estimator, "ieee952": res.ieee952(nm)}
    if res.choice is not None:
        extra["selection"] = res.choice.selection_dict()
    out = {"noise_model": _block(res, "noise_model", nm, extra)}
    paper = res.choice.paper if res.choice is not None else None
    if paper is not None:
        extra = {"method": paper.estimator, "ieee952": res.ieee952(paper)}
        out["paper_model"] = _block(res, "paper_model", paper, extra)
    return out


def analysis_document(results: list[ChannelAnalysis]) -> dict:
    """The JSON document of docs/analysis-json.md."""
    return {"format": DOC_FORMAT, "version": DOC_VERSION, "channels": [channel_document(r) for r in results]}


def split_channel_id(ch) -> tuple[str, str, str]:
    """(device, sensor, axis) of a ``device/gyro|accel/axis`` id, else the sensor from the units."""
    parts = ch.id.split("/")
    kind = sensor_kind(ch.units, ch.id)
    if kind is None:
        raise InputError(
            f"channel {ch.id}: units {ch.units!r} name neither a gyroscope (rad/s) nor an accelerometer (m/s^2)"
        )
    if len(parts) >= 3 and parts[-2] == kind:
        return "/".join(parts[:-2]), kind, parts[-1]
    return ch.id, kind, "-"
