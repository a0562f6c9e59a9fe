"""What the record cannot see: upper bounds on K and B from the measured Allan deviation, and the
checks that keep the classic IEEE-952 block from printing an impossible number.

**Upper bounds.** The Allan variance of a sum of independent noise terms is the sum of their Allan
variances, each non-negative, so at every cluster time ``tau`` a rate random walk ``K`` obeys
``K^2 tau / 3 <= AVAR(tau)`` and a bias instability ``B`` obeys ``(2 ln 2 / pi) B^2 <= AVAR(tau)``
(IEEE Std 952-1997 C.1; within the flicker band, which spans the record) whatever the other terms
are. With the measured overlapping AVAR a scaled chi-square of ``edf`` degrees of freedom, its
true value is below ``avar edf / chi2_q(edf)`` at confidence ``1 - q``; taking the tightest of
``k`` taus (one per octave) with ``q = alpha / k`` (Bonferroni: conservative for the correlated
points) gives a bound at confidence at least ``1 - alpha``. It is what an engineer needs for a
filter's process noise when the term is too weak to show ("K < x at 90 %"): never a bare null.
B's bound reads cluster times from :data:`FLOOR_FROM_S` on only: a real 1/f band has a
high-frequency corner, below which the flicker's Allan variance falls under its floor (the project's
simulators' starts at 0.25 s and is flat from 1 s: on the 1 h MPU-9150 datasheet gyro x the bound
read at 0.13 s was 0.93 B, below the truth).

**B's structure band** (:func:`b_band`): the same curve read as a flicker floor, a 90 % interval of
B that does not rest on the fitted model's bias structure. Upper end: the bound above (at 95 %);
lower end: at every tau the lower 95 % limit of the measured AVAR less what the white noise and the
walk can take (their upper ends), over ``0.441``, the largest over the taus (Bonferroni) — a
statement that holds when the slow part is a flicker floor, as B's definition assumes.
:func:`with_bounds` widens B's interval to take it in where the model's own B is a reading of one
structure among several: the chosen model does not fit the Allan deviation (the 1 h MPU-9150
datasheet gyro x: ``wn+2gm+rw``, B −26 % with [−31, −21] %, while the measured curve lies within
4 % of the truth's floor from 1 s to 140 s). Not where a fitting Gauss-Markov model's floor gives B:
the curve of a Gauss-Markov bias has a maximum, not a floor, and the band would read its hump
(repeats of one such device would then get a B interval 3x wider on some runs only); the models
within the evidence threshold already mix B's interval (:func:`~.model_choice.mixed_interval`).
The same for a walk (:func:`k_band`), where the model does not fit or its walk leads only at the last
octaves (:data:`WALK_MIN_EDF`).

**Classic IEEE-952 checks** (:func:`ieee_usability`): every term adds Allan variance, so the white
noise ``N`` of the subset fit can be neither 0 (the Allan deviation falls as ``tau^-1/2`` somewhere
from the filter's memory on on any sensor) nor above the measured deviation at 1 s by more than the two
estimates' sampling errors allow (:data:`N_FLAG_CONFIDENCE`); and ``B`` is not 0 where the curve has a
minimum inside the record. A coefficient
that breaks one of these, or that disagrees with the noise model's own 90 % interval of the same
quantity, is marked unusable with the reason instead of being printed as a measurement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2, norm

from imustation.analysis.estimators.classical.allan import AllanResult
from imustation.analysis.estimators.classical.ieee import B_FACTOR, IEEECoefficients

#: confidence of the stated upper bounds
BOUND_CONFIDENCE = 0.90
#: points of the Allan curve used for a bound: at least this many degrees of freedom (fewer: the
#: chi-square's lower quantiles collapse and the bound says nothing)
MIN_EDF = 1.0
#: B is read from the Allan curve from this cluster time on, s: below it a bias instability's 1/f band may
#: have its corner (the model choice tries flicker cut-offs up to 1 s, ``model_choice.FLICKER_CUT_MAX_S``)
FLOOR_FROM_S = 1.0


@dataclass(frozen=True)
class UpperBound:
    """``value`` (unit of the coefficient) exceeds the true coefficient with ``confidence``; ``tau_s``
    the cluster time (s) that gives it."""

    value: float
    tau_s: float
    confidence: float = BOUND_CONFIDENCE


def _octave_points(allan: AllanResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The curve's taus with usable EDF, thinned to one per octave (s, (unit)^2, EDF)."""
    tau, avar, edf = allan.tau, allan.adev**2, allan.edf
    ok = np.isfinite(avar) & (avar > 0) & np.isfinite(edf) & (edf >= MIN_EDF)
    tau, avar, edf = tau[ok], avar[ok], edf[ok]
    if len(tau) == 0:
        return tau, avar, edf
    keep = [0]
    for i in range(1, len(tau)):
        if tau[i] >= 2.0 * tau[keep[-1]] * (1.0 - 1e-9):
            keep.append(i)
    return tau[keep], avar[keep], edf[keep]


