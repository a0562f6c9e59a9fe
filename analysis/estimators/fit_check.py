"""A simple goodness-of-fit check of a noise model against the measured Allan deviation.

Used by the automatic model choice (:mod:`.model_choice`) to tell "fits" from "does
not fit". Each measured overlapping Allan variance ``a`` at cluster time tau is,
under the model, ``AVAR_model(tau) chi^2_edf / edf`` (``edf`` the identified noise
type's, at most a rate random walk's); its chi-square probability is
mapped to a standard normal score ``z`` ("whitened residual"). Points four octaves
of tau apart (a factor 4, where neighbouring overlapping Allan variances are
nearly uncorrelated) with at least :data:`MIN_EDF` degrees of freedom, at and
above the cluster time from which the model holds (a device filter's memory), give
``sum z^2``; the model fits when its chi-square probability with as many degrees
of freedom is above :data:`ALPHA`. ``where`` names the tau range of the scores
beyond 2.5.

This is deliberately simple: it ignores the remaining correlation across tau and
the uncertainty of the fitted parameters. The full adequacy test of issue 22
(docs/noise-model.md, "On real recordings") may replace it: the model choice only
needs :func:`allan_fit_check`'s ``fits`` and ``p_value``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2, norm

from imustation.analysis.estimators.allan import AllanResult, edf_oadev
from imustation.analysis.estimators.noise_models import NoiseModel

#: smallest equivalent degrees of freedom of a tau used by the check
MIN_EDF = 4.0
#: the model fits when the chi-square probability of sum z^2 is above this
ALPHA = 0.01
#: spacing of the taus used (a factor of 4 in tau)
SPACING = 4.0


@dataclass(frozen=True)
class FitCheck:
    """Outcome of :func:`allan_fit_check`.

    ``fits``; ``statistic`` = sum of squared whitened residuals over ``dof`` taus and
    its ``p_value``; ``tau`` (s) and ``z`` the taus used and their scores; ``where`` a
    sentence naming the taus that do not fit ("" when all do).
    """

    fits: bool
    statistic: float
    dof: int
    p_value: float
    tau: np.ndarray
    z: np.ndarray
    where: str

    def as_dict(self) -> dict:
        return {"fits": self.fits, "statistic": self.statistic, "dof": self.dof, "p_value": self.p_value,
                "where": self.where}  # fmt: skip


def _thin(tau: np.ndarray, spacing: float) -> np.ndarray:
    keep, last = [], -math.inf
    for i, t in enumerate(tau):
        if math.log(t) >= last + math.log(spacing) - 1e-9:
            keep.append(i)
            last = math.log(t)
    return np.array(keep, dtype=int)


def allan_fit_check(allan: AllanResult, model: NoiseModel, fs_hz: float, tau_min: float = 0.0) -> FitCheck:
    """Check ``model`` (rate units) against the measured overlapping Allan deviation ``allan``
    at cluster times from ``tau_min`` (s) on (module docstring); ``fs_hz`` Hz."""
    ok = np.isfinite(allan.edf) & (allan.edf >= MIN_EDF) & (allan.tau >= tau_min * (1 - 1e-9)) & (allan.adev > 0)
    idx = np.flatnonzero(ok)
    idx = idx[_thin(allan.tau[idx], SPACING)] if len(idx) else idx
    tau = allan.tau[idx]
    if len(tau) == 0:
        return FitCheck(True, 0.0, 0, 1.0, tau, np.zeros(0), "no cluster time with enough degrees of freedom")
    # the EDF of the noise type identified at each tau, but at most that of a rate random walk:
    # the identification is unsure at the long taus, and an EDF too large rejects good models
    m = np.maximum(np.rint(tau * fs_hz), 1.0)
    edf_rw = edf_oadev(float(np.max(allan.n[idx] + 2 * m)), m, np.full(len(m), -2))
    edf = np.minimum(allan.edf[idx], np.maximum(edf_rw, 1.0))
    with np.errstate(all="ignore"):
        ratio = allan.adev[idx] ** 2 / model.avar(tau, fs_hz)
    # chi-square probability of each measured AVAR under the model, as a normal score
    p = chi2.cdf(edf * ratio, edf)
    z = norm.ppf(np.clip(p, 1e-300, 1.0 - 1e-16))
    z = np.where(np.isfinite(z), z, 40.0)
    stat = float(np.sum(z * z))
    p_value = float(chi2.sf(stat, len(tau)))
    bad = np.abs(z) > 2.5
    where = ""
    if bad.any():
        lo, hi = float(tau[bad].min()), float(tau[bad].max())
        side = "above" if float(np.mean(z[bad])) > 0 else "below"
        where = f"measured Allan deviation {side} the model between {lo:.3g} s and {hi:.3g} s"
    return FitCheck(p_value > ALPHA, stat, len(tau), p_value, tau, z, where)
