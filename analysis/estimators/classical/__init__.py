"""Classical statistics of a rate record: no likelihood, closed forms and compiled loops.

The Allan family (:mod:`.allan`, compiled loops in :mod:`._kernels`), PSD (:mod:`.psd`),
IEEE-952 coefficients from an Allan curve (:mod:`.ieee`), AR(p)/Gauss-Markov (:mod:`.ar`), the
covariance of Allan-variance estimates under a model (:mod:`.avar_cov`), and temperature
statistics: bias-vs-temperature regression and warm-up detection (:mod:`.temperature`, used by
the pipeline's verdict, the report and the monitor). Imports only the models wing.
"""
