"""Attitude-error growth: Kalman-propagated variance vs closed forms and vs simulated data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imustation.analysis.estimators.models.noise_models import GaussMarkov, NoiseModel, RandomWalk, WhiteRate, standard
from imustation.analysis.reports.attitude import angle_error_std, angle_spread

T = np.array([0.1, 1.0, 10.0, 100.0, 1000.0, 1e4])


def test_stationary_gm_closed_form():
    sw, sb, tb = 1e-4, 2e-6, 500.0
    a = T / tb
    # integral of a stationary GM: 2 s^2 tau^2 (a - 1 + e^-a), s^2 = sigma_b^2 tau_b / 2
    expected = sw**2 * T + sb**2 * tb**3 * (a - 1 + np.exp(-a))
    np.testing.assert_allclose(angle_error_std(standard(sw, sb, tb), T) ** 2, expected, rtol=1e-9)


def test_bias_known_and_random_walk_closed_forms():
    sw, sb, tb = 1e-4, 2e-6, 500.0
    a = T / tb
    known = sw**2 * T + sb**2 * tb**2 * (T - 2 * tb * -np.expm1(-a) + tb / 2 * -np.expm1(-2 * a))
    got = angle_error_std(standard(sw, sb, tb), T, bias_known=True) ** 2
    np.testing.assert_allclose(got, known, rtol=1e-6)
    rw = NoiseModel((WhiteRate(sw), RandomWalk(3e-6)))
    np.testing.assert_allclose(angle_error_std(rw, T) ** 2, sw**2 * T + 9e-12 * T**3 / 3, rtol=1e-9)


def test_prediction_matches_simulated_spread():
    fs, sw, sb, tb = 50.0, 1e-4, 2e-5, 60.0
    model = NoiseModel((WhiteRate(sw), GaussMarkov(sb, tb)))
    lags = np.array([1.0, 10.0, 60.0, 200.0])
    ratios = []
    for seed in range(4):
        rate = model.simulate(int(6 * 3600 * fs), fs, seed=seed)
        sp = angle_spread(rate, fs, lags)
        ratios.append(sp.std / angle_error_std(model, sp.t_s))
    # oracle: simulate-then-measure; 4 x 108 independent windows -> std of the ratio ~ 1/sqrt(2*428) = 3.4 %
    mean = np.mean(ratios, axis=0)
    assert sp.windows == 108
    assert np.all(np.abs(mean - 1) < 4 * 1 / math.sqrt(2 * 4 * (sp.windows - 1))), mean


def test_spread_interval_and_errors():
    rng = np.random.default_rng(1)
    sp = angle_spread(rng.normal(size=10000), 10.0, np.array([1.0, 10.0]))
    assert np.all(sp.std_lo < sp.std) and np.all(sp.std < sp.std_hi)
    with pytest.raises(Exception, match="need at least 3"):
        angle_spread(rng.normal(size=100), 10.0, np.array([5.0]))


def test_record_mean_correction_for_slow_bias():
    # tau_b longer than the record: the record-mean bias removal takes part of the bias variance away.
    # Oracle: simulation; tolerance from the ratio's spread over 24 records (windows within a record share
    # the slow bias, so they are not independent).
    fs, L = 10.0, 3600.0
    model = NoiseModel((WhiteRate(1e-4), GaussMarkov(2e-5, 4 * 3600.0)))
    lags = np.array([10.0, 60.0, 200.0])
    ratio, ratio_full = [], []
    for seed in range(24):
        sp = angle_spread(model.simulate(int(L * fs), fs, seed=100 + seed), fs, lags)
        ratio.append(sp.std / angle_error_std(model, sp.t_s, record_s=L))
        ratio_full.append(sp.std / angle_error_std(model, sp.t_s))
    ratio, ratio_full = np.array(ratio), np.array(ratio_full)
    tol = 4 * ratio.std(axis=0, ddof=1) / math.sqrt(len(ratio))
    assert np.all(np.abs(ratio.mean(axis=0) - 1) < tol)
    assert np.all(np.abs(ratio_full.mean(axis=0) - 1) > tol)  # the stationary start over-predicts here
