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
"""

from imustation.analysis.allan import AllanResult, mdev, oadev, ohdev, totdev
from imustation.analysis.ar import ARResult, GaussMarkov, fit_ar, gauss_markov_from_ar1
from imustation.analysis.gmwm import GMWMResult, WVResult, fit_gmwm, wavelet_variance
from imustation.analysis.ieee import IEEECoefficients, ieee_coefficients
from imustation.analysis.ml_rate import fit_ml_rate
from imustation.analysis.mli import MLiResult, compare_models, fit_integrated, fit_mli, integrate
from imustation.analysis.models import StandardModel, simulate_standard
from imustation.analysis.noise_models import NoiseModel
from imustation.analysis.psd import PSDResult, log_average, welch_psd

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
