"""The likelihood engine the model fits share: parameters in, likelihood and intervals out.

Parameter layout and bounds (:mod:`.paramspec`), the exact likelihood, optimiser driver,
intervals and result type :class:`~.fitting.MLiResult` (:mod:`.fitting`), the Newton iteration
(:mod:`.newton`), misfit-robust sandwich intervals (:mod:`.robust`), the compiled Kalman filter
(:mod:`.kalman`), the prefix-scan filter of the fast path (:mod:`.scan`) and the integrated-signal
sampling pattern (:mod:`.pattern`). Imports only the models wing.
"""
