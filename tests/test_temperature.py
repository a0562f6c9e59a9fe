"""Temperature regression (simulate an injected tempco, fit it back) and warm-up detection."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from imustation.analysis.estimators.classical.temperature import (
    detect_warmup,
    fit_tempco,
    fit_warmup,
    reading_step,
)
from imustation.analysis.pipeline.loaders import device_temperature, device_temperature_record
from imustation.analysis.reports.plots import bias_track
from imustation.errors import InputError


def _warm_temperature(t):
    # chip warm-up: +3 degC with a 900 s time constant, then a slow room drift
    return 25.0 + 3.0 * (1.0 - np.exp(-t / 900.0)) + 0.3 * np.sin(2 * np.pi * t / 21600.0)


def test_tempco_recovered_from_simulation():
    fs, hours, alpha, sigma_w = 10.0, 4.0, 2e-6, 1e-4  # alpha rad/s/K; white rate noise rad/s/sqrt(Hz)
    t = np.arange(int(hours * 3600 * fs)) / fs
    temp = _warm_temperature(t)
    rng = np.random.default_rng(5)
    rate = 1e-3 + alpha * (temp - 25.0) + rng.normal(0, sigma_w * math.sqrt(fs), len(t))
    bt, b = bias_track(rate, fs, 60.0)
    tt = t[::10]  # a 1 Hz thermometer
    res = fit_tempco(bt, b, tt, _warm_temperature(tt))
    # oracle: the injected slope; the OLS standard error is exact for white noise (independent block means)
    expected_se = sigma_w / math.sqrt(60.0) / math.sqrt(np.sum((_warm_temperature(bt) - res.t_mean_c) ** 2))
    assert res.slope_stderr == pytest.approx(expected_se, rel=0.1)
    assert abs(res.slope - alpha) < 4 * res.slope_stderr
    assert res.n == 240 and res.span_c > 2.5
    # white noise: block means independent, the autocorrelation test leaves (almost) all of n
    assert res.n_eff > 0.8 * res.n and res.slope_stderr_eff == pytest.approx(res.slope_stderr, rel=0.15)
    # ten times the coefficient (about 13 standard errors) passes the test
    bt, b = bias_track(rate + 9 * alpha * (temp - 25.0), fs, 60.0)
    strong = fit_tempco(bt, b, tt, _warm_temperature(tt))
    assert strong.significant and strong.p_value < 1e-6


def test_tempco_significance_accounts_for_autocorrelated_bias():
    """A Gauss-Markov bias (tau_b 1 h) and a slow temperature drift, no temperature coefficient at all:
    the OLS t-test "finds" one in most 12 h records (spurious regression, issue 23 saw R^2 0.51 on a
    simulator without a coefficient); the effective-sample-size test in about its nominal 1 %."""
    from scipy.signal import lfilter
    from scipy.stats import t as student_t

    fs, tau_b, sigma_b = 2.0, 3600.0, 2e-6
    t = np.arange(int(12 * 3600 * fs)) / fs
    temp = 25 + 0.8 * np.sin(2 * np.pi * t / (9 * 3600)) + 0.3 * t / 43200
    phi = math.exp(-1 / fs / tau_b)
    ols = corrected = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        bias = lfilter([1], [1, -phi], rng.normal(0, sigma_b * math.sqrt(tau_b / 2 * (1 - phi**2)), len(t)))
        bt, b = bias_track(bias + rng.normal(0, 1e-4 * math.sqrt(fs), len(t)), fs, 60.0)
        res = fit_tempco(bt, b, t[::2], temp[::2])
        ols += 2 * student_t.sf(abs(res.slope) / res.slope_stderr, res.n - 2) < 0.01
        corrected += res.significant
        assert res.n_eff < 0.3 * res.n and res.slope_stderr_eff > res.slope_stderr
    assert ols >= 15 and corrected <= 2, (ols, corrected)


def test_tempco_refuses_constant_temperature():
    with pytest.raises(InputError, match="temperature spans 0 K"):
        fit_tempco(np.arange(10.0), np.ones(10), np.array([0.0, 20.0]), np.array([25.0, 25.0]))
    with pytest.raises(InputError, match="spans 0.1 K"):  # below the default 0.125 K
        fit_tempco(np.arange(10.0), np.ones(10), np.array([0.0, 9.0]), np.array([25.0, 25.1]))


def test_warmup_detection():
    t = np.arange(0.0, 4 * 3600.0, 1.0)
    # closed form: dT/dt = (3/900) e^{-t/900} + 0.3 (2 pi/21600) cos(2 pi t/21600) degC/s; the last time it
    # exceeds 1 degC/h (~2580 s); a 600 s window centred there starts 300 s earlier (+- one 300 s step)
    rate_h = 3600 * (3.0 / 900 * np.exp(-t / 900) + 0.3 * 2 * np.pi / 21600 * np.cos(2 * np.pi * t / 21600))
    settle = t[np.nonzero(np.abs(rate_h) > 1.0)[0][-1]]
    assert 2400 < settle < 2700
    end = detect_warmup(t, _warm_temperature(t), window_s=600.0, max_rate_c_per_h=1.0)
    assert settle - 600 <= end <= settle + 300
    assert detect_warmup(t, np.full_like(t, 25.0)) == 0.0
    # a steady 6 degC/h drift has no transient to cut up to: nothing settles, nothing is cut
    drift = fit_warmup(t, 25 + t / 600.0)
    assert drift.state == "unsettled" and drift.cut_s == 0.0 and drift.drift_c_per_h == pytest.approx(6.0)
    assert drift.describe().startswith("temperature still changing at the end (+24 K")
    # the first 10 minutes of a 4 K, 15 min warm-up: no transient to tell from a drift, but far from settled
    first = fit_warmup(t[:600], 25 + 4 * (1 - np.exp(-t[:600] / 900.0)), step_c=1 / 340)
    assert first.state == "unsettled" and first.cut_s == 0.0
    # a 0.5 degC/h drift is settled by the limit: no warm-up
    assert fit_warmup(t, 25 + t / 7200.0).state == "none"
    # a real warm-up cut off before it settles: still warming, nothing settled to keep
    early = fit_warmup(t[:1800], _warm_temperature(t[:1800]))
    assert early.state == "unsettled" and early.end_s == t[1799] and early.cut_s == 0.0


def test_one_quantisation_step_is_not_a_warmup():
    # configs/demo.toml, 1.5 h: the die reads a flat 30.0 degC, then 30.5 from one step on (0.5 K LSB);
    # the old fit read a transient 'until 824 s' into it and report cut 13 min that analyze kept
    t = np.arange(0.5, 5400.0, 1.0)
    for at in (100.0, 600.0, 1800.0, 4000.0):
        temp = np.where(t < at, 30.0, 30.5)
        temp[np.searchsorted(t, at)] = 30.05  # a 1 s block mean straddling the step
        fit = fit_warmup(t, temp, step_c=0.5)
        assert fit.state == "none" and fit.cut_s == 0.0, (at, fit)
        assert fit_warmup(t, temp).state == "none", at  # the step estimated from these block means


def test_a_record_too_short_is_unknown_not_warming_until_its_end():
    # 12 s: the old fit solved a 1-block least-squares problem (level 0.96 degC, drift 19000 degC/h)
    # and called the whole record warm-up ('until 12 s')
    t = np.arange(0.5, 12.0, 1.0)
    for temp in (np.full_like(t, 30.0), 30.0 + 0.01 * t):
        fit = fit_warmup(t, temp)
        assert fit.state == "unknown" and math.isnan(fit.end_s) and fit.cut_s == 0.0
        assert "too short" in fit.describe()
        assert math.isnan(detect_warmup(t, temp))


def test_room_drift_against_a_fine_thermometer_is_not_a_warmup():
    # the 3 h lab (configs/lab-example.toml): a die at 30 degC following a slow room swing of 0.5 K,
    # read in 1/340 K steps; the old fit's transient (2.5 K, tau 5370 s) and drift (-0.68 K/h)
    # cancelled and it reported 'warm-up transient until 22 s' on every MPU and MTi channel
    t = np.arange(0.5, 3 * 3600.0, 1.0)
    rng = np.random.default_rng(3)
    true = 30.0 + 0.5 * np.sin(np.pi * t / 10800.0) ** 2
    temp = np.round((true + rng.normal(0, 0.002, len(t))) * 340.0) / 340.0
    fit = fit_warmup(t, temp, step_c=1 / 340)
    assert fit.state == "none" and fit.cut_s == 0.0, fit
    # the same room with a real 4 K, 15 min warm-up on top is found, many steps of change
    warm = fit_warmup(t, temp - 4.0 * np.exp(-t / 900.0), step_c=1 / 340)
    assert warm.state == "transient" and 2000 < warm.cut_s < 3200 and warm.change_c > 3.5
    assert re.fullmatch(r"warm-up 4 K until \d+ s", warm.describe())


def test_reading_step_from_the_data():
    assert reading_step(np.array([30.0, 30.0, 30.5, 30.5, 30.0, 31.0])) == 0.5
    assert reading_step(np.full(5, 25.0)) == 0.0


def _quantised(temp, step=0.5):
    return np.round(temp / step) * step


@pytest.mark.parametrize("seed", range(5))
def test_quantised_flat_temperature_is_no_warmup(seed):
    # a die thermometer of 0.5 K resolution in a stable room: the reading toggles between steps
    t = np.arange(0.0, 12 * 3600.0, 1.0)
    rng = np.random.default_rng(seed)
    temp = _quantised(25.2 + 0.05 * np.sin(2 * np.pi * t / 21600) + rng.normal(0, 0.15, len(t)))
    assert detect_warmup(t, temp) == 0.0
    # nor is one step of a slow room drift crossing a quantisation level, without any noise
    assert detect_warmup(t, _quantised(25.1 + 0.8 * t / t[-1])) == 0.0


@pytest.mark.parametrize("seed", range(3))
def test_quantised_exponential_warmup_is_found_near_the_truth(seed):
    t = np.arange(0.0, 12 * 3600.0, 1.0)
    rng = np.random.default_rng(seed)
    amp, tau, limit = 5.0, 900.0, 1.0  # K, s, K/h
    temp = _quantised(30.0 - amp * np.exp(-t / tau) + rng.normal(0, 0.1, len(t)))
    truth = tau * math.log(amp * 3600.0 / (tau * limit))  # where the transient slows below the limit: 2696 s
    fit = fit_warmup(t, temp, max_rate_c_per_h=limit)
    assert fit.end_s == pytest.approx(truth, rel=0.1)
    assert fit.amplitude_c == pytest.approx(-amp, rel=0.1) and fit.tau_s == pytest.approx(tau, rel=0.2)


def test_device_temperature_from_run(sim_run):
    path, _ = sim_run
    rec = device_temperature_record(str(path), "bmx055")
    t, c = device_temperature(str(path), "bmx055")
    # the raw readings' step (BMX055: 0.5 K LSB), not the block means' (which may be constant)
    assert rec.step_c in (0.0, 0.5) and rec.step_c >= reading_step(c)
    assert len(t) == pytest.approx(1200, abs=2) and np.all(np.diff(t) > 0)
    assert 10.0 < np.median(c) < 50.0
    with pytest.raises(InputError, match="no temperature channel"):
        device_temperature(str(path), "nope")


def test_holm_and_the_listed_coefficients():
    from imustation.analysis.estimators.classical.temperature import TempcoResult, holm
    from imustation.analysis.reports.tables import TempcoRow, tempco_csv, tempco_markdown

    # step-down: 0.005 <= 0.05/4, 0.01 <= 0.05/3, then 0.03 > 0.05/2 stops
    assert holm(np.array([0.01, 0.04, 0.03, 0.005]), 0.05).tolist() == [True, False, False, True]
    assert holm(np.array([1e-4, 0.5, np.nan]), 0.05).tolist() == [True, False, False]
    tc = TempcoResult(2e-6, 1e-7, 0.0, 25.0, 3.0, 0.9, 100, 0.99, 0.5, 40.0, 2e-7, 1e-9, True)
    rows = [
        TempcoRow("imu/gyro/x", "gyro", "internal", tc, listed=True),
        TempcoRow("imu/gyro/y", "gyro", "internal", tc, listed=False),
        TempcoRow("imu/gyro/z", "gyro", "internal", None, "temperature spans 0 K"),
    ]
    md = tempco_markdown(rows)
    assert "imu/gyro/x" in md and "imu/gyro/y" not in md and "°/h/K" in md
    assert md.count("\n") == 3  # header, rule, one row
    assert len(tempco_csv(rows).splitlines()) == 4  # every coefficient in the CSV
