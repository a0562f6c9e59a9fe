"""sigma_w when the slow terms reach the fine scales (issue 22, "Filtered devices", "Intervals").

A bias instability that dominates from a few filter memories on (the MPU-9150 of the
datasheet profile) leaves sigma_w resting on how the slow terms continue below the fine
scales, which nothing measures. The Allan variances at k and 2k samples beyond the filter's
memory still bound sigma_w^2 from above with no model of them
(analysis/estimators/ml/finescale.py white_bound), and the stated interval reaches that bound.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from imustation.analysis.estimators.engine.fitting import Z90
from imustation.analysis.estimators.engine.pattern import integrate
from imustation.analysis.estimators.ml.composite import fit_composite_data
from imustation.analysis.estimators.ml.finescale import fine_statistics, octave_avars, white_bound

FS = 200.0
N = 2_000_000


def filtered(seed: int, sigma_w: float = 1e-3, pole: float = 0.5) -> np.ndarray:
    """White rate noise (density sigma_w) through a first-order low-pass of unit DC gain."""
    x = np.random.default_rng(seed).normal(0.0, sigma_w * math.sqrt(FS), N)
    return lfilter([1.0 - pole], [1.0, -pole], x)


def gauss_markov(seed: int, sigma: float, tau_s: float) -> np.ndarray:
    a = math.exp(-1.0 / (FS * tau_s))
    e = np.random.default_rng(seed).normal(0.0, sigma * math.sqrt(1.0 - a * a), N)
    return lfilter([1.0], [1.0, -a], e)


def bound_of(x: np.ndarray, k: int) -> tuple[float, float]:
    got = octave_avars(x, FS, (k, 2 * k)).avar
    return white_bound(x, FS, k, got)


def test_the_bound_is_sigma_w_squared_for_filtered_white_noise_and_white_angle_noise():
    x = filtered(1)
    angle = np.diff(np.random.default_rng(2).normal(0.0, 2e-5, N + 1)) * FS  # white angle noise, 2e-5 rad
    U, se = bound_of(x + angle, 8)
    assert abs(U - 1e-6) <= 3.0 * se and se < 0.01 * U  # exact for both, whatever their size


def test_the_bound_lies_above_sigma_w_squared_when_a_gauss_markov_bias_reaches_the_fine_scales():
    for seed in range(3):
        x = filtered(10 + seed) + gauss_markov(20 + seed, 2e-3, 0.3)
        U, se = bound_of(x, 8)
        assert U - 1e-6 > 5.0 * se  # above, and by much more than its error: a bound, not an estimate


def test_slow_terms_at_the_fine_scales_widen_sigma_w_s_interval_up_to_the_bound():
    x = filtered(3) + gauss_markov(4, 3e-3, 0.25)
    fine = fine_statistics(x, FS)
    assert fine.bound_samples > 0 and math.isfinite(fine.white_bound[0])
    res = fit_composite_data(integrate(x, FS, m=400, pattern="uniform"), fine, "wn+lp", robust=True)
    lo, hi = res.ci90["sigma_w"]
    if fine.slow_share > 0.05:
        top = math.sqrt(fine.white_bound[0] + Z90 * fine.white_bound[1])
        assert hi >= top * (1 - 1e-12) and "sigma_w <=" in res.message
    assert lo <= 1e-3 <= hi  # the wrong model (no bias term) still states an interval holding the truth


def test_a_term_at_its_search_bound_leaves_the_other_intervals_defined():
    x = np.random.default_rng(5).normal(0.0, 1e-3 * math.sqrt(FS), 400_000)
    fine = fine_statistics(x, FS)
    res = fit_composite_data(integrate(x, FS, m=200, pattern="uniform"), fine, "wn+gm+rw", robust=True)
    assert res.at_bound  # white noise has no bias terms: they end at their bounds
    lo, hi = res.ci90["sigma_w"]
    assert 0 < lo < 1e-3 < hi < 1.02e-3
    for name in res.at_bound:  # a one-sided likelihood has no symmetric interval: none is stated
        assert all(math.isnan(v) for v in res.ci90[name])
