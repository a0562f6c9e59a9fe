"""IEEE Std 952-1997 Annex C coefficients read from an Allan deviation curve.

Each coefficient is fitted on the part of the curve where its slope dominates:
angle random walk ``N`` (slope -1/2, AVAR = N^2/tau), bias instability ``B``
(flat minimum, sigma_min = sqrt(2 ln2 / pi) B = 0.6643 B), rate random walk ``K``
(slope +1/2, AVAR = K^2 tau / 3). A term whose slope region is absent is NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from imustation.analysis.allan import AllanResult

B_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.6643


@dataclass(frozen=True)
class IEEECoefficients:
    """N in (unit)/sqrt(Hz) (rad/s/sqrt(Hz) = rad/sqrt(s)), B in (unit), K in (unit)/s*sqrt(Hz)."""

    N: float
    B: float
    K: float
    tau_B: float


def _local_slopes(res: AllanResult) -> np.ndarray:
    lt, la = np.log(res.tau), np.log(res.adev)
    return np.gradient(la, lt) if len(lt) > 2 else np.full(len(lt), np.nan)


def ieee_coefficients(res: AllanResult) -> IEEECoefficients:
    """Fit N, B, K on the slope regions of an Allan deviation curve."""
    slope = _local_slopes(res)
    avar = res.adev**2
    white = np.abs(slope + 0.5) < 0.15
    N = float(np.sqrt(np.exp(np.mean(np.log(avar[white] * res.tau[white]))))) if white.any() else float("nan")
    i_min = int(np.argmin(res.adev))
    B = float(res.adev[i_min] / B_FACTOR)
    rrw = (np.abs(slope - 0.5) < 0.15) & (np.arange(len(slope)) > i_min)
    K = float(np.sqrt(np.exp(np.mean(np.log(3.0 * avar[rrw] / res.tau[rrw]))))) if rrw.any() else float("nan")
    return IEEECoefficients(N, B, K, float(res.tau[i_min]))
