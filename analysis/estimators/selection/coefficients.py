"""IEEE-952 coefficients a fitted noise model implies: N, B, K (with 90 % intervals) and its
Gauss-Markov terms, the ``ieee952`` block of every model in the analysis JSON
(docs/analysis-json.md).

B is the model's bias-instability parameter when it has one, otherwise read from the model's
Allan-deviation floor (IEEE Std 952-1997 C.1: the floor of flicker rate noise is 0.664 B).
When the model choice found other models that fit nearly as well, B's interval is mixed with
theirs (:func:`~.model_choice.mixed_interval`).
"""

from __future__ import annotations

import math

import numpy as np

from imustation.analysis.estimators.engine.fitting import Z90, MLiResult
from imustation.analysis.estimators.engine.paramspec import ParamSpec
from imustation.analysis.estimators.models.sensor_terms import FLICKER_FLOOR
from imustation.analysis.estimators.selection.model_choice import flicker_cut, mixed_interval


def ieee952_summary(res: MLiResult, duration_s: float, close: tuple[MLiResult, ...] = ()) -> dict:
    """N, B, K (with 90 % intervals) and the Gauss-Markov terms a fitted model implies.

    ``N`` = sigma_w; ``K`` = sigma_k (``None`` without a rate random walk), its interval mixed
    with the ``close`` models' when one of them fits without a walk (:func:`carries_walk`): a
    flicker read as a walk (a KVH DSP-3000's 0.05 deg/h flicker gave K 64x the truth with an
    interval that excluded it) then gets an interval from 0 when the walk-free models carry 5 %
    of the BIC weight — K is not separable, its upper end is the statement; ``B``:
    the bias-instability parameter when the model has one (``B_from`` ``"fitted"``),
    otherwise the model's Allan-deviation minimum over ``1/fs .. duration_s/2``
    divided by 0.664 (``"model floor"``), its interval by the delta method from the
    fit's covariance (``cov_log``). ``close``: models that fit nearly as well (the
    choice's ``close``), whose B intervals the B interval is mixed with (:func:`mixed_interval`).
    ``K_from_tau_s``: where the walk takes over the model's Allan variance (:func:`walk_from`). Units:
    rad/s/sqrt(Hz), rad/s, rad/s^2/sqrt(Hz), s.
    """
    p, ci = res.params, res.ci90
    out: dict = {"N": res.sigma_w, "N_ci90": list(ci.get("sigma_w", (math.nan, math.nan)))}
    if "B" in p:
        out |= {"B": p["B"], "B_ci90": list(ci["B"]), "B_from": "fitted"}
    else:
        B, lo, hi = _floor_b(res, duration_s)
        out |= {"B": B, "B_ci90": [lo, hi], "B_from": "model floor"}
    if close:
        items = [(*out["B_ci90"], res.bic)] + [(*ieee952_summary(o, duration_s)["B_ci90"], o.bic) for o in close]
        lo, hi = mixed_interval(items)
        if math.isfinite(lo):
            out["B_ci90"] = [lo, hi]
    if "sigma_k" in p:
        out |= {"K": p["sigma_k"], "K_ci90": list(ci["sigma_k"])}
        without = tuple(o.bic for o in close if not carries_walk(o, duration_s))
        if without:
            walks = [(*res.ci90["sigma_k"], res.bic)] + [
                (*o.ci90["sigma_k"], o.bic) for o in close if "sigma_k" in o.params
            ]
            lo, hi = mixed_interval(walks, without)
            if math.isfinite(hi):
                out["K_ci90"] = [lo, hi]
        out["K_from_tau_s"] = walk_from(res, duration_s)
    else:
        out |= {"K": None, "K_ci90": None, "K_from_tau_s": None}
    gms = sorted(k for k in p if k.startswith("tau_b"))
    out["gauss_markov"] = [
        {
            "sigma_b": p["sigma_b" + k[5:]],
            "tau_b": p[k],
            "sigma_b_ci90": list(ci["sigma_b" + k[5:]]),
            "tau_b_ci90": list(ci[k]),
        }  # fmt: skip
        for k in gms
    ]
    return out


def walk_from(res: MLiResult, duration_s: float) -> float:
    """The cluster time (s) from which the model's rate random walk carries more Allan variance than its
    other terms together, over ``1/fs .. duration_s/2``; inf when it never does inside the record. A walk
    that shows only at the last octaves, where the Allan curve has a few degrees of freedom, is a marginal
    detection (:func:`~.allan_bounds.with_bounds`)."""
    tau = np.logspace(math.log10(1.0 / res.fs_hz), math.log10(max(duration_s / 2.0, 2.0 / res.fs_hz)), 200)
    walk = sum((t.avar(tau, res.fs_hz) for t in res.noise_model.terms if t.code == "rw"), np.zeros_like(tau))
    rest = res.noise_model.avar(tau, res.fs_hz) - walk
    above = np.flatnonzero(walk >= rest)
    return float(tau[above[0]]) if len(above) else math.inf


def carries_walk(res: MLiResult, duration_s: float) -> bool:
    """Whether ``res`` has a rate random walk, or a Gauss-Markov term that acts as one over the
    whole record (correlation time beyond half of ``duration_s``, s): a model without either fits
    the record with K = 0."""
    p = res.params
    return "sigma_k" in p or any(k.startswith("tau_b") and p[k] > duration_s / 2.0 for k in p)


def _floor_b(res: MLiResult, duration_s: float) -> tuple[float, float, float]:
    """Model Allan-deviation minimum / 0.664 and its delta-method 90 % interval."""
    tau = np.logspace(math.log10(1.0 / res.fs_hz), math.log10(max(duration_s / 2.0, 2.0 / res.fs_hz)), 200)

    def floor(model) -> float:
        return float(np.sqrt(np.min(model.avar(tau, res.fs_hz)))) / FLICKER_FLOOR

    B = floor(res.noise_model)
    if res.phi is None or res.cov_log is None or not np.all(np.isfinite(res.cov_log)):
        return B, math.nan, math.nan
    times = next((t.times for t in res.noise_model.terms if t.code == "fl"), ())
    spec = ParamSpec(ParamSpec.for_record(res.model, res.fs_hz, duration_s).codes, times, flicker_cut(res))
    h = 1e-3
    g = np.empty(len(res.phi))
    for j in range(len(res.phi)):
        d = np.zeros(len(res.phi))
        d[j] = h
        up = floor(spec.model(res.phi + d, res.b_on, res.memory_s))
        dn = floor(spec.model(res.phi - d, res.b_on, res.memory_s))
        g[j] = (math.log(up) - math.log(dn)) / (2 * h)
    se = math.sqrt(max(float(g @ res.cov_log @ g), 0.0))
    return B, B * math.exp(-Z90 * se), B * math.exp(Z90 * se)