def _upper_avar(avar: np.ndarray, edf: np.ndarray, q: float) -> np.ndarray:
    """Upper ``1 - q`` confidence limits of the true AVAR behind measured ``avar`` with ``edf``."""
    return avar * edf / chi2.ppf(q, edf)


def k_upper(allan: AllanResult, alpha: float = 1.0 - BOUND_CONFIDENCE) -> UpperBound | None:
    """Upper bound (unit/s/sqrt(Hz)) on a rate random walk from the Allan curve (module docstring)."""
    tau, avar, edf = _octave_points(allan)
    if len(tau) == 0:
        return None
    k2 = 3.0 * _upper_avar(avar, edf, alpha / len(tau)) / tau
    i = int(np.argmin(k2))
    return UpperBound(float(math.sqrt(k2[i])), float(tau[i]), 1.0 - alpha)


def _floor_points(allan: AllanResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The octave points (:func:`_octave_points`) from :data:`FLOOR_FROM_S` on; all of them when the record
    holds none there."""
    tau, avar, edf = _octave_points(allan)
    keep = tau >= FLOOR_FROM_S
    return (tau[keep], avar[keep], edf[keep]) if keep.any() else (tau, avar, edf)


def b_upper(allan: AllanResult, alpha: float = 1.0 - BOUND_CONFIDENCE) -> UpperBound | None:
    """Upper bound (unit) on a bias instability (flicker floor) from the Allan curve (module docstring)."""
    tau, avar, edf = _floor_points(allan)
    if len(tau) == 0:
        return None
    b2 = _upper_avar(avar, edf, alpha / len(tau)) / B_FACTOR**2
    i = int(np.argmin(b2))
    return UpperBound(float(math.sqrt(b2[i])), float(tau[i]), 1.0 - alpha)


def b_band(allan: AllanResult, n_hi: float, k_hi: float, alpha: float = 1.0 - BOUND_CONFIDENCE) -> tuple[float, float]:
    """90 % interval (unit) of B read from the measured Allan curve as a flicker floor (module docstring).

    ``n_hi``: the white noise's upper end (unit/sqrt(Hz)), ``k_hi``: the walk's (unit/s/sqrt(Hz); a
    model-free bound where the model has none); each side at ``alpha / 2`` Bonferroni over one tau per
    octave from :data:`FLOOR_FROM_S`. ``(nan, nan)`` without usable points; the lower end is 0 where
    the white noise and the walk may take the whole curve."""
    tau, avar, edf = _floor_points(allan)
    if len(tau) == 0:
        return (math.nan, math.nan)
    q = 0.5 * alpha / len(tau)
    hi = float(np.sqrt(np.min(_upper_avar(avar, edf, q)))) / B_FACTOR
    low_avar = avar * edf / chi2.ppf(1.0 - q, edf)
    n_hi, k_hi = np.float64(n_hi), np.float64(k_hi)
    with np.errstate(over="ignore", invalid="ignore"):  # an end of 1e200 squares to inf: nothing is left
        rest = low_avar - n_hi**2 / tau - k_hi**2 * tau / 3.0
    lo = float(np.sqrt(max(float(np.nanmax(rest, initial=-np.inf)), 0.0))) / B_FACTOR
    return (min(lo, hi), max(lo, hi))


def k_band(allan: AllanResult, n_hi: float, b_hi: float, alpha: float = 1.0 - BOUND_CONFIDENCE) -> tuple[float, float]:
    """90 % interval (unit/s/sqrt(Hz)) of a rate random walk read from the measured Allan curve (module
    docstring): the upper end as :func:`k_upper` (at 95 %); the lower end the largest over the taus of what
    is left of the lower 95 % limit of the measured AVAR once white noise ``n_hi`` (unit/sqrt(Hz)) and a
    flicker floor ``b_hi`` (unit) are taken out, read as ``K^2 tau / 3``. ``(nan, nan)`` without points."""
    tau, avar, edf = _octave_points(allan)
    if len(tau) == 0:
        return (math.nan, math.nan)
    q = 0.5 * alpha / len(tau)
    hi = float(np.sqrt(np.min(3.0 * _upper_avar(avar, edf, q) / tau)))
    n_hi, b_hi = np.float64(n_hi), np.float64(b_hi)
    with np.errstate(over="ignore", invalid="ignore"):  # an end of 1e200 squares to inf: nothing is left
        rest = avar * edf / chi2.ppf(1.0 - q, edf) - n_hi**2 / tau - (B_FACTOR * b_hi) ** 2
    lo = float(np.sqrt(max(float(np.nanmax(3.0 * rest / tau, initial=-np.inf)), 0.0)))
    return (min(lo, hi), max(lo, hi))


#: a walk whose share of the model's Allan variance leads only where the measured curve has fewer degrees of
#: freedom than this is a marginal detection: its likelihood interval rests on a handful of the record's
#: longest clusters (the 2 h BMX055 datasheet gyro y: K +77 % with [+11, +180] %, the walk leading from 343 s on)
WALK_MIN_EDF = 20.0


#: an interval end below the value over this factor is the edge of the fit's search range, 0 in effect (the
#: reports print it "~0": ``reports.numbers.EXTREME_FACTOR``)
ZERO_END_FACTOR = 1e6


def excludes_zero(value: float, ci) -> bool:
    """Whether the 90 % interval ``ci`` (``[lo, hi]``, unit of ``value``) of a term ``value`` excludes 0: its
    lower end is above ``value`` / :data:`ZERO_END_FACTOR`."""
    if not ci or len(ci) != 2 or not _finite(ci[0]) or not _finite(value):
        return False
    return ci[0] > 0 and ci[0] > value / ZERO_END_FACTOR


def with_bounds(summary: dict, allan: AllanResult, model_fits: bool = True) -> dict:
    """An ``ieee952`` summary (:func:`~.coefficients.ieee952_summary`) with ``K_upper90`` and
    ``B_upper90`` (and the tau, s, that gives each), ``K_detected``: whether the model carries a
    random walk with an interval that excludes 0 (:func:`excludes_zero`), and ``B_detected``: whether it
    carries a bias instability or a Gauss-Markov term and B's interval excludes 0 (otherwise its ``B`` is the
    floor where its white noise meets its walk, or a flicker the record does not show: an upper bound).
    ``B_band90``: B read from the curve as a flicker floor (:func:`b_band`); B's
    interval takes it in (``B_widened`` says why) where the model does not fit (``model_fits`` false);
    K's likewise (``K_widened``, :func:`_with_k_band`). Keys documented
    in docs/analysis-json.md."""
    out = dict(summary)
    kb, bb = k_upper(allan), b_upper(allan)
    out = _with_k_band(out, allan, model_fits)
    # an interval from 0 (a model without the term fits nearly as well) is a bound, not a detection
    k_ci = out.get("K_ci90")
    out["K_detected"] = bool(
        out.get("K") is not None and k_ci and all(_finite(v) for v in k_ci) and excludes_zero(out["K"], k_ci)
    )
    # a model without a bias instability or a Gauss-Markov term has no B of its own: its "model floor" is
    # where its white noise meets its random walk, an upper bound on B rather than a measurement; a fitted
    # flicker whose interval reaches 0 (white noise read as wn+fl: B 4.9e-6 m/s^2 with [9e-34, 2e22]) is one too
    has_b = out.get("B_from") == "fitted" or bool(out.get("gauss_markov"))
    out["B_detected"] = has_b and out.get("B") is not None and excludes_zero(out["B"], out.get("B_ci90"))
    out["K_upper90"] = kb.value if kb else None
    out["K_upper90_tau_s"] = kb.tau_s if kb else None
    out["B_upper90"] = bb.value if bb else None
    out["B_upper90_tau_s"] = bb.tau_s if bb else None
    return _with_band(out, allan, model_fits)


def _finite(v) -> bool:
    return v is not None and math.isfinite(v)


def _edf_at(allan: AllanResult, tau_s: float) -> float:
    """The measured curve's degrees of freedom at ``tau_s`` (s; 0 beyond its last point)."""
    ok = np.isfinite(allan.edf) & (allan.tau > 0)
    if not ok.any() or not math.isfinite(tau_s) or tau_s > allan.tau[ok][-1]:
        return 0.0
    return float(np.interp(math.log(tau_s), np.log(allan.tau[ok]), allan.edf[ok]))


