"""PSD normalisation (white level, sine power), log-frequency averaging; AR/SBC and Gauss-Markov recovery."""

import numpy as np
import pytest
from scipy.signal import lfilter, welch

from imustation.analysis import fit_ar, gauss_markov_from_ar1, log_average, welch_psd
from imustation.errors import InputError


def test_white_noise_level_one_and_two_sided():
    # white rate noise of ARW coefficient N: two-sided S = N^2, one-sided G = 2 N^2
    # (IEEE 952; docs/reference/noise-formulas.md §5)
    N, fs = 3e-4, 100.0
    y = np.random.default_rng(1).normal(0, N * np.sqrt(fs), 400_000)
    one = welch_psd(y, fs, nperseg=1024)
    two = welch_psd(y, fs, nperseg=1024, sides="two")
    # each bin averages ~780 windows (50 % overlap): relative sd ~ 1/sqrt(windows); the mean over bins is tight
    assert np.mean(one.psd[1:-1]) == pytest.approx(2 * N**2, rel=0.01)
    assert np.mean(two.psd[1:-1]) == pytest.approx(N**2, rel=0.01)
    np.testing.assert_allclose(two.psd[1:-1], one.psd[1:-1] / 2, rtol=1e-12)
    assert one.sides == "one" and two.sides == "two"


def test_sine_power_and_parseval():
    # a sine of amplitude A carries power A^2/2: the integral of G over its peak (scipy TestWelch oracle)
    fs, A, f0 = 200.0, 0.02, 12.5
    t = np.arange(200_000) / fs
    y = A * np.sin(2 * np.pi * f0 * t) + np.random.default_rng(2).normal(0, 1e-4, len(t))
    res = welch_psd(y, fs, nperseg=4096)
    df = res.f[1] - res.f[0]
    peak = np.abs(res.f - f0) < 5 * df
    assert np.sum(res.psd[peak]) * df == pytest.approx(A**2 / 2, rel=1e-3)
    assert np.sum(res.psd) * df == pytest.approx(np.var(y), rel=2e-3)  # Parseval, one-sided


def test_blockwise_equals_scipy_welch_and_counts_equal_floats():
    rng = np.random.default_rng(3)
    counts = rng.integers(-2000, 2000, 50_000).astype(np.int16)
    scale = 1e-4
    ref_f, ref_p = welch(counts * scale, fs=400.0, nperseg=512, noverlap=256)
    res = welch_psd(counts, 400.0, scale=scale, nperseg=512, block_windows=3)
    np.testing.assert_allclose(res.f, ref_f)
    np.testing.assert_allclose(res.psd, ref_p, rtol=1e-10)
    assert res.windows == (50_000 - 512) // 256 + 1


def test_segments_never_straddle_gaps():
    rng = np.random.default_rng(4)
    y = rng.normal(0, 1, 20_000)
    y[10_000:] += 100.0  # a step at the gap would put a huge 1/f^2 leakage into windows crossing it
    res = welch_psd(y, 1.0, nperseg=1000, segments=[(0, 10_000), (10_000, 20_000)])
    assert res.windows == 2 * 19
    assert np.mean(res.psd[1:]) == pytest.approx(2.0, rel=0.05)
    with pytest.raises(InputError):
        welch_psd(y, 1.0, nperseg=30_000)


def test_log_average_keeps_level_and_counts_bins():
    y = np.random.default_rng(5).normal(0, 1, 300_000)
    res = welch_psd(y, 10.0, nperseg=8192)
    avg = log_average(res, per_decade=10)
    assert avg.bins.sum() == len(res.f) - 1  # DC dropped, every other bin used once
    assert np.all(np.diff(avg.f) > 0)
    # white level 2 sigma^2 / fs = 0.2; scatter of a band mean ~ 1/sqrt(windows * bins)
    tol = 5 / np.sqrt(res.windows * avg.bins)
    assert np.all(np.abs(avg.psd / 0.2 - 1) < tol + 0.02)


def test_ar1_recovery_and_sbc_order():
    rng = np.random.default_rng(6)
    phi, n = 0.9, 200_000
    x = lfilter([1], [1, -phi], rng.normal(0, 0.5, n)) + 3.0
    ar = fit_ar(x, max_order=6)
    assert ar.order == 1
    assert abs(ar.phi[0] - phi) < 4 * ar.phi_stderr[0]
    assert ar.sigma2 == pytest.approx(0.25, rel=0.02)  # sd of a variance estimate ~ sqrt(2/n)
    assert ar.intercept / (1 - ar.phi[0]) == pytest.approx(3.0, abs=0.1)
    x2 = lfilter([1], [1, -0.5, 0.3], rng.normal(0, 1, n))
    assert fit_ar(x2, max_order=6).order == 2


def test_gauss_markov_from_ar1():
    # x_k = e^{-beta dt} x_{k-1} + w_k with beta = 0.5 1/s at 100 Hz (Zhao et al. eqs. 10-13)
    fs, beta, sigma = 100.0, 0.5, 2.0
    phi = np.exp(-beta / fs)
    n = 2_000_000
    w = np.random.default_rng(7).normal(0, sigma * np.sqrt(1 - phi**2), n)
    gm = gauss_markov_from_ar1(fit_ar(lfilter([1], [1, -phi], w), order=1), fs)
    assert abs(gm.beta - beta) < 4 * gm.beta_stderr
    assert gm.T == pytest.approx(1 / gm.beta)
    # the stationary sd of a GM record of length L has relative scatter ~ sqrt(1/(beta L)) (Nassar 2005)
    assert gm.sigma == pytest.approx(sigma, rel=3 / np.sqrt(beta * n / fs))
    with pytest.raises(InputError):
        gauss_markov_from_ar1(fit_ar(w, order=2), fs)
