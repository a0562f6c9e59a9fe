"""Allan deviation against published values and allantools; ML_i against the simulator."""

import numpy as np
import pytest
from reference_data import nbs14_1000

from imustation.analysis import StandardModel, fit_mli, oadev, simulate_standard
from imustation.analysis.estimators.engine.fitting import full_nll
from imustation.analysis.estimators.engine.pattern import integrate_pattern, sampling_pattern
from imustation.analysis.estimators.engine.scan import standard_profile
from imustation.analysis.pipeline.loaders import load_inputs


def test_nbs14_generator_check_values():
    n = (nbs14_1000() * 2147483647).round().astype(np.int64)
    assert n[1:4].tolist() == [395529916, 1209410747, 633705974]


def test_oadev_nbs14_published():
    res = oadev(nbs14_1000(), 1.0, taus=[1, 10, 100])
    # SP 1065 Table 31, OADEV row (higher-precision values of Danielson 2010)
    np.testing.assert_allclose(res.adev, [0.2922318781, 0.0915995342, 0.0324134303], rtol=5e-9)


def test_oadev_nbs14_10_point():
    y = np.array([892, 809, 823, 798, 671, 644, 883, 903, 677], dtype=float)
    res = oadev(y, 1.0, taus=[1, 2])
    np.testing.assert_allclose(res.adev, [91.22945, 85.95287], rtol=1e-6)


def test_oadev_matches_allantools():
    allantools = pytest.importorskip("allantools")
    y = simulate_standard(StandardModel(1e-4, 1e-5, 50.0, 0.02), 200_000, 100.0, 1)
    taus = np.array([0.01, 0.05, 0.3, 1.0, 7.0, 33.0, 200.0, 900.0])
    ours = oadev(y, 100.0, taus)
    t2, ad, _, _ = allantools.oadev(y, rate=100.0, data_type="freq", taus=taus)
    np.testing.assert_allclose(ours.tau, t2, rtol=1e-12)
    np.testing.assert_allclose(ours.adev, ad, rtol=1e-9)


def test_oadev_counts_equal_floats():
    rng = np.random.default_rng(2)
    counts = rng.integers(-3000, 3000, 100_000).astype(np.int16)
    scale = 6.65e-5
    a = oadev(counts, 400.0, scale=scale)
    b = oadev(counts.astype(float) * scale, 400.0)
    np.testing.assert_allclose(a.adev, b.adev, rtol=1e-9)


def test_oadev_white_noise_closed_form():
    # white rate noise of density N: ADEV = N / sqrt(tau) (IEEE 952 C.1)
    N, fs = 2e-4, 200.0
    y = np.random.default_rng(3).normal(0.0, N * np.sqrt(fs), 2_000_000)
    res = oadev(y, fs, taus=[0.1, 1.0, 10.0])
    np.testing.assert_allclose(res.adev, N / np.sqrt(res.tau), rtol=0.03)
    assert np.all(res.adev_lo < res.adev) and np.all(res.adev < res.adev_hi)


def test_scan_filter_equals_textbook_kalman_filter():
    """The reduced scan filter gives the textbook KF likelihood (large-prior b_on limit)."""
    from scipy.linalg import expm

    fs = 100.0
    x = simulate_standard(StandardModel(1e-4, 5e-6, 40.0, 0.003), 20_000, fs, 5)
    pts = sampling_pattern(len(x), 50, "log")
    y = integrate_pattern(x, fs, pts)
    dt = np.diff(pts) / fs
    sw, sb, tau = 1.2e-4, 4e-6, 30.0
    # textbook filter on the absolute angle with state (b, b_on, angle)
    F = np.array([[-1 / tau, 0, 0], [0, 0, 0], [1, 1, 0]])
    GQG = np.diag([sb**2, 0.0, sw**2])
    big = 1e4
    xs = np.zeros(3)
    P = np.diag([sb**2 * tau / 2, big, 0.0])
    angle = np.concatenate([[0.0], np.cumsum(y)])
    nll = 0.0
    for i, d in enumerate(dt):
        M = np.zeros((6, 6))
        M[:3, :3] = -F
        M[:3, 3:] = GQG
        M[3:, 3:] = F.T
        E = expm(M * d)  # Van Loan (eq. 21)
        Phi = E[3:, 3:].T
        Qd = Phi @ E[:3, 3:]
        xs = Phi @ xs
        P = Phi @ P @ Phi.T + Qd
        B = P[2, 2]
        nu = angle[i + 1] - xs[2]
        nll += 0.5 * (np.log(2 * np.pi * B) + nu * nu / B)
        K = P[:, 2] / B
        xs = xs + K * nu
        P = P - np.outer(K, K) * B
    # diffuse limit (de Jong 1991): the large-prior likelihood exceeds the diffuse one
    # by the prior's normalising term 0.5 log(2 pi big)
    prof = standard_profile(y, dt, np.array([sb**2 / sw**2]), np.array([tau]))
    ours = full_nll(prof, np.array([sw**2]))[0]
    assert nll - 0.5 * np.log(2 * np.pi * big) == pytest.approx(ours, abs=1e-4)


def test_fit_mli_recovers_sigma_w_within_3_percent():
    """Mean over 4 seeds of 4 h records (ML_i sigma_w spread ~2 % per record -> ~1 % for the mean)."""
    truth = StandardModel(1.05e-4, 1.26e-6, 530.5, 0.01)
    fs = 400.0
    fits = [fit_mli(simulate_standard(truth, int(4 * 3600 * fs), fs, seed), fs) for seed in range(4)]
    errors = np.array([f.sigma_w / truth.sigma_w - 1 for f in fits])
    assert abs(errors.mean()) < 0.03, errors
    for f in fits:  # each within 4 of its own standard errors
        assert abs(f.sigma_w - truth.sigma_w) < 4 * f.stderr["sigma_w"]
        assert f.converged
        assert f.b_on == pytest.approx(0.01, abs=5e-4)


def test_fit_mli_counts_path_equals_float_path():
    truth = StandardModel(1e-4, 1e-6, 500.0, 0.01)
    scale = 6.65e-5
    x = simulate_standard(truth, 400_000, 400.0, 9)
    counts = np.rint(x / scale).astype(np.int16)
    a = fit_mli(counts, 400.0, scale=scale)
    b = fit_mli(counts.astype(float) * scale, 400.0)
    assert a.sigma_w == pytest.approx(b.sigma_w, rel=1e-6)


def test_sampling_pattern_shapes():
    p = sampling_pattern(17_280_000, 1000, "log")
    assert p[0] == 0 and p[-1] == 17_280_000 and len(p) == 1001
    assert np.all(np.diff(p) >= 1)
    u = sampling_pattern(10_000, 100, "uniform")
    assert np.all(np.diff(u) == 100)


def test_csv_and_npy_loaders(tmp_path):
    data = np.random.default_rng(0).normal(size=(500, 2))
    np.save(tmp_path / "imu.npy", data)
    np.savetxt(tmp_path / "imu.csv", data, delimiter=",", header="gx,gy", comments="")
    a = load_inputs([str(tmp_path / "imu.npy")], fs_hz=100.0)
    b = load_inputs([str(tmp_path / "imu.csv")], fs_hz=100.0)
    assert [c.id for c in a] == ["imu/0", "imu/1"] == [c.id for c in b]
    np.testing.assert_allclose(a[1].data, b[1].data, rtol=1e-12)