def _with_k_band(out: dict, allan: AllanResult, model_fits: bool) -> dict:
    """``out`` with K's interval widened to the curve's reading of a walk (:func:`k_band`, ``K_widened``
    says why) where the model's K rests on its structure or on the record's last clusters: the model does not
    fit, or its walk leads only where the curve has fewer than :data:`WALK_MIN_EDF` degrees of freedom."""
    out["K_widened"] = None
    ci = out.get("K_ci90")
    if out.get("K") is None or not ci or not all(_finite(v) for v in ci):
        return out
    start = out.get("K_from_tau_s")
    edf = _edf_at(allan, start) if start is not None else math.inf
    if model_fits and edf >= WALK_MIN_EDF:
        return out
    n_ci = out.get("N_ci90") or ()
    n_hi = n_ci[1] if len(n_ci) == 2 and _finite(n_ci[1]) else out.get("N") or 0.0
    b_ci = out.get("B_ci90") or ()
    b_hi = b_ci[1] if len(b_ci) == 2 and _finite(b_ci[1]) else out.get("B") or 0.0
    band = k_band(allan, float(n_hi), float(b_hi))
    if not all(math.isfinite(v) for v in band):
        return out
    out["K_ci90"] = [min(ci[0], band[0]), max(ci[1], band[1])]
    why = (
        "the chosen model does not fit the Allan deviation"
        if not model_fits
        else f"the walk leads the model's Allan variance only where the curve has {edf:.0f} degrees of freedom"
    )
    out["K_widened"] = why + "; the interval takes in K read from the measured curve"
    return out


