"""The "enough data?" verdict of one channel, with its reasons.

The question is whether the record pins down the noise parameters the user
needs (``need``). By default, with the automatic model choice, those are the IEEE-952
quantities of :data:`IEEE_NEED` -- ``N``, ``B``, ``K`` with the intervals of the ``ieee952``
block (mixed over the models that fit nearly as well; K not detected, or seen only at the record's
last clusters so that its interval is the Allan curve's wide reading: its upper bound) --
which do not depend on which of two indistinguishable structures (Gauss-Markov or flicker
plus random walk) a repeat happens to choose (issue 32: six repeats of one ADIS16405 got
enough, marginal and not enough from tau_b of whichever model each chose); the record length
against tau_b is then reported, not judged. With a model given (``--model wn+gm``), those of
:data:`DEFAULT_NEED` -- ``sigma_w``, ``sigma_b``, ``tau_b`` -- that the fitted model has.
:func:`data_verdict` applies these rules, each giving *enough*, *marginal* or *not enough*;
the verdict is the worst:

* every needed parameter has a 90 % interval (the fit's ``ci90``, profile
  likelihood for ML_i-F) whose spread ``hi / lo`` is at most
  :data:`ENOUGH_SPREAD` (3: known within about a factor 1.7 either way);
  up to :data:`MARGINAL_SPREAD` (25: a factor 5 either way) *marginal*; wider,
  missing, or a parameter at its search bound -> *not enough*;
* a record shorter than :data:`MIN_RECORD_S` (60 s) -> *not enough*;
* the record spans at least :data:`MIN_TAU_B_MULTIPLE` (10) times the longest
  fitted correlation time, else *marginal*; below :data:`MARGINAL_TAU_B_MULTIPLE`
  (3) *not enough*: the slowest process is barely observed;
* a detected warm-up (``warmup_s > 0``: the smooth temperature fit of
  :func:`.temperature.fit_warmup`, a real temperature change of many reading steps) that the
  analysis did not cut (``warmup_cut_s``, :mod:`.warmup`: ``--warmup auto`` cuts it) ->
  *marginal*, discard it; a cut warm-up is a reason, not a fault; a record still warming up at its end ->
  *marginal*; a record too short to tell says so;
* a temperature span above :data:`MAX_TEMP_SPAN_C` (2 K) after the warm-up ->
  *marginal*: temperature drift may dominate the bias.

The Allan minimum is reported, not judged, unless the IEEE-952 bias instability
``B`` is needed (then its tau must leave 10 clusters in the record): a
Gauss-Markov bias has no Allan minimum, its deviation keeps falling beyond
``tau_b`` (issue 22: a record of 60 tau_b was called "not enough" for that).
Interval spreads come from a fit of one record and vary between repeats (a
weakly seen bias: tau_b's spread 3.5-19 over eight repeats); the bands are
wide so that repeats of one device fall in one of them (docs/import.md).
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

#: a record shorter than this (s) is *not enough* whatever its intervals say: the bias terms need
#: Allan clusters of tens of seconds, ten times over (a 12 s record was 'marginal')
MIN_RECORD_S = 60.0
MIN_TAU_B_MULTIPLE = 10.0
MARGINAL_TAU_B_MULTIPLE = 3.0
MIN_ALLAN_CLUSTERS = 10.0
MAX_TEMP_SPAN_C = 2.0
#: 90 % interval spread hi/lo of a needed parameter: up to this enough, up to MARGINAL_SPREAD marginal
ENOUGH_SPREAD = 3.0
MARGINAL_SPREAD = 25.0
#: parameters the verdict judges unless told otherwise (``analyze --need``) for a given model
DEFAULT_NEED = ("sigma_w", "sigma_b", "tau_b")
#: ... and with the automatic model choice: the model-independent IEEE-952 quantities
IEEE_NEED = ("N", "B", "K")
#: the IEEE-952 bias instability: judged by the Allan minimum, not by an interval
ALLAN_B = "B"

LEVELS = ("enough", "marginal", "not enough")


@dataclass(frozen=True)
class Verdict:
    """``verdict`` one of :data:`LEVELS`; ``reasons`` one sentence each; ``need`` the judged
    parameters and ``spread`` their 90 % interval spreads hi/lo (NaN when unknown); ``warmup_s``
    the warm-up ``--warmup auto`` cuts (s), ``warmup_cut_s`` what this analysis cut (s)."""

    verdict: str
    duration_s: float
    tau_b_s: float
    allan_min_tau_s: float
    warmup_s: float
    temp_span_c: float
    reasons: tuple[str, ...] = field(default_factory=tuple)
    need: tuple[str, ...] = ()
    spread: dict[str, float] = field(default_factory=dict)
    #: the warm-up fit's state (:data:`.temperature.WARMUP_STATES`); "" without a temperature channel
    warmup_state: str = ""
    warmup_cut_s: float = 0.0
    #: the reasons that made the verdict worse than "enough" (a subset of ``reasons``), for a short list
    problems: tuple[str, ...] = ()

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
            "warmup_state": self.warmup_state or None,
            "warmup_cut_s": num(self.warmup_cut_s),
            "temp_span_c": num(self.temp_span_c),
            "reasons": list(self.reasons),
            "problems": list(self.problems),
            "need": list(self.need),
            "spread": {k: num(v) for k, v in self.spread.items()},
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


@dataclass(frozen=True)
class Interval:
    """A needed parameter's estimate and 90 % interval (its unit); ``why`` says why it is missing."""

    value: float
    lo: float
    hi: float
    why: str = ""
    #: a term not detected: the upper bound (90 %) the record sets instead of an interval
    upper: float = math.nan
    #: the name the reasons print ("" : the needed name); a random walk's sigma_k stands for sigma_b
    label: str = ""
    #: the SI unit the reasons print after the value ("" : none known)
    unit: str = ""
    #: why a term judged by its bound is not a measurement ("" : "not detected")
    note: str = ""

    def show(self, x: float) -> str:
        """``x`` as the reasons print it: three digits and the SI unit (the table is in display units)."""
        return f"{x:.3g} {self.unit}" if self.unit else f"{x:.3g}"

    @property
    def spread(self) -> float:
        ok = all(math.isfinite(v) for v in (self.lo, self.hi)) and self.lo > 0 and self.hi >= self.lo
        return self.hi / self.lo if ok else math.nan


