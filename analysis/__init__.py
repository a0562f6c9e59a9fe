"""Analysis layer (``imustation.analysis``): arrays and run files in, dataclasses out.

Public API::

    from imustation.analysis import oadev, fit_mli
    res = oadev(rate, fs_hz)            # .tau, .adev, .adev_lo, .adev_hi
    fit = fit_mli(rate, fs_hz)          # .sigma_w, .sigma_b, .tau_b, .b_on, .stderr, .nll

This layer imports nothing from ``imustation.drivers`` or ``imustation.acquisition``.
"""

from imustation.analysis.allan import AllanResult, oadev
from imustation.analysis.ieee import IEEECoefficients, ieee_coefficients
from imustation.analysis.mli import MLiResult, fit_mli
from imustation.analysis.models import StandardModel, simulate_standard

__all__ = [
    "AllanResult",
    "oadev",
    "IEEECoefficients",
    "ieee_coefficients",
    "MLiResult",
    "fit_mli",
    "StandardModel",
    "simulate_standard",
]