def _with_band(out: dict, allan: AllanResult, model_fits: bool) -> dict:
    """``out`` with ``B_band90`` and, where the model's B rests on its structure, B's interval widened to it."""
    n_ci = out.get("N_ci90") or ()
    n_hi = n_ci[1] if len(n_ci) == 2 and _finite(n_ci[1]) else out.get("N") or 0.0
    k_ci = out.get("K_ci90") or ()
    k_hi = k_ci[1] if len(k_ci) == 2 and _finite(k_ci[1]) else out.get("K_upper90") or 0.0
    band = b_band(allan, float(n_hi), float(k_hi))
    out["B_band90"] = list(band) if all(math.isfinite(v) for v in band) else None
    out["B_widened"] = None
    why = (
        ""
        if model_fits
        else "the chosen model does not fit the Allan deviation: its B rests on a structure the data reject"
    )
    if why and out["B_band90"] is not None and out.get("B_detected") and out.get("B") is not None:
        ci = [v if _finite(v) else None for v in (out.get("B_ci90") or (None, None))]
        lo = min(v for v in (ci[0], band[0], out["B"]) if v is not None)
        hi = max(v for v in (ci[1], band[1], out["B"]) if v is not None)
        out["B_ci90"] = [lo, hi]
        out["B_widened"] = why + "; the interval takes in B read from the measured curve as a flicker floor"
    return out