def fit_intervals(fit, need: Sequence[str]) -> dict[str, Interval]:
    """The intervals of the needed parameters of an :class:`~.fitting.MLiResult` (``ALLAN_B`` skipped).

    ``sigma_b`` of a random-walk model is its ``sigma_k``; a parameter the model does not
    have, or one at its search bound, comes with ``why``.
    """
    out: dict[str, Interval] = {}
    for name in need:
        if name == ALLAN_B:
            continue
        key = name
        if name == "sigma_b" and "sigma_b" not in fit.ci90 and "sigma_k" in fit.ci90:
            key = "sigma_k"
        if key not in fit.ci90:
            out[name] = Interval(math.nan, math.nan, math.nan, f"{name} is not a parameter of the {fit.model} model")
            continue
        lo, hi = fit.ci90[key]
        value = float(fit.params.get(key, getattr(fit, name, math.nan)))
        bound = [b for b in fit.at_bound if b == key or b.rstrip("0123456789") == key]
        label = "sigma_k (the rate random walk, for sigma_b)" if key != name else ""
        why = f"{label or name} at its search bound: not identified" if bound else ""
        out[name] = Interval(value, float(lo), float(hi), why, label=label)
    return out


def ieee_intervals(summary: Mapping, need: Sequence[str]) -> dict[str, Interval]:
    """The intervals of ``N``, ``B``, ``K`` in ``need`` from an ``ieee952`` summary
    (:func:`~.coefficients.ieee952_summary` with :func:`~.allan_bounds.with_bounds`); K without a
    random walk or not detected (``K_detected`` false), B without a bias term (``B_detected`` false): the
    upper bound."""
    out: dict[str, Interval] = {}
    for name in need:
        value, ci = summary.get(name), summary.get(f"{name}_ci90")
        if name == "B" and summary.get("B_detected") is False:
            value = None  # the model's floor is an upper bound on B, not a measurement of it
        if name == "K" and summary.get("K_detected") is False:
            value = None  # an interval from 0: the walk is not separable from the other terms, its bound judges
        if name == "K" and value is not None and summary.get("K_widened") and ci and ci[1] is not None:
            # a walk seen only at the record's last clusters (or by a model that does not fit): its interval is
            # the Allan curve's reading and spans a large factor; a repeat of the same device that does not
            # choose the walk states the bound, so this one is judged by its upper end too (one verdict)
            out[name] = Interval(math.nan, math.nan, math.nan, upper=float(ci[1]), note="barely detected")
            continue
        if value is not None and ci and all(v is not None for v in ci):
            out[name] = Interval(float(value), float(ci[0]), float(ci[1]))
        elif summary.get(f"{name}_upper90") is not None:
            out[name] = Interval(math.nan, math.nan, math.nan, upper=float(summary[f"{name}_upper90"]))
        else:
            out[name] = Interval(math.nan, math.nan, math.nan, f"{name}: neither an interval nor a bound")
    return out


