"""Per-channel analysis and the ``imustation-analysis`` JSON document (v1)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from imustation.analysis.allan import AllanResult, oadev
from imustation.analysis.gmwm import fit_gmwm
from imustation.analysis.ieee import IEEECoefficients, ieee_coefficients
from imustation.analysis.loaders import Channel
from imustation.analysis.mli import MLiResult, compare_models, fit_integrated, integrate
from imustation.analysis.verdict import Verdict, channel_verdict
from imustation.errors import InputError

DOC_FORMAT = "imustation-analysis"
DOC_VERSION = 1
#: estimators of ``analyze --method``
METHODS = ("mli", "gmwm", "both")


@dataclass(frozen=True)
class ChannelAnalysis:
    channel: Channel
    allan: AllanResult
    ieee: IEEECoefficients
    mli: MLiResult | None
    models: tuple[MLiResult, ...] = ()
    gmwm: MLiResult | None = None
    verdict: Verdict | None = None


def analyze_channel(
    ch: Channel,
    *,
    pattern: str = "log",
    m: int = 1000,
    model: str = "wn+gm",
    compare: tuple[str, ...] = (),
    method: str = "mli",
) -> ChannelAnalysis:
    """Allan deviation, IEEE-952 coefficients and the ML_i and/or GMWM fit of one channel.

    ``compare``: further models fitted to the same integrated record (AIC/BIC).
    ``method``: ``"mli"``, ``"gmwm"`` or ``"both"`` (GMWM: :mod:`.gmwm`).
    """
    if method not in METHODS:
        raise InputError(f"method {method!r}: use one of {', '.join(METHODS)}")
    allan = oadev(ch.data, ch.fs_hz, scale=ch.scale, segments=ch.segments)
    ieee = ieee_coefficients(allan)
    mli, models, gmwm = None, (), None
    if method in ("mli", "both"):
        inc = integrate(ch.data, ch.fs_hz, m=m, pattern=pattern, scale=ch.scale, segments=ch.segments)
        mli = fit_integrated(inc, model)
        models = tuple(compare_models(inc, tuple(dict.fromkeys((model, *compare))))) if compare else ()
    if method in ("gmwm", "both"):
        gmwm = fit_gmwm(ch.data, ch.fs_hz, model, scale=ch.scale, segments=ch.segments)
    verdict = channel_verdict(ch, allan, mli if mli is not None else gmwm)
    return ChannelAnalysis(ch, allan, ieee, mli, models, gmwm, verdict)


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
    """The JSON document of design.md ("Analysis contract")."""
    return {"format": DOC_FORMAT, "version": DOC_VERSION, "channels": [channel_document(r) for r in results]}
