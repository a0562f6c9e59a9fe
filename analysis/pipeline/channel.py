"""Per-channel analysis and the ``imustation-analysis`` JSON document (v1)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from imustation.analysis.estimators.allan import AllanResult, oadev
from imustation.analysis.estimators.composite import fit_composite
from imustation.analysis.estimators.fitting import MLiResult
from imustation.analysis.estimators.gmwm import fit_gmwm
from imustation.analysis.estimators.ieee import IEEECoefficients, ieee_coefficients
from imustation.analysis.estimators.mli import compare_models, fit_integrated
from imustation.analysis.estimators.model_choice import ModelChoice, as_choice_result, choose_model, ieee952_summary
from imustation.analysis.estimators.pattern import integrate
from imustation.analysis.pipeline.choices import (
    DEFAULT_ESTIMATOR,
    DEFAULT_METHOD,
    DEFAULT_MODEL,
    ESTIMATORS,
    METHODS,
    MODEL_AUTO,
    PAPER_MODEL,
)
from imustation.analysis.pipeline.devicefilter import filter_hint
from imustation.analysis.pipeline.loaders import Channel
from imustation.analysis.pipeline.verdict import Verdict, channel_verdict
from imustation.errors import InputError

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
    #: ``--model auto``: the candidates, the check of each and the paper's wn+gm fit
    choice: ModelChoice | None = None


def analyze_channel(
    ch: Channel,
    *,
    pattern: str = "log",
    m: int = 1000,
    model: str = DEFAULT_MODEL,
    compare: tuple[str, ...] = (),
    method: str = DEFAULT_METHOD,
    estimator: str = DEFAULT_ESTIMATOR,
) -> ChannelAnalysis:
    """Allan deviation, IEEE-952 coefficients and the noise-model fits of one channel.

    ``estimator`` (``"mli-f"``, ``"mli"`` or ``"gmwm"``) fills ``noise_model``,
    the result reports and exports use. ``method``: the comparison blocks
    ``"mli"``, ``"gmwm"`` or ``"both"``; ``pattern`` and ``m`` are ML_i's.
    ``compare``: further models fitted by ML_i to the same integrated record (AIC/BIC).
    ``model="auto"``: ML_i-F chooses the model (:func:`choose_model`, the device's
    filter settings from the run file as a hint); GMWM then fits the chosen model from
    the filter's memory on, ML_i (the paper's estimator) the paper's model, and the
    IEEE-952 fit starts beyond the filter's memory.
    """
    if method not in METHODS:
        raise InputError(f"method {method!r}: use one of {', '.join(METHODS)}")
    if estimator not in ESTIMATORS:
        raise InputError(f"estimator {estimator!r}: use one of {', '.join(ESTIMATORS)}")
    allan = oadev(ch.data, ch.fs_hz, scale=ch.scale, segments=ch.segments)
    choice, tau_min = None, 0.0
    if model == MODEL_AUTO:
        hint = filter_hint(ch.meta, ch.fs_hz)
        choice = choose_model(ch.data, ch.fs_hz, scale=ch.scale, segments=ch.segments, hint=hint, allan=allan)
        model = choice.chosen.model
        tau_min = choice.fine.memory_s if choice.fine.term else 0.0
    ieee = ieee_coefficients(allan, tau_min=tau_min)
    mli, models, gmwm = None, (), None
    if method in ("mli", "both") or estimator == "mli":
        inc = integrate(ch.data, ch.fs_hz, m=m, pattern=pattern, scale=ch.scale, segments=ch.segments)
        mli_model = PAPER_MODEL if choice is not None else model  # the paper's estimator with its model
        mli = fit_integrated(inc, mli_model)
        models = tuple(compare_models(inc, tuple(dict.fromkeys((mli_model, *compare))))) if compare else ()
    if method in ("gmwm", "both") or estimator == "gmwm":
        gmwm = fit_gmwm(ch.data, ch.fs_hz, model, scale=ch.scale, segments=ch.segments, tau_min=tau_min)
    if estimator == "mli-f":
        if choice is not None:
            best = as_choice_result(choice)
        else:
            best = fit_composite(ch.data, ch.fs_hz, model, scale=ch.scale, segments=ch.segments)
    else:
        best = mli if estimator == "mli" else gmwm
    # only the requested comparison blocks are reported
    mli_block = mli if method in ("mli", "both") else None
    gmwm_block = gmwm if method in ("gmwm", "both") else None
    verdict = channel_verdict(ch, allan, best)
    return ChannelAnalysis(ch, allan, ieee, mli_block, models, gmwm_block, verdict, best, estimator, choice)


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
            **(_noise_blocks(res) if res.noise_model is not None else {}),
            **({"mli": res.mli.as_dict()} if res.mli is not None else {}),
            **({"gmwm": res.gmwm.as_dict()} if res.gmwm is not None else {}),
            **({"models": [r.as_dict() for r in res.models]} if res.models else {}),
            "allan": {
                "tau": res.allan.tau,
                "adev": res.allan.adev,
                "adev_lo": res.allan.adev_lo,
                "adev_hi": res.allan.adev_hi,
                "edf": res.allan.edf,
                "alpha": res.allan.alpha,
            },
            "ieee": res.ieee.as_dict(),
            **({"verdict": res.verdict.as_dict()} if res.verdict is not None else {}),
        }
    )


def _noise_blocks(res: ChannelAnalysis) -> dict:
    """``noise_model`` (with ``ieee952``, and ``selection`` for ``--model auto``) and ``paper_model``."""
    duration = res.channel.n / res.channel.fs_hz
    nm = res.noise_model
    block = {**nm.as_dict(), "method": nm.estimator, "ieee952": ieee952_summary(nm, duration)}
    out = {"noise_model": block}
    if res.choice is not None:
        block["selection"] = res.choice.selection_dict()
        paper = res.choice.paper
        if paper is not None:
            summary = ieee952_summary(paper, duration)
            out["paper_model"] = {**paper.as_dict(), "method": paper.estimator, "ieee952": summary}
    return out


def analysis_document(results: list[ChannelAnalysis]) -> dict:
    """The JSON document of docs/analysis-json.md."""
    return {"format": DOC_FORMAT, "version": DOC_VERSION, "channels": [channel_document(r) for r in results]}
