"""Allan family against NIST SP 1065 published values, allantools, and closed forms."""

import numpy as np
import pytest
from reference_data import NBS14_10_FREQ, nbs14_1000

from imustation.analysis.estimators.classical.allan import edf_oadev, mdev, oadev, ohdev, totdev
from imustation.errors import InputError

# SP 1065 Table 31 (7 significant figures) at m = 1, 10, 100 (docs/reference/noise-formulas.md §1.1)
NBS14_1000 = {
    oadev: [2.922319e-01, 9.159953e-02, 3.241343e-02],
    mdev: [2.922319e-01, 6.172376e-02, 2.170921e-02],
    ohdev: [2.943883e-01, 9.581083e-02, 3.237638e-02],
    totdev: [2.922319e-01, 9.134743e-02, 3.406530e-02],
}
# Riley test suite Table I / SP 1065, tau = 1, 2 (docs/reference/noise-formulas.md §1.2)
NBS14_10 = {
    oadev: [91.22945, 85.95287],
    mdev: [91.22945, 74.78849],
    ohdev: [70.80607, 85.61487],
    totdev: [91.22945, 93.90379],
}


@pytest.mark.parametrize("fn", list(NBS14_1000), ids=lambda f: f.__name__)
def test_nbs14_1000_point_published(fn):
    res = fn(nbs14_1000(), 1.0, taus=[1, 10, 100])
    np.testing.assert_allclose(res.adev, NBS14_1000[fn], rtol=2e-6)


def test_nbs14_1000_point_high_precision():
    # Danielson 2010 (independent implementation), 10 significant figures
    np.testing.assert_allclose(
        oadev(nbs14_1000(), 1.0, [1, 10, 100]).adev, [0.2922318781, 0.0915995342, 0.0324134303], rtol=5e-9
    )
    np.testing.assert_allclose(
        mdev(nbs14_1000(), 1.0, [1, 10, 100]).adev, [0.2922318781, 0.0617237638, 0.0217092091], rtol=5e-9
    )


@pytest.mark.parametrize("fn", list(NBS14_10), ids=lambda f: f.__name__)
def test_nbs14_10_point_published(fn):
    res = fn(NBS14_10_FREQ, 1.0, taus=[1, 2])
    np.testing.assert_allclose(res.adev, NBS14_10[fn], rtol=1e-6)


@pytest.mark.parametrize("name", ["oadev", "mdev", "ohdev", "totdev"])
def test_matches_allantools(name):
    allantools = pytest.importorskip("allantools")
    rng = np.random.default_rng(5)
    fs = 50.0
    # white + random walk + offset: the mean matters for rounding, the walk for the long taus
    y = 0.3 + rng.normal(0, 1e-2, 60_000) + np.cumsum(rng.normal(0, 1e-5, 60_000))
    taus = np.array([0.02, 0.04, 0.1, 0.34, 1.0, 7.7, 33.0, 150.0, 390.0])
    ours = {"oadev": oadev, "mdev": mdev, "ohdev": ohdev, "totdev": totdev}[name](y, fs, taus)
    t2, dev, _, _ = getattr(allantools, name)(y, rate=fs, data_type="freq", taus=taus)
    np.testing.assert_allclose(ours.tau, t2, rtol=1e-12)
    np.testing.assert_allclose(ours.adev, dev, rtol=1e-9)


def test_integer_counts_match_allantools_and_low_memory_path():
    allantools = pytest.importorskip("allantools")
    rng = np.random.default_rng(6)
    counts = (rng.normal(120, 300, 200_000)).astype(np.int16)
    scale, fs = 6.65e-5, 400.0
    taus = np.array([1, 3, 10, 100, 1000, 20_000, 90_000]) / fs
    exact = oadev(counts, fs, taus, scale=scale)
    streamed = oadev(counts, fs, taus, scale=scale, max_bytes=0)  # running int64 sums from the counts
    np.testing.assert_allclose(streamed.adev, exact.adev, rtol=1e-12)
    _, dev, _, _ = allantools.oadev(counts * scale, rate=fs, data_type="freq", taus=taus)
    np.testing.assert_allclose(exact.adev, dev, rtol=1e-9)


def test_angle_input_equals_rate_input():
    y = nbs14_1000()
    x = np.concatenate([[0.0], np.cumsum(y)]) * 1.0  # x[k] = tau0 * sum y, tau0 = 1 s
    for fn in (oadev, mdev, ohdev, totdev):
        a = fn(y, 1.0, [1, 10, 100])
        b = fn(x, 1.0, [1, 10, 100], data_type="angle")
        np.testing.assert_allclose(b.adev, a.adev, rtol=1e-12)