def data_verdict(
    duration_s: float,
    tau_b_s: float,
    allan_min_tau_s: float,
    *,
    allan_min_at_end: bool = False,
    warmup_s: float = math.nan,
    warmup_state: str = "",
    warmup_cut_s: float = 0.0,
    temp_span_c: float = math.nan,
    intervals: Mapping[str, Interval] | None = None,
    need: Sequence[str] = (),
    judge_tau_b: bool = True,
) -> Verdict:
    """Verdict of a record of ``duration_s`` seconds (see the module doc for the rules).

    ``tau_b_s``: the longest fitted correlation time (s; NaN when the fit did not converge,
    inf for a random walk); ``intervals``: the needed parameters' intervals
    (:func:`fit_intervals`); ``need`` the names asked for (``"B"`` judges the Allan minimum);
    ``judge_tau_b`` False: the record length against tau_b is reported, not judged (the IEEE-952
    quantities are judged by their intervals).
    ``warmup_s`` the warm-up's end ``--warmup auto`` cuts at (s) and ``warmup_state`` the warm-up
    fit's state (:data:`.temperature.WARMUP_STATES`; ``""``: a ``warmup_s`` > 0 is a transient);
    ``warmup_cut_s`` what the analysis cut (s).
    """
    level = 0
    reasons: list[str] = []
    problems: list[str] = []

    def worse(lv: int, why: str) -> None:
        nonlocal level
        level = max(level, lv)
        reasons.append(why)
        problems.append(why)

    if not duration_s >= MIN_RECORD_S:
        worse(2, f"record of {duration_s:.3g} s is shorter than {MIN_RECORD_S:g} s: too short for any bias term")
    spread: dict[str, float] = {}
    for key, iv in (intervals or {}).items():
        sp = spread[key] = iv.spread
        name = iv.label or key
        if not iv.why and not math.isfinite(sp) and math.isfinite(iv.upper):
            reasons.append(f"{name} {iv.note or 'not detected'}: {name} < {iv.show(iv.upper)} (90 %)")
            continue
        if iv.why:
            worse(2, iv.why)
        elif not math.isfinite(sp):
            worse(2, f"{name}: no interval")
        elif sp > MARGINAL_SPREAD:
            # the factor itself can be 1e63 (an interval reaching its search range): not worth printing
            worse(2, f"{name} = {iv.show(iv.value)}: its 90 % interval spans more than a factor {MARGINAL_SPREAD:g}")
        elif sp > ENOUGH_SPREAD:
            worse(1, f"{name} = {iv.show(iv.value)}: its 90 % interval spans a factor {sp:.1f} (> {ENOUGH_SPREAD:g})")
        else:
            reasons.append(f"{name} = {iv.show(iv.value)} within a factor {sp:.2f} (90 %)")
    if not judge_tau_b:
        if math.isfinite(tau_b_s) and tau_b_s > 0:
            reasons.append(f"record is {duration_s / tau_b_s:.1f} x tau_b ({tau_b_s:.3g} s) of the chosen model")
    elif math.isinf(tau_b_s):
        reasons.append("random-walk or bias-instability bias: no correlation time to compare the record with")
    elif math.isfinite(tau_b_s) and tau_b_s > 0:
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
        judged = ALLAN_B in need and judge_tau_b
        if allan_min_at_end:
            why = f"Allan deviation still falls at the longest tau ({allan_min_tau_s:.3g} s): no minimum reached"
            if judged:
                worse(2, why + ": no bias instability B")
            else:
                reasons.append(why + " (as a Gauss-Markov bias's does beyond tau_b)")
        elif clusters < MIN_ALLAN_CLUSTERS and judged:
            worse(1, f"Allan minimum at {allan_min_tau_s:.3g} s is only {clusters:.1f} clusters of the record")
        else:
            reasons.append(f"Allan minimum at {allan_min_tau_s:.3g} s ({clusters:.0f} clusters)")
    if warmup_state == "unsettled":
        worse(1, "still warming up at the end of the record: no settled data")
    elif warmup_state == "unknown":
        reasons.append("record too short to tell a warm-up")
    elif math.isfinite(warmup_s):
        if warmup_s > 0 and warmup_cut_s >= warmup_s:
            reasons.append(f"warm-up until {warmup_s:.0f} s cut ({warmup_cut_s:.0f} s left out)")
        elif warmup_s > 0:
            cut = f"only {warmup_cut_s:.0f} s" if warmup_cut_s > 0 else "nothing"
            worse(1, f"warm-up transient until {warmup_s:.0f} s, {cut} cut: discard it (--warmup auto)")
        else:
            reasons.append("no warm-up transient" + (f" ({warmup_cut_s:.0f} s cut)" if warmup_cut_s > 0 else ""))
    else:
        reasons.append("no temperature: warm-up and drift not checked")
    if math.isfinite(temp_span_c):
        if temp_span_c > MAX_TEMP_SPAN_C:
            worse(1, f"temperature spans {temp_span_c:.2g} K after warm-up: drift may dominate the bias")
        elif math.isfinite(warmup_s):
            reasons.append(f"temperature spans {temp_span_c:.2g} K")
    return Verdict(LEVELS[level], duration_s, tau_b_s, allan_min_tau_s, warmup_s, temp_span_c, tuple(reasons),
                   tuple(need), spread, warmup_state, warmup_cut_s, tuple(problems))  # fmt: skip


