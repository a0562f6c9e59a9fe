"""Maximum-likelihood and moment estimators of a noise model, built on the engine.

ML_i on the integrated signal (:mod:`.mli`), ML_i-F, its composite likelihood with the
fine-scale Allan variance (:mod:`.composite`, statistics in :mod:`.finescale`), classical ML on
the rates (:mod:`.ml_rate`) and GMWM (:mod:`.gmwm`). Each returns an
:class:`~imustation.analysis.estimators.engine.fitting.MLiResult`-shaped dataclass. Imports the
engine, classical and models wings.
"""
