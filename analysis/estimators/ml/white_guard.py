"""sigma_w never confidently wrong: the chosen model's white-noise interval checked against what the
fine scales say from later starting points.

The model family reads sigma_w at the first cluster size beyond the device filter's memory where the
Allan variances follow white noise, the angle term and smooth slow terms
(:func:`~.finescale.fine_statistics`). Whatever lies just below the next scales and has another
shape (a resonance before its correlation time is over, the onset of a bias instability that stops
at some fine scale, a filter's tail) biases it, and its interval, computed as if the shape were
right, is then confidently wrong (issue 32: a 35 Hz resonance, sigma_w -4.1 % with an interval
ending at -1.0 %).

The same fit started one, two, three ... octaves later (:func:`~.finescale.white_by_scale`) reads
sigma_w^2 where those shapes have died away, less precisely. Where such an estimate disagrees with
the chosen model's by more than :data:`DISAGREE_Z` of its standard error, the data say the shape
below it is not what the fit assumed, and the model's interval is widened to take in that estimate's
90 % interval: the point estimate stays, and the interval says how wide the truth may be. Where the
slow terms show at the fine scales, the model-free bound of :func:`~.finescale.white_bound` (the
slow terms can only add to it) is the interval's upper end whenever it lies above the model's
(before: only when their share at the first fine scale exceeded 5 %; the MPU-9150 datasheet gyro z,
share under 5 %, came out -2.3 % with an interval ending at -1.0 % while the bound stood at +0.06
%), and it caps the widening above. On channels where the fine scales are white the later estimates
agree and nothing changes.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from imustation.analysis.estimators.engine.fitting import Z90
from imustation.analysis.estimators.ml.composite import CompositeResult
from imustation.analysis.estimators.ml.finescale import (
    FineStatistic,
    Octaves,
    allan_corr,
    fine_white,
    octave_avars,
    white_by_scale,
)

#: a later scale's sigma_w^2 disagrees with the model's when this many of its standard errors away
DISAGREE_Z = 3.0
#: the floor L overstates sigma_w^2 where a bias instability's Allan variance still falls at the finest
#: scales (a discrete 1/f spectrum up to the Nyquist frequency: Kasdin's flicker at 118 deg/h over
#: 0.3 deg/sqrt(h) gave L 1.2 x sigma_w^2, a DLPF'd one more): only a model sigma_w^2 below L / 4 is
#: overruled, and the stated range starts at L / 4
FLOOR_MARGIN = 4.0


def white_floor(fine: FineStatistic, fs_hz: float) -> tuple[float, float]:
    """A lower bound on sigma_w^2 ((rate unit)^2 s) from the Allan variances at the pair of
    :func:`~.finescale.white_bound` (k and 2k samples, beyond the filter's memory), and its standard
    error; (NaN, NaN) without that pair.

    ``L = 2 tau (AVAR(tau) - AVAR(2 tau))`` is ``sigma_w^2 (1 - 2.25 tau_lp / tau)`` for white noise behind
    a filter and adds ``2 tau (s(tau) - s(2 tau)) <= 0`` for any slow term whose Allan variance does not
    fall from tau to 2 tau (a bias instability's floor, a random walk, a Gauss-Markov term before its
    correlation time): a bound from below that needs no model of them. White angle noise and
    resonances fall as tau^-2 and break it: not used where the fine scales carry an angle term ``wa``.
    """
    k = fine.bound_samples
    if k <= 0 or fine.octaves is None or fine.term == "wa":
        return (math.nan, math.nan)
    got = fine.octaves
    if k not in got.avar or 2 * k not in got.avar:
        return (math.nan, math.nan)
    tau = k / fs_hz
    (a1, e1), (a2, e2) = got.statistic(k), got.statistic(2 * k)
    s1, s2 = a1 * math.sqrt(2.0 / e1), a2 * math.sqrt(2.0 / e2)
    var = s1 * s1 + s2 * s2 - 2.0 * allan_corr(k, 2 * k) * s1 * s2
    return (2.0 * tau * (a1 - a2), 2.0 * tau * math.sqrt(max(var, 0.0)))


#: octaves of later starting points wanted beyond the statistic's first scale
LATER_OCTAVES = 3
#: an angle term the statistic does not carry (its z under finescale.ANGLE_Z) is not ruled out when its z
#: exceeds this: the interval then takes in sigma_w read with it. One standard error: a term of z biases the
#: single-scale reading by ~2.4 z of its standard errors, beyond a 90 % interval from z ~0.7 (at 2, the
#: folded 62.5 Hz filter's interval missed on 4 of 6 records; at 1, on 1 of 6)
ANGLE_OPEN_Z = 1.0


def with_angle_term(fine: FineStatistic, fs_hz: float) -> tuple[float, float]:
    """sigma_w^2 ((rate unit)^2 s) read with an angle term at the statistic's first scale k: ``U = 2 u(2 tau)
    - u(tau)`` from the Allan variances at k and 2k samples (``u = tau AVAR``; exact for white noise plus
    any angle term beyond the memory), and its standard error (white-noise covariance times the
    statistic's block inflation); (NaN, NaN) where the statistic's octaves lack 2k.

    The single-scale statistic assumes no angle term at k; one of ``z`` standard errors biases it by about
    ``2.4 z`` of its own standard errors (the 62.5 Hz filter folded at 125 Hz, not announced: z -1.6 ..
    -3.7 on 1 h records, sigma_w +0.3 .. +0.6 % with intervals ending below the truth on 6 of 6)."""
    got, k = fine.octaves, fine.samples
    if got is None or k not in got.avar or 2 * k not in got.avar:
        return (math.nan, math.nan)
    (a1, e1), (a2, e2) = got.statistic(k), got.statistic(2 * k)
    t1, t2 = k / fs_hz, 2 * k / fs_hz
    s1, s2 = a1 * math.sqrt(2.0 / e1), a2 * math.sqrt(2.0 / e2)
    g1, g2 = -t1, 2.0 * t2
    var = (g1 * s1) ** 2 + (g2 * s2) ** 2 + 2.0 * g1 * g2 * allan_corr(k, 2 * k) * s1 * s2
    return (g1 * a1 + g2 * a2, math.sqrt(max(var, 0.0) * max(fine.inflation, 1.0)))


def later_octaves(
    fine: FineStatistic,
    rate: np.ndarray,
    fs_hz: float,
    *,
    scale: float = 1.0,
    segments: list[tuple[int, int]] | None = None,
) -> Octaves | None:
    """``fine.octaves`` extended to the cluster sizes the later starting points need (up to
    ``16 * 2**LATER_OCTAVES`` times the statistic's first size, as the record allows); ``None`` when
    ``fine.octaves`` already reach them. ``rate`` as for :func:`~.finescale.fine_statistics`."""
    have = fine.octaves
    if have is None:
        return None
    top = 16 * fine.samples * 2**LATER_OCTAVES
    want = tuple(k for k in (2**j for j in range(31)) if max(have.avar) < k <= top and 2 * k < have.n)
    if not want:
        return None
    more = octave_avars(rate, fs_hz, want, scale=scale, segments=segments)
    return Octaves(have.n, have.fs_hz, {**have.avar, **more.avar}, {**have.edf, **more.edf})


def guard_white(
    res: CompositeResult, fine: FineStatistic, fs_hz: float, octaves: Octaves | None = None
) -> CompositeResult:
    """``res`` with its ``sigma_w`` 90 % interval widened to take in every later scale's estimate that
    disagrees with it and to reach the bound U (module docstring), and ``message`` saying so; ``res``
    itself otherwise. A point below :func:`white_floor` / :data:`FLOOR_MARGIN` (by its 90 % error) is
    replaced by the geometric middle of the floor and the bound, the interval by their range (from the
    floor / :data:`FLOOR_MARGIN`) (the model's curve,
    ``noise_model``, is left as fitted; ``message`` says so). ``octaves``: Allan variances of the
    record reaching further than ``fine.octaves`` (:func:`later_octaves`)."""
    ci = res.ci90.get("sigma_w")
    if ci is None or not res.sigma_w > 0:
        return res
    lo, hi = ci
    notes = []
    u, u_se = fine.white_bound
    if math.isfinite(u) and math.isfinite(u_se) and u > 0:
        top = math.sqrt(u + Z90 * u_se)
        if math.isfinite(hi) and top > hi:  # the slow terms show at the fine scales: sigma_w rests on their shape
            hi = top
            notes.append(
                f"sigma_w <= {top:.4g} (90 %) where the slow terms can only add (finescale.white_bound): its "
                "interval reaches it"
            )
    s2 = res.sigma_w**2
    wider = []
    for i, (tau, a, se) in enumerate(white_by_scale(fine, fs_hz, octaves)):
        # white angle noise and a resonance beyond its correlation time look alike only beyond it: with an
        # angle term "wa" the next octave's estimate always belongs in the interval (a 20 Hz, Q 2 resonance:
        # sigma_w -1.2 % with an interval ending at -0.4 %, the next octave's -0.4 +- 1.4 %)
        always = i == 0 and fine.term == "wa"
        if not (math.isfinite(se) and se > 0) or (abs(a - s2) <= DISAGREE_Z * se and not always):
            continue
        a_lo, a_hi = a - Z90 * se, a + Z90 * se
        if a_hi <= 0:
            continue
        new_lo = math.sqrt(a_lo) if a_lo > 0 else 0.0
        new_hi = math.sqrt(a_hi)
        wider.append((tau, math.sqrt(max(a, 0.0)), always and abs(a - s2) <= DISAGREE_Z * se))
        lo = min(lo, new_lo) if math.isfinite(lo) else new_lo
        hi = max(hi, new_hi) if math.isfinite(hi) else new_hi
    if fine.nuisance.shape[1] == 0:
        # the model's sigma_w also rests on the coarse scales through its slow terms' model; where that model
        # is not the record's it steers sigma_w beyond what the fine scales say (project ADIS16448 simulator,
        # flicker built of relaxation terms plus a random walk, fitted wn+fl+lp: sigma_w -0.35 % mean over 12
        # 1 h records, 3 outside +-0.5 % intervals). The fine scales' own reading needs no slow-term model
        # where they show none: its 90 % interval belongs in the stated one
        a, se = fine_white(fine)
        if math.isfinite(a) and math.isfinite(se) and a + Z90 * se > 0:
            f_lo, f_hi = math.sqrt(max(a - Z90 * se, 0.0)), math.sqrt(a + Z90 * se)
            if f_lo < lo or f_hi > hi:
                lo, hi = min(lo, f_lo), max(hi, f_hi)
                notes.append(
                    f"the fine scales alone read sigma_w {math.sqrt(max(a, 0.0)):.4g} "
                    f"({100 * (math.sqrt(max(a, 0.0)) / res.sigma_w - 1):+.2f} %; the model's rests on its slow terms "
                    "too): the interval takes in their 90 % interval"
                )
    if not fine.term and fine.nuisance.shape[1] == 0 and abs(fine.angle_z) > ANGLE_OPEN_Z:
        # an angle term the data do not rule out: sigma_w read with it belongs in the interval
        a, se = with_angle_term(fine, fs_hz)
        if math.isfinite(a) and math.isfinite(se) and a + Z90 * se > 0:
            a_lo = a - Z90 * se
            lo = min(lo, math.sqrt(a_lo) if a_lo > 0 else 0.0)
            hi = max(hi, math.sqrt(a + Z90 * se))
            notes.append(
                f"an angle term of z {fine.angle_z:.2g} at {fine.samples} samples is not ruled out: the interval "
                f"takes in sigma_w read with it ({math.sqrt(max(a, 0.0)):.4g})"
            )
    if math.isfinite(u) and math.isfinite(u_se) and u > 0:  # an upper bound no shape below it can break
        hi = max(ci[1], min(hi, math.sqrt(u + Z90 * u_se)))
    for tau, s, agreed in wider[:1]:
        if agreed:
            notes.append(
                f"with a white angle term (a resonance looks alike only beyond its correlation time) the interval "
                f"takes in sigma_w read from {tau:g} s on ({s:.4g})"
            )
        else:
            notes.append(
                f"sigma_w read from {tau:g} s on is {s:.4g} ({100 * (s / res.sigma_w - 1):+.1f} %): the shape below "
                "that scale is not the model's (a resonance, the slow terms' onset); interval widened to cover it"
            )
    point, params = res.sigma_w, res.params
    low, low_se = white_floor(fine, fs_hz)
    if math.isfinite(low) and low > 0 and res.sigma_w**2 < (low - Z90 * low_se) / FLOOR_MARGIN:
        # the model's white noise lies below what the fine scales allow: a slow term (at its bound, or a
        # Gauss-Markov term short enough to act as white noise) took its place. The point becomes the
        # middle of what the data allow, the interval their range
        bottom = math.sqrt(max(low - Z90 * low_se, 0.0) / FLOOR_MARGIN)
        bound = math.sqrt(u + Z90 * u_se) if math.isfinite(u) and math.isfinite(u_se) and u > 0 else math.nan
        # the model-free bound caps what a collapsed model's own interval says (12 h MPU-9150 gyro y: 7.6e-3
        # against a bound of 9.3e-5)
        top = min(hi, bound) if math.isfinite(hi) and math.isfinite(bound) else hi if math.isfinite(hi) else bound
        point = math.sqrt(math.sqrt(low) * math.sqrt(u)) if math.isfinite(u) and u > low else math.sqrt(low)
        lo, hi = bottom, max(top, point) if math.isfinite(top) else top
        params = {**res.params, "sigma_w": point}
        notes.append(
            f"the model's sigma_w {res.sigma_w:.3g} lies below the {math.sqrt(low):.4g} the Allan variances at "
            f"{fine.bound_samples} and {2 * fine.bound_samples} samples allow (a slow term took the white noise's "
            f"place): stated as the middle {point:.4g} of the range the fine scales allow"
        )
    if not notes:
        return res
    message = "; ".join([res.message, *notes])
    return replace(res, sigma_w=point, params=params, ci90={**res.ci90, "sigma_w": (lo, hi)}, message=message)