def longest_correlation_time(fit) -> float:
    """The slowest fitted correlation time (s): inf for a random walk or a bias instability without a
    Gauss-Markov term (neither has one: a wn+fl model was 'no converged finite tau_b', marginal),
    NaN when the fit did not converge."""
    if fit is None or not fit.converged:
        return math.nan
    if "sigma_k" in fit.params:
        return math.inf
    taus = [v for k, v in fit.params.items() if k.startswith("tau_b") and math.isfinite(v)]
    if not taus and "B" in fit.params:
        return math.inf
    return max(taus) if taus else math.nan


def channel_verdict(ch, allan, fit, need: Sequence[str] | None = None, summary: Mapping | None = None) -> Verdict:
    """Verdict of an analysed channel: ``allan`` its AllanResult, ``fit`` its MLiResult (or None),
    ``need`` the parameters judged (``"B"``: the IEEE-952 bias instability); None: with ``summary``
    (the fit's ``ieee952`` block, given for the automatic model choice) :data:`IEEE_NEED` judged by
    its intervals, without it those of :data:`DEFAULT_NEED` the fitted model has. ``N`` and ``K`` in
    ``need`` are read from ``summary``.

    Warm-up and temperature span come from the device's temperature channel
    when ``ch`` is a run-file channel that has one (:func:`.loaders.device_temperature`).
    """
    duration = ch.n / ch.fs_hz
    tau_min, at_end = allan_minimum_tau(allan.tau, allan.adev)
    warmup, span, state = math.nan, math.nan, ""
    applied = ch.meta.get("warmup")  # the cut the analysis made (.warmup.apply_warmup)
    cut_s = float(applied.cut_s) if applied is not None else 0.0
    duration -= min(cut_s, duration)
    device = ch.meta.get("device") if ch.ref is not None else None
    if device:
        try:
            mtime = os.stat(ch.source).st_mtime_ns
        except OSError:
            mtime = 0
        warmup, span, state = _warmup_and_span(ch.source, device, mtime, cut_s)
    ieee_mode = summary is not None and fit is not None and need is None
    if ieee_mode:
        need = IEEE_NEED
    if need is None and fit is None:
        need = DEFAULT_NEED
    elif need is None:
        have = set(fit.ci90) | ({"sigma_b"} if "sigma_k" in fit.ci90 else set())
        need = tuple(n for n in DEFAULT_NEED if n in have)
    if fit is None:
        intervals = {n: Interval(math.nan, math.nan, math.nan, "no model fit") for n in need if n != ALLAN_B}
    elif ieee_mode:
        intervals = ieee_intervals(summary, need)
    else:
        intervals = fit_intervals(fit, [n for n in need if not (summary is not None and n in ("N", "K"))])
        if summary is not None:
            intervals |= ieee_intervals(summary, [n for n in need if n in ("N", "K")])
    intervals = {k: replace(iv, unit=_si_unit(ch, k)) for k, iv in intervals.items()}
    return data_verdict(
        duration,
        longest_correlation_time(fit),
        tau_min,
        allan_min_at_end=at_end,
        warmup_s=warmup,
        warmup_state=state,
        warmup_cut_s=cut_s,
        temp_span_c=span,
        intervals=intervals,
        need=tuple(need),
        judge_tau_b=not ieee_mode,
    )


