"""The "enough data?" verdict of one channel, with its reasons.

A record identifies the bias process only if it is long compared with the
process: the fitted Gauss-Markov correlation time ``tau_b`` and the averaging
time of the Allan minimum (where bias instability takes over from white
noise). A warm-up transient at the start and a temperature drift over the
record bias both. :func:`data_verdict` applies these rules:

* ``duration >= MIN_TAU_B_MULTIPLE * tau_b`` (10): otherwise the bias process is
  barely seen (``tau_b`` poorly identified) -> *not enough*; between 3x and 10x *marginal*;
* the Allan minimum must lie at ``tau <= duration / MIN_ALLAN_CLUSTERS`` (10
  clusters at least): otherwise its level is not resolved -> *marginal*; a
  minimum at the longest tau computed means the curve has not turned -> *not enough*;
* a detected warm-up (``warmup_s > 0``, :func:`.temperature.detect_warmup`)
  -> *marginal*, discard it (``report --warmup``);
* a temperature span above ``MAX_TEMP_SPAN_C`` (2 K) after the warm-up ->
  *marginal*: temperature drift may dominate the bias.

Missing inputs (no fit, no temperature) are stated and do not count against
the record, except a missing or unconverged ``tau_b`` fit (-> *marginal*).
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, field

import numpy as np

MIN_TAU_B_MULTIPLE = 10.0
MARGINAL_TAU_B_MULTIPLE = 3.0
MIN_ALLAN_CLUSTERS = 10.0
MAX_TEMP_SPAN_C = 2.0

LEVELS = ("enough", "marginal", "not enough")


@dataclass(frozen=True)
class Verdict:
    """``verdict`` one of :data:`LEVELS`; ``reasons`` one sentence each."""

    verdict: str
    duration_s: float
    tau_b_s: float
    allan_min_tau_s: float
    warmup_s: float
    temp_span_c: float
    reasons: tuple[str, ...] = field(default_factory=tuple)

    @property
    def enough(self) -> bool:
        return self.verdict == "enough"

    def as_dict(self) -> dict:
        def num(x: float) -> float | None:
            return float(x) if x is not None and math.isfinite(x) else None

        return {
            "verdict": self.verdict,
            "duration_s": num(self.duration_s),
            "tau_b_s": num(self.tau_b_s),
            "allan_min_tau_s": num(self.allan_min_tau_s),
            "warmup_s": num(self.warmup_s),
            "temp_span_c": num(self.temp_span_c),
            "reasons": list(self.reasons),
        }


def allan_minimum_tau(tau: np.ndarray, adev: np.ndarray) -> tuple[float, bool]:
    """Tau of the Allan-deviation minimum and whether it is the last tau computed (not turned yet)."""
    adev = np.asarray(adev, dtype=float)
    ok = np.isfinite(adev)
    if not ok.any():
        return math.nan, False
    idx = np.nonzero(ok)[0]
    k = idx[int(np.argmin(adev[ok]))]
    return float(tau[k]), bool(k == idx[-1])


def data_verdict(
    duration_s: float,
    tau_b_s: float,
    allan_min_tau_s: float,
    *,
    allan_min_at_end: bool = False,
    warmup_s: float = math.nan,
    temp_span_c: float = math.nan,
) -> Verdict:
    """Verdict of a record of ``duration_s`` seconds (see the module doc for the rules)."""
    level = 0
    reasons: list[str] = []

    def worse(lv: int, why: str) -> None:
        nonlocal level
        level = max(level, lv)
        reasons.append(why)

    if math.isfinite(tau_b_s) and tau_b_s > 0:
        ratio = duration_s / tau_b_s
        if ratio < MARGINAL_TAU_B_MULTIPLE:
            worse(2, f"record is {ratio:.1f} x tau_b ({tau_b_s:.3g} s): the bias process is barely observed")
        elif ratio < MIN_TAU_B_MULTIPLE:
            worse(1, f"record is {ratio:.1f} x tau_b ({tau_b_s:.3g} s), below {MIN_TAU_B_MULTIPLE:g} x")
        else:
            reasons.append(f"record is {ratio:.0f} x tau_b ({tau_b_s:.3g} s)")
    else:
        worse(1, "no converged finite tau_b: the bias process is not identified by the fit")
    if math.isfinite(allan_min_tau_s):
        clusters = duration_s / allan_min_tau_s
        if allan_min_at_end:
            worse(2, f"Allan deviation still falls at the longest tau ({allan_min_tau_s:.3g} s): no minimum reached")
        elif clusters < MIN_ALLAN_CLUSTERS:
            worse(1, f"Allan minimum at {allan_min_tau_s:.3g} s is only {clusters:.1f} clusters of the record")
        else:
            reasons.append(f"Allan minimum at {allan_min_tau_s:.3g} s ({clusters:.0f} clusters)")
    if math.isfinite(warmup_s):
        if warmup_s > 0:
            worse(1, f"warm-up transient until {warmup_s:.0f} s: discard it")
        else:
            reasons.append("no warm-up transient")
    else:
        reasons.append("no temperature: warm-up and drift not checked")
    if math.isfinite(temp_span_c):
        if temp_span_c > MAX_TEMP_SPAN_C:
            worse(1, f"temperature spans {temp_span_c:.2g} K after warm-up: drift may dominate the bias")
        elif math.isfinite(warmup_s):
            reasons.append(f"temperature spans {temp_span_c:.2g} K")
    return Verdict(LEVELS[level], duration_s, tau_b_s, allan_min_tau_s, warmup_s, temp_span_c, tuple(reasons))


def channel_verdict(ch, allan, fit) -> Verdict:
    """Verdict of an analysed channel: ``allan`` its AllanResult, ``fit`` its MLiResult (or None).

    Warm-up and temperature span come from the device's temperature channel
    when ``ch`` is a run-file channel that has one (:func:`.temperature.device_temperature`).
    """
    duration = ch.n / ch.fs_hz
    tau_min, at_end = allan_minimum_tau(allan.tau, allan.adev)
    warmup, span = math.nan, math.nan
    device = ch.meta.get("device") if ch.ref is not None else None
    if device:
        try:
            mtime = os.stat(ch.source).st_mtime_ns
        except OSError:
            mtime = 0
        warmup, span = _warmup_and_span(ch.source, device, mtime)
    tau_b = fit.tau_b if fit is not None and fit.converged else math.nan
    return data_verdict(duration, tau_b, tau_min, allan_min_at_end=at_end, warmup_s=warmup, temp_span_c=span)


@functools.lru_cache(maxsize=16)
def _warmup_and_span(path: str, device: str, mtime_ns: int) -> tuple[float, float]:
    """(end of warm-up s, temperature span after it K) of a device; NaN without a temperature channel."""
    from imustation.analysis.reports.temperature import detect_warmup, device_temperature
    from imustation.errors import InputError

    try:
        t_s, temp_c = device_temperature(path, device)
    except InputError:
        return math.nan, math.nan
    if len(t_s) < 3:
        return math.nan, math.nan
    warmup = detect_warmup(t_s, temp_c)
    after = temp_c[t_s >= warmup]
    return warmup, float(after.max() - after.min()) if len(after) else math.nan