def naive_pooled_oavar(y, fs, m, segments):
    """Independent oracle: second differences inside each segment only, pooled."""
    s, c = 0.0, 0
    for a, b in segments:
        x = np.concatenate([[0.0], np.cumsum(y[a:b])])
        if len(x) - 2 * m > 0:
            d = x[2 * m :] - 2 * x[m:-m] + x[: -2 * m]
            s += float(np.sum(d * d))
            c += len(d)
    return s / (2.0 * m * m * c)


def test_segments_are_pooled_not_concatenated():
    rng = np.random.default_rng(7)
    y = rng.normal(0, 1, 30_000)
    y[12_000:] += 5.0  # a step at the gap: concatenation would add a spurious term
    segs = [(0, 12_000), (12_000, 30_000)]
    taus = np.array([1, 7, 100, 2000, 5000])
    res = oadev(y, 1.0, taus, segments=segs)
    expect = np.sqrt([naive_pooled_oavar(y, 1.0, int(m), segs) for m in taus])
    np.testing.assert_allclose(res.adev, expect, rtol=1e-11)
    whole = oadev(y, 1.0, taus)
    assert np.all(whole.adev[2:] > 1.1 * res.adev[2:])  # the step shows up only across the gap
    assert res.n[-1] == (12_001 - 10_000) + (18_001 - 10_000)
    with pytest.raises(InputError):
        oadev(y, 1.0, taus, segments=[(0, 10), (5, 20)])


def test_white_noise_closed_form_and_interval():
    # white rate noise of density N: AVAR = N^2 / tau (IEEE 952 C.1); relative sd of the AVAR ~ sqrt(2/edf)
    N, fs = 2e-4, 200.0
    y = np.random.default_rng(3).normal(0.0, N * np.sqrt(fs), 2_000_000)
    res = oadev(y, fs, taus=[0.005, 0.1, 1.0, 10.0])
    ratio = res.adev**2 / (N**2 / res.tau)
    assert np.all(np.abs(ratio - 1) < 4 * np.sqrt(2 / res.edf))
    assert np.all(res.alpha == 0)  # identified as white rate noise
    assert np.all(res.adev_lo < res.adev) and np.all(res.adev < res.adev_hi)


def test_random_walk_discrete_closed_form_over_seeds():
    # discrete RW rate, increments gamma^2, tau0 = 1: AVAR = gamma^2 (2n^2 + 1) / (6n)
    # (docs/reference/noise-formulas.md §5)
    gamma, fs, n = 1e-3, 1.0, 200_000
    m = np.array([1, 4, 30])
    vals = []
    for seed in range(6):
        y = np.cumsum(np.random.default_rng(seed).normal(0, gamma, n))
        vals.append(oadev(y, fs, m / fs).adev ** 2)
    expect = gamma**2 * (2 * m**2 + 1) / (6 * m)
    res = oadev(np.cumsum(np.random.default_rng(0).normal(0, gamma, n)), fs, m / fs)
    assert np.all(res.alpha == -2)
    mean = np.mean(vals, axis=0)
    assert np.all(np.abs(mean / expect - 1) < 3 * np.sqrt(2 / res.edf) / np.sqrt(6))


def test_gauss_markov_discrete_closed_form_over_seeds():
    # AR(1): AVAR = s_e^2 [n - 3phi - n phi^2 + 4 phi^(n+1) - phi^(2n+1)] / [n^2 (1-phi)^2 (1-phi^2)]
    from scipy.signal import lfilter

    phi, s_e, n = np.exp(-1 / 50.0), 1.0, 400_000
    m = np.array([1, 10, 100])
    expect = (
        s_e**2
        * (m - 3 * phi - m * phi**2 + 4 * phi ** (m + 1) - phi ** (2 * m + 1))
        / (m**2 * (1 - phi) ** 2 * (1 - phi**2))
    )
    vals = [
        oadev(lfilter([1], [1, -phi], np.random.default_rng(s).normal(0, s_e, n)), 1.0, m).adev ** 2 for s in range(4)
    ]
    edf = oadev(np.random.default_rng(0).normal(size=n), 1.0, m).edf  # white-noise EDF: optimistic here
    assert np.all(np.abs(np.mean(vals, axis=0) / expect - 1) < 6 * np.sqrt(2 / edf))


def test_edf_matches_allantools_simple_formulas():
    ci = pytest.importorskip("allantools.ci")
    for alpha in (2, 1, 0, -2):
        for m in (1, 5, 40):
            ours = edf_oadev(1001, np.array([m]), np.array([alpha]))[0]
            assert ours == pytest.approx(ci.edf_simple(1001, m, alpha), rel=1e-12)