#: the dimension of each judged quantity (imustation.units.DIMENSIONS)
_DIMENSION = {"N": "density", "sigma_w": "density", "B": "rate", "K": "drift", "sigma_b": "drift", "tau_b": "time"}


def _si_unit(ch, name: str) -> str:
    """The SI unit of quantity ``name`` on channel ``ch`` ("" when its kind or dimension is not known)."""
    from imustation.units import display_units, sensor_kind

    dim = _DIMENSION.get(name)
    if dim is None:
        return ""
    try:
        return display_units(sensor_kind(ch.units, ch.id), dim)[0]
    except ValueError:
        return ""


@functools.lru_cache(maxsize=16)
def _warmup_and_span(path: str, device: str, mtime_ns: int, cut_s: float) -> tuple[float, float, str]:
    """(end of the warm-up ``--warmup auto`` cuts s, temperature span K after it and after ``cut_s``,
    warm-up state) of a device (:func:`.warmup.auto_warmup`); NaN and ``""`` without a temperature channel."""
    from imustation.analysis.pipeline.loaders import device_temperature_record
    from imustation.analysis.pipeline.warmup import auto_warmup
    from imustation.errors import InputError

    state, _, end = auto_warmup(path, device, mtime_ns)
    if not state:
        return math.nan, math.nan, ""
    try:
        rec = device_temperature_record(path, device)
    except InputError:
        return math.nan, math.nan, ""
    warmup = end if state == "transient" else 0.0
    after = rec.temp_c[rec.t_s >= max(warmup, cut_s)]
    return warmup, float(after.max() - after.min()) if len(after) else math.nan, state
