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
from imustation.analysis.estimators.pattern import integrate
from imustation.analysis.pipeline.choices import DEFAULT_ESTIMATOR, DEFAULT_METHOD, DEFAULT_MODEL, ESTIMATORS, METHODS
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
    """
    if method not in METHODS:
        raise InputError(f"method {method!r}: use one of {', '.join(METHODS)}")
    if estimator not in ESTIMATORS:
        raise InputError(f"estimator {estimator!r}: use one of {', '.join(ESTIMATORS)}")
    allan = oadev(ch.data, ch.fs_hz, scale=ch.scale, segments=ch.segments)
    ieee = ieee_coefficients(allan)
    mli, models, gmwm = None, (), None
    if method in ("mli", "both") or estimator == "mli":
        inc = integrate(ch.data, ch.fs_hz, m=m, pattern=pattern, scale=ch.scale, segments=ch.segments)
        mli = fit_integrated(inc, model)
        models = tuple(compare_models(inc, tuple(dict.fromkeys((model, *compare))))) if compare else ()
    if method in ("gmwm", "both") or estimator == "gmwm":
        gmwm = fit_gmwm(ch.data, ch.fs_hz, model, scale=ch.scale, segments=ch.segments)
    if estimator == "mli-f":
        best = fit_composite(ch.data, ch.fs_hz, model, scale=ch.scale, segments=ch.segments)
    else:
        best = mli if estimator == "mli" else gmwm
    # only the requested comparison blocks are reported
    mli_block = mli if method in ("mli", "both") else None
    gmwm_block = gmwm if method in ("gmwm", "both") else None
    verdict = channel_verdict(ch, allan, best)
    return ChannelAnalysis(ch, allan, ieee, mli_block, models, gmwm_block, verdict, best, estimator)


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
            **(
                {"noise_model": {**res.noise_model.as_dict(), "method": res.noise_model.estimator}}
                if res.noise_model is not None
                else {}
            ),
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


def analysis_document(results: list[ChannelAnalysis]) -> dict:
    """The JSON document of docs/analysis-json.md."""
    return {"format": DOC_FORMAT, "version": DOC_VERSION, "channels": [channel_document(r) for r in results]}
