"""Analysis layer (``imustation.analysis``): arrays and run files in, dataclasses out.

Public API::

    from imustation.analysis import oadev, fit_mli
    res = oadev(rate, fs_hz)            # .tau, .adev, .adev_lo, .adev_hi (also mdev, ohdev, totdev)
    psd = welch_psd(rate, fs_hz)        # .f, .psd (one-sided unless sides="two"); log_average(psd)
    ar = fit_ar(rate)                   # AR(p) by least squares, SBC order; gauss_markov_from_ar1
    fit = fit_mli(rate, fs_hz)          # .sigma_w, .sigma_b, .tau_b, .b_on, .stderr, .nll
    fit = fit_mli(rate, fs_hz, model="wn+2gm", segments=[(0, n1), (n2, n)])
    wv = wavelet_variance(rate, fs_hz)  # Haar WV: .scale, .tau, .wv, .wv_lo, .wv_hi; fit_gmwm -> MLiResult fields

This layer imports nothing from ``imustation.drivers`` or ``imustation.acquisition``.

The names above load on first use (PEP 562 ``__getattr__``): importing one submodule,
e.g. ``imustation.analysis.models`` for the chip simulators, does not pay for scipy.stats,
numba and every estimator.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from imustation.analysis.allan import AllanResult, mdev, oadev, ohdev, totdev
    from imustation.analysis.ar import ARResult, GaussMarkov, fit_ar, gauss_markov_from_ar1
    from imustation.analysis.gmwm import GMWMResult, WVResult, fit_gmwm, wavelet_variance
    from imustation.analysis.ieee import IEEECoefficients, ieee_coefficients
    from imustation.analysis.ml_rate import fit_ml_rate
    from imustation.analysis.mli import MLiResult, compare_models, fit_integrated, fit_mli, integrate
    from imustation.analysis.models import StandardModel, simulate_standard
    from imustation.analysis.noise_models import NoiseModel
    from imustation.analysis.psd import PSDResult, log_average, welch_psd

#: submodule -> the public names it defines (in step with the TYPE_CHECKING imports and __all__)
_SOURCES = {
    "allan": ("AllanResult", "mdev", "oadev", "ohdev", "totdev"),
    "ar": ("ARResult", "GaussMarkov", "fit_ar", "gauss_markov_from_ar1"),
    "gmwm": ("GMWMResult", "WVResult", "fit_gmwm", "wavelet_variance"),
    "ieee": ("IEEECoefficients", "ieee_coefficients"),
    "ml_rate": ("fit_ml_rate",),
    "mli": ("MLiResult", "compare_models", "fit_integrated", "fit_mli", "integrate"),
    "models": ("StandardModel", "simulate_standard"),
    "noise_models": ("NoiseModel",),
    "psd": ("PSDResult", "log_average", "welch_psd"),
}
_ORIGIN = {name: module for module, names in _SOURCES.items() for name in names}

__all__ = [
    "AllanResult",
    "oadev",
    "mdev",
    "ohdev",
    "totdev",
    "PSDResult",
    "welch_psd",
    "log_average",
    "ARResult",
    "GaussMarkov",
    "fit_ar",
    "gauss_markov_from_ar1",
    "IEEECoefficients",
    "ieee_coefficients",
    "MLiResult",
    "fit_mli",
    "fit_integrated",
    "integrate",
    "compare_models",
    "fit_ml_rate",
    "WVResult",
    "wavelet_variance",
    "GMWMResult",
    "fit_gmwm",
    "NoiseModel",
    "StandardModel",
    "simulate_standard",
]


def __getattr__(name: str):
    module = _ORIGIN.get(name)
    if module is None:  # also lets ``from imustation.analysis import plots`` fall through to the submodule
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # later look-ups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
