"""Estimators: sample arrays in (SI units or integer counts with a scale), plain dataclasses out.

Five wings, each importing only the ones below it (an import-linter ``layers`` contract):

* :mod:`.selection` -- model-choice policy: adequacy, automatic choice, coefficients, screen;
* :mod:`.ml` -- the noise-model fits: ML_i, ML_i-F, ML on rates, GMWM;
* :mod:`.engine` -- the likelihood engine they share (parameters, filters, optimiser, intervals)
  and :mod:`.classical` -- Allan family, PSD, IEEE-952, AR, Allan covariance, temperature
  statistics; the two are independent of each other;
* :mod:`.models` -- the noise models themselves, the only wing ``drivers/sim`` may import.

Nothing here reads files, plots or imports :mod:`imustation.analysis.reports` or
:mod:`imustation.analysis.pipeline` (an import-linter contract). No ``__init__`` here imports
anything, so the chip simulators can load :mod:`.models.standard` alone.
"""
