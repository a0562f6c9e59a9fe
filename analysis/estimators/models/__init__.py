"""Noise models: what a sensor's noise is, with no estimation in it.

The term library and model names (:mod:`.noise_models`: PSD, Allan variance, discretisation of
each term), the paper's standard model and its simulator (:mod:`.standard`), real-sensor terms
(bias instability, device filters: :mod:`.sensor_terms`) and published parameter sets
(:mod:`.reference`). The only wing the chip simulators (``drivers/sim``) may import; it imports
no other wing. This ``__init__`` imports nothing, so a simulator loads one module alone.
"""
