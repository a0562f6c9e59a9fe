"""Estimators: sample arrays in (SI units or integer counts with a scale), plain dataclasses out.

Allan family (:mod:`.allan`), PSD (:mod:`.psd`), IEEE-952 coefficients (:mod:`.ieee`),
AR(p)/Gauss-Markov (:mod:`.ar`), the rate noise-model library (:mod:`.noise_models`,
:mod:`.models` with the paper's standard model, :mod:`.reference` values), and the
noise-model fits: ML_i (:mod:`.mli`), ML_i-F (:mod:`.composite`), classical ML on the rates
(:mod:`.ml_rate`) and GMWM (:mod:`.gmwm`), which share the fitting engine of :mod:`.fitting`,
the integrated-signal pattern of :mod:`.pattern`, the parameter layout of :mod:`.paramspec`,
the scan filter of :mod:`.scan` and the compiled Kalman filter of :mod:`.kalman`. Model
adequacy: the covariance of Allan-variance estimates across tau under a model
(:mod:`.avar_cov`) and the goodness-of-fit test on it (:mod:`.adequacy`); :mod:`.screen`
names channels with nothing to characterise. Real sensors: bias instability and
device-filter terms (:mod:`.sensor_terms`), the filter-aware fine-scale statistics
(:mod:`.finescale`), misfit-robust intervals (:mod:`.robust`) and the automatic model
choice (:mod:`.model_choice`).

Nothing here reads files, plots or imports :mod:`imustation.analysis.reports` or
:mod:`imustation.analysis.pipeline` (an import-linter contract). This ``__init__`` imports
nothing, so the chip simulators can load :mod:`.models` alone.
"""
