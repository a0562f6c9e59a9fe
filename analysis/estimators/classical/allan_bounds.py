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

**Classic IEEE-952 checks** (:func:`ieee_usability`): every term adds Allan variance, so the white
noise ``N`` of the subset fit can be neither 0 (the Allan deviation falls as ``tau^-1/2`` somewhere
from the filter's memory on on any sensor) nor above the measured deviation at 1 s by more than its
sampling error; and ``B`` is not 0 where the curve has a minimum inside the record. A coefficient
that breaks one of these, or that disagrees with the noise model's own 90 % interval of the same
quantity, is marked unusable with the reason instead of being printed as a measurement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2

from imustation.analysis.estimators.classical.allan import AllanResult
from imustation.analysis.estimators.classical.ieee import B_FACTOR, IEEECoefficients

#: confidence of the stated upper bounds
BOUND_CONFIDENCE = 0.90
#: points of the Allan curve used for a bound: at least this many degrees of freedom (fewer: the
#: chi-square's lower quantiles collapse and the bound says nothing)
MIN_EDF = 1.0


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


def b_upper(allan: AllanResult, alpha: float = 1.0 - BOUND_CONFIDENCE) -> UpperBound | None:
    """Upper bound (unit) on a bias instability (flicker floor) from the Allan curve (module docstring)."""
    tau, avar, edf = _octave_points(allan)
    if len(tau) == 0:
        return None
    b2 = _upper_avar(avar, edf, alpha / len(tau)) / B_FACTOR**2
    i = int(np.argmin(b2))
    return UpperBound(float(math.sqrt(b2[i])), float(tau[i]), 1.0 - alpha)


def with_bounds(summary: dict, allan: AllanResult) -> dict:
    """An ``ieee952`` summary (:func:`~.coefficients.ieee952_summary`) with ``K_upper90`` and
    ``B_upper90`` (and the tau, s, that gives each), ``K_detected``: whether the model carries a
    random walk with an interval that excludes 0, and ``B_detected``: whether it carries a bias instability or a
    Gauss-Markov term (otherwise its ``B`` is the floor where its white noise meets its walk, an
    upper bound). Keys documented in docs/analysis-json.md."""
    out = dict(summary)
    kb, bb = k_upper(allan), b_upper(allan)
    ci = out.get("K_ci90")
    # an interval from 0 (a model without a walk fits nearly as well) is a bound, not a detection
    out["K_detected"] = bool(
        out.get("K") is not None and ci and all(v is not None and math.isfinite(v) for v in ci) and ci[0] > 0
    )
    # a model without a bias instability or a Gauss-Markov term has no B of its own: its "model floor" is
    # where its white noise meets its random walk, an upper bound on B rather than a measurement
    out["B_detected"] = out.get("B_from") == "fitted" or bool(out.get("gauss_markov"))
    out["K_upper90"] = kb.value if kb else None
    out["K_upper90_tau_s"] = kb.tau_s if kb else None
    out["B_upper90"] = bb.value if bb else None
    out["B_upper90_tau_s"] = bb.tau_s if bb else None
    return out


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
        high = ieee.adev_1s + 1.645 * (ieee.adev_1s_stderr if math.isfinite(ieee.adev_1s_stderr) else 0.0)
        if ieee.N > high:
            n_why.append(
                f"N {ieee.N:.3g} is above the measured Allan deviation at 1 s ({ieee.adev_1s:.3g}), which no sum "
                "of the IEEE-952 terms allows: a term outside them (a sinusoid, a resonance) reaches 1 s"
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
