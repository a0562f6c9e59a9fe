"""Analysis layer (``imustation.analysis``): arrays and run files in, dataclasses out.

Public API::

    from imustation.analysis import oadev, fit_mli
    res = oadev(rate, fs_hz)            # .tau, .adev, .adev_lo, .adev_hi (also mdev, ohdev, totdev)
    psd = welch_psd(rate, fs_hz)        # .f, .psd (one-sided unless sides="two"); log_average(psd)
    ar = fit_ar(rate)                   # AR(p) by least squares, SBC order; gauss_markov_from_ar1
    fit = fit_mli(rate, fs_hz)          # .sigma_w, .sigma_b, .tau_b, .b_on, .stderr, .nll
    fit = fit_mli(rate, fs_hz, model="wn+2gm", segments=[(0, n1), (n2, n)])
    wv = wavelet_variance(rate, fs_hz)  # Haar WV: .scale, .tau, .wv, .wv_lo, .wv_hi; fit_gmwm -> MLiResult fields

Three rooms (each subpackage's ``__init__`` names what it offers):

* :mod:`.estimators` -- arrays in, plain dataclasses out (Allan, PSD, IEEE-952, AR, the
  noise-model library, ML_i, ML_i-F, ML on rates, GMWM and their fitting engine);
* :mod:`.reports` -- tables, figures, filter-parameter exports, attitude and temperature
  handling, and the assembly of one run's report;
* :mod:`.pipeline` -- loading channels, running the estimators per channel, serially or on
  a cluster, over runs and fleets, the Monte Carlo study and the option vocabularies.

This layer imports nothing from ``imustation.drivers`` or ``imustation.acquisition``.

The names above load on first use (PEP 562 ``__getattr__``): importing one submodule,
e.g. ``imustation.analysis.estimators.models.standard`` for the chip simulators, does not pay for scipy.stats,
numba and every estimator.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from imustation.analysis.estimators.classical.allan import AllanResult, mdev, oadev, ohdev, totdev
    from imustation.analysis.estimators.classical.ar import ARResult, GaussMarkovFit, fit_ar, gauss_markov_from_ar1
    from imustation.analysis.estimators.classical.ieee import IEEECoefficients, ieee_coefficients
    from imustation.analysis.estimators.classical.psd import PSDResult, log_average, welch_psd
    from imustation.analysis.estimators.engine.fitting import MLiResult
    from imustation.analysis.estimators.engine.pattern import integrate
    from imustation.analysis.estimators.ml.gmwm import GMWMResult, WVResult, fit_gmwm, wavelet_variance
    from imustation.analysis.estimators.ml.ml_rate import fit_ml_rate
    from imustation.analysis.estimators.ml.mli import compare_models, fit_integrated, fit_mli
    from imustation.analysis.estimators.models.noise_models import NoiseModel
    from imustation.analysis.estimators.models.standard import StandardModel, simulate_standard

#: module (below this package) -> the public names it defines (in step with the TYPE_CHECKING imports and __all__)
_SOURCES = {
    "estimators.classical.allan": ("AllanResult", "mdev", "oadev", "ohdev", "totdev"),
    "estimators.classical.ar": ("ARResult", "GaussMarkovFit", "fit_ar", "gauss_markov_from_ar1"),
    "estimators.ml.gmwm": ("GMWMResult", "WVResult", "fit_gmwm", "wavelet_variance"),
    "estimators.classical.ieee": ("IEEECoefficients", "ieee_coefficients"),
    "estimators.ml.ml_rate": ("fit_ml_rate",),
    "estimators.engine.fitting": ("MLiResult",),
    "estimators.ml.mli": ("compare_models", "fit_integrated", "fit_mli"),
    "estimators.engine.pattern": ("integrate",),
    "estimators.models.standard": ("StandardModel", "simulate_standard"),
    "estimators.models.noise_models": ("NoiseModel",),
    "estimators.models.sensor_terms": ("BiasInstability", "LowPass"),
    "estimators.selection.model_choice": ("ModelChoice", "choose_model"),
    "estimators.classical.psd": ("PSDResult", "log_average", "welch_psd"),
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
    "GaussMarkovFit",
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
    "BiasInstability",
    "LowPass",
    "ModelChoice",
    "choose_model",
    "StandardModel",
    "simulate_standard",
]


def __getattr__(name: str):
    module = _ORIGIN.get(name)
    if module is None:  # also lets ``from imustation.analysis import reports`` fall through to the subpackage
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # later look-ups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
