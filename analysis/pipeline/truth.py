"""Identified against simulated N, B, K, like for like (``demo --lab --profile datasheet``; issue 32).

The datasheet profile's truth is white noise through the device filter, a bias instability and a
rate random walk (drivers/sim/profiles.py), not the paper's Gauss-Markov model: the demo fits what
``analyze`` fits (the automatic model choice) and compares the ``ieee952`` block's N, B, K with the
simulator's (:func:`imustation.drivers.sim.simulated_nbk`: N the output samples' white-noise density,
the decimation's folding included; plus the counts' rounding, white noise of LSB^2/12 per sample).
Each row holds the truth inside its 90 % interval or says why not.
"""

from __future__ import annotations

import math

from imustation.analysis.pipeline.channel import ChannelAnalysis

#: (parameter, dimension for imustation.units.display_units)
NBK = (("N", "density"), ("B", "rate"), ("K", "drift"))


def rounding_density(scale: float, fs_hz: float) -> float:
    """White-noise density (unit/sqrt(Hz)) of rounding to ``scale`` units per count at ``fs_hz`` Hz."""
    return scale / math.sqrt(12.0 * fs_hz)


def nbk_rows(res: ChannelAnalysis, truth: tuple[float, float, float], drift_note: str = "") -> list[dict]:
    """One row per N, B, K: ``param``, ``simulated``, ``identified``, ``ci90_lo``, ``ci90_hi``,
    ``error_pct``, ``dimension`` and ``note`` (empty when the interval holds the truth; otherwise why
    not). ``truth`` (N, B, K) in SI without the rounding (added here when the channel stores counts);
    ``drift_note``: what the simulation adds beyond N, B, K (warm-up, temperature drift), said where B
    or K miss."""
    ch = res.channel
    fit = res.noise_model
    s = res.ieee952(fit)
    n_true, b_true, k_true = truth
    if ch.scale != 1.0:
        n_true = math.hypot(n_true, rounding_density(ch.scale, ch.fs_hz))
    fits = res.choice is None or res.choice.fits
    slow = "slow terms reach the fine scales" in fit.message
    rows = []
    for name, dim in NBK:
        sim = {"N": n_true, "B": b_true, "K": k_true}[name]
        value, ci = s.get(name), s.get(f"{name}_ci90")
        note = ""
        if name == "B" and s.get("B_detected") is False and s.get("B_upper90") is not None:
            value, ci = None, None  # the model's floor is no measurement of B: the upper bound is the statement
        if value is None:  # not detected: the upper bound is the statement
            lo, hi, value = 0.0, s.get(f"{name}_upper90") or math.nan, math.nan
            note = f"not detected: {name} < {hi:.3g} at 90 %"
        else:
            lo, hi = ci if ci else (math.nan, math.nan)
        held = lo <= sim <= hi if sim > 0 else True
        if not held:
            if not (math.isfinite(lo) and math.isfinite(hi)):
                why = "no interval: the record does not determine it"
            elif name == "N" and slow:
                why = "sigma_w rests on the slow terms' shape at the fine scales (docs/noise-model.md, Limit)"
            elif not fits:
                why = "no model of the family fits the Allan deviation; the interval is the chosen model's"
            elif name in ("B", "K") and drift_note:
                why = f"outside its 90 % interval; {drift_note}"
            else:
                why = "outside its 90 % interval (1 row in 10 is, by chance)"
            note = f"{note}; {why}" if note else why
        err = 100.0 * (value / sim - 1.0) if sim > 0 and math.isfinite(value) else math.nan
        rows.append(
            {
                "param": name,
                "simulated": sim,
                "identified": value,
                "ci90_lo": lo,
                "ci90_hi": hi,
                "error_pct": err,
                "dimension": dim,
                "note": note,
            }  # fmt: skip
        )
    return rows