#: the classic N is marked "above the Allan deviation at 1 s" only when its lower limit exceeds the measured
#: ADEV(1 s)'s upper limit, each one-sided at this confidence: on clean data the two agree within ADEV(1 s)'s
#: sampling error (the 1.5 h demo capture's gyro x, white noise + Gauss-Markov: N 1.3 % above ADEV(1 s), 1.7
#: of its standard errors), and a record's every channel, a fleet's every device, is tested: a 95 % limit
#: would mark about one clean channel in twenty
N_FLAG_CONFIDENCE = 0.999


def adev_upper(adev: float, stderr: float, confidence: float = N_FLAG_CONFIDENCE) -> float:
    """One-sided upper ``confidence`` limit (unit of ``adev``) of the true Allan deviation behind a measured
    ``adev`` with standard error ``stderr`` (``adev / sqrt(2 edf)``, :func:`.ieee.ieee_coefficients`): the
    chi-square limit of ``edf`` degrees of freedom; ``adev`` itself where the error is unknown."""
    if not (math.isfinite(stderr) and stderr > 0 and adev > 0):
        return adev
    edf = 0.5 * (adev / stderr) ** 2
    return adev * math.sqrt(edf / float(chi2.ppf(1.0 - confidence, edf)))


#: the classic N is marked when it lies this far (relative) outside the noise model's 90 % interval of N
N_AGREE = 0.10


def ieee_usability(
    ieee: IEEECoefficients, allan: AllanResult, n_ci90: tuple[float, float] | None = None
) -> IEEECoefficients:
    """``ieee`` with ``N_unusable`` / ``B_unusable`` set to the reason where its N or B breaks what
    any noise term allows (module docstring), or N lies more than :data:`N_AGREE` outside
    ``n_ci90`` (the noise model's 90 % interval of N, unit/sqrt(Hz)), empty strings otherwise."""
    n_why, b_why = [], []
    if not ieee.N > 0:
        n_why.append("the subset fit left the white noise out (N = 0): no sensor has none")
    elif math.isfinite(ieee.adev_1s):
        high = adev_upper(ieee.adev_1s, ieee.adev_1s_stderr)
        n_se = ieee.N_stderr if math.isfinite(ieee.N_stderr) else 0.0
        n_low = ieee.N - float(norm.ppf(N_FLAG_CONFIDENCE)) * n_se
        if n_low > high:
            n_why.append(
                f"N {ieee.N:.3g} is above the measured Allan deviation at 1 s ({ieee.adev_1s:.3g}; its upper "
                f"{100 * N_FLAG_CONFIDENCE:.1f} % limit {high:.3g}), which no sum of the IEEE-952 terms allows: "
                "a term outside them (a sinusoid, a resonance) reaches 1 s"
            )
    if ieee.N > 0 and n_ci90 is not None and all(math.isfinite(v) and v > 0 for v in n_ci90):
        lo, hi = n_ci90
        if ieee.N < lo * (1.0 - N_AGREE) or ieee.N > hi * (1.0 + N_AGREE):
            n_why.append(
                f"N {ieee.N:.3g} lies outside the noise model's 90 % interval [{lo:.3g}, {hi:.3g}] by more than "
                f"{100 * N_AGREE:.0f} %: the Allan-curve fit trades the white noise against its other terms"
            )
    usable = np.flatnonzero(np.isfinite(allan.edf) & (allan.edf >= 10.0))
    if ieee.B == 0 and len(usable) > 2:
        i = int(usable[np.argmin(allan.adev[usable])])
        if 0 < i < usable[-1]:
            b_why.append(
                f"B = 0 although the Allan deviation has a minimum at {allan.tau[i]:.3g} s: read B_min "
                f"({ieee.B_min:.3g}) or the noise model's B"
            )
    return replace(ieee, N_unusable="; ".join(n_why), B_unusable="; ".join(b_why))
