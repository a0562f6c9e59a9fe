"""Overlapping Allan deviation of rate data.

For rate samples ``y_k`` (rad/s) at ``fs_hz``, the angle is
``x_k = tau0 * sum_{i<k} y_i`` (``x_0 = 0``) and, with ``tau = m tau0``,

.. math:: \\sigma^2(\\tau) = \\frac{1}{2\\tau^2 (N-2m)} \\sum_{i=0}^{N-2m-1} (x_{i+2m} - 2x_{i+m} + x_i)^2

(NIST SP 1065 eq. 11; N = number of angle points). Integer counts are
integrated exactly in int64 before scaling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from imustation.errors import InputError

#: probability mass inside [adev_lo, adev_hi] (one sigma of a normal)
CONFIDENCE = 0.683


@dataclass(frozen=True)
class AllanResult:
    """Allan deviation at cluster times ``tau`` (s); same units as the rate.

    ``adev_lo``/``adev_hi`` bound a 68.3 % interval from the equivalent degrees
    of freedom ``edf`` (white-noise EDF, SP 1065 §5.2); ``n`` is the number of
    second differences averaged at each tau.
    """

    tau: np.ndarray
    adev: np.ndarray
    adev_lo: np.ndarray
    adev_hi: np.ndarray
    edf: np.ndarray
    n: np.ndarray


def log_taus(n: int, fs_hz: float, per_decade: int = 10) -> np.ndarray:
    """Log-spaced cluster times (s) with distinct integer ``m`` up to ``(n-1)//2``."""
    m_max = max(1, (n - 1) // 2)
    m = np.unique(np.round(np.logspace(0, np.log10(m_max), int(per_decade * np.log10(m_max)) + 1)))
    return m.astype(np.int64) / fs_hz


def integrate(rate: np.ndarray, fs_hz: float, scale: float = 1.0) -> np.ndarray:
    """Angle ``x`` (N+1 points, ``x[0] = 0``): exact int64 sums for integer counts."""
    tau0 = 1.0 / fs_hz
    if np.issubdtype(rate.dtype, np.integer):
        x = np.empty(len(rate) + 1, dtype=np.int64)
        x[0] = 0
        np.cumsum(rate, dtype=np.int64, out=x[1:])
        return x.astype(np.float64) * (scale * tau0)
    x = np.empty(len(rate) + 1, dtype=np.float64)
    x[0] = 0.0
    np.cumsum(rate, out=x[1:])
    return x * (scale * tau0)


def _check(rate: np.ndarray, fs_hz: float) -> np.ndarray:
    rate = np.asarray(rate)
    if rate.ndim != 1:
        raise InputError(f"rate must be one-dimensional, got shape {rate.shape}")
    if len(rate) < 3:
        raise InputError(f"{len(rate)} samples: Allan deviation needs at least 3")
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise InputError(f"fs_hz = {fs_hz}: must be a positive sampling rate")
    if rate.dtype.kind == "f" and not np.all(np.isfinite(rate)):
        raise InputError("rate holds NaN or infinite values")
    return rate


def edf_white(n_x: int, m: np.ndarray) -> np.ndarray:
    """EDF of the overlapping AVAR for white rate noise (SP 1065 Table 5 form)."""
    n = n_x - 1  # rate samples
    m = np.asarray(m, dtype=float)
    return (3.0 * (n - 1) / (2.0 * m) - 2.0 * (n - 2) / n) * 4.0 * m**2 / (4.0 * m**2 + 5.0)


def oadev(rate: np.ndarray, fs_hz: float, taus: np.ndarray | None = None, *, scale: float = 1.0) -> AllanResult:
    """Overlapping Allan deviation of rate samples.

    Parameters
    ----------
    rate : (n,) rate samples (rad/s, m/s^2, ...) or integer counts with ``scale``.
    fs_hz : sampling rate, Hz.
    taus : cluster times, s; rounded to whole samples; default :func:`log_taus`.
    scale : units per count when ``rate`` holds integer counts.
    """
    rate = _check(rate, fs_hz)
    x = integrate(rate, fs_hz, scale)
    n_x = len(x)
    tau_s = log_taus(len(rate), fs_hz) if taus is None else np.asarray(taus, dtype=float)
    m = np.unique(np.round(tau_s * fs_hz).astype(np.int64))
    m = m[(m >= 1) & (2 * m < n_x)]
    if len(m) == 0:
        raise InputError("no requested tau fits the record (need 2*tau shorter than the record)")
    avar = np.empty(len(m))
    for j, mj in enumerate(m):
        d = x[2 * mj :] - 2.0 * x[mj:-mj] + x[: -2 * mj]
        avar[j] = np.dot(d, d) / (2.0 * (mj / fs_hz) ** 2 * len(d))
    adev = np.sqrt(avar)
    edf = np.maximum(edf_white(n_x, m), 1.0)
    alpha = 1.0 - CONFIDENCE
    lo = adev * np.sqrt(edf / chi2.ppf(1 - alpha / 2, edf))
    hi = adev * np.sqrt(edf / chi2.ppf(alpha / 2, edf))
    return AllanResult(m / fs_hz, adev, lo, hi, edf, n_x - 2 * m)
