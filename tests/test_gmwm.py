"""GMWM: Haar wavelet variance, model WV, the estimator, CLI and study column.

Oracles: a direct MODWT Haar computation (the definition of docs/reference/noise-formulas.md §4,
written with cumulative sums here) and the identity nu^2 = AVAR(m = tau/2)/2
against :func:`oadev`; the closed-form WV table of §4 (written out here, per-sample
parameters) for each process; simulate-then-fit with the §4 tolerances or, where
the parameter is weakly identified, a multiple of the fit's own standard error.
"""

from __future__ import annotations

import json
import math
from decimal import Decimal, getcontext

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.analysis.estimators.classical.allan import oadev
from imustation.analysis.estimators.ml.gmwm import GMWMResult, fit_gmwm, model_wv, wavelet_variance
from imustation.analysis.estimators.ml.mli import fit_mli
from imustation.analysis.estimators.models.noise_models import (
    GaussMarkov,
    NoiseModel,
    RandomWalk,
    RateRamp,
    WhiteAngle,
    WhiteRate,
    standard,
)
from imustation.analysis.pipeline.study import run_study
from imustation.cli import cli
from imustation.errors import InputError

FS = 100.0


def modwt_haar_wv(x: np.ndarray, j: int) -> float:
    """nu_hat^2(tau_j) from the definition: W_t = (sum of the newer half - older half)/tau_j, t >= tau_j - 1."""
    tau = 2**j
    h = tau // 2
    c = np.concatenate([[0.0], np.cumsum(x)])
    t = np.arange(tau - 1, len(x))
    newer = c[t + 1] - c[t + 1 - h]
    older = c[t + 1 - h] - c[t + 1 - tau]
    w = (newer - older) / tau
    return float(np.mean(w * w))


def test_wv_equals_modwt_definition_and_half_oavar():
    x = np.random.default_rng(3).normal(0.2, 1.0, 5000).cumsum() * 1e-2 + np.random.default_rng(4).normal(size=5000)
    wv = wavelet_variance(x, FS)
    assert wv.level[-1] == 12 and np.array_equal(wv.scale, 2**wv.level)
    direct = np.array([modwt_haar_wv(x, j) for j in wv.level])
    np.testing.assert_allclose(wv.wv, direct, rtol=1e-9)
    av = oadev(x, FS, (2 ** (wv.level - 1)) / FS)
    np.testing.assert_allclose(wv.wv, 0.5 * av.adev**2, rtol=1e-14)
    np.testing.assert_array_equal(wv.n, len(x) - wv.scale + 1)
    np.testing.assert_allclose(wv.edf, np.maximum(wv.n / wv.scale, 1.0))
    assert np.all(wv.wv_lo < wv.wv) and np.all(wv.wv < wv.wv_hi)


def test_wv_interval_covers_white_noise_truth():
    # 95 % chi-square intervals: over 20 records x 10 levels the truth sigma^2/tau lies inside
    # with frequency near 0.95 (binomial sd ~ 1.5 %; accept 0.88..0.995)
    hits = []
    for s in range(20):
        x = np.random.default_rng(s).normal(0.0, 2.0, 4096)
        wv = wavelet_variance(x, FS)
        truth = 4.0 / wv.scale
        keep = wv.level <= 10
        hits += list(((wv.wv_lo <= truth) & (truth <= wv.wv_hi))[keep])
    assert 0.88 <= np.mean(hits) <= 0.995


def test_wv_with_gap_never_spans_it():
    x = np.random.default_rng(1).normal(size=3000)
    x[1000:1500] = 1e6  # garbage inside the gap
    wv = wavelet_variance(x, FS, segments=[(0, 1000), (1500, 3000)])
    j = 3
    c1 = modwt_haar_wv(x[:1000], j) * (1000 - 8 + 1)
    c2 = modwt_haar_wv(x[1500:], j) * (1500 - 8 + 1)
    assert wv.n[j - 1] == (1000 - 8 + 1) + (1500 - 8 + 1)
    assert wv.wv[j - 1] == pytest.approx((c1 + c2) / wv.n[j - 1], rel=1e-9)


# ---------------------------------------------------------------------------
# model WV against the closed forms of docs/reference/noise-formulas.md §4 (tau in samples)


TAUS = 2.0 ** np.arange(1, 21)


def test_model_wv_matches_section4_table():
    dt = 1.0 / FS
    s2 = 2.5e-3  # white: per-sample variance sigma^2 = sigma_w^2/dt
    wn = model_wv(NoiseModel((WhiteRate(math.sqrt(s2 * dt)),)), TAUS, FS)
    np.testing.assert_allclose(wn, s2 / TAUS, rtol=1e-10)
    g2 = 3e-7  # random walk: per-sample innovation variance gamma^2 = sigma_k^2 dt
    rw = model_wv(NoiseModel((RandomWalk(math.sqrt(g2 / dt)),)), TAUS, FS)
    np.testing.assert_allclose(rw, g2 * (TAUS**2 + 2) / (12 * TAUS), rtol=1e-10)
    omega = 4e-6  # drift per sample
    dr = model_wv(NoiseModel((RateRamp(omega / dt),)), TAUS, FS)
    np.testing.assert_allclose(dr, omega**2 * TAUS**2 / 16, rtol=1e-10)
    Q2 = 7e-3  # quantisation: X_t = difference of iid angle-like noise of variance Q^2 (per-sample units)
    qn = model_wv(NoiseModel((WhiteAngle(math.sqrt(Q2) * dt),)), TAUS, FS)
    np.testing.assert_allclose(qn, 6 * Q2 / TAUS**2, rtol=1e-10)
    for T in (0.05, 3.0, 400.0):  # AR(1) with simts' GM convention: phi = e^{-dt/T}
        sigma_b = 2e-3
        ar1 = model_wv(NoiseModel((GaussMarkov(sigma_b, T),)), TAUS, FS)
        np.testing.assert_allclose(ar1, ar1_wv_closed_form(sigma_b**2 * T / 2, dt / T), rtol=1e-10)


def ar1_wv_closed_form(var_gm: float, d: float) -> np.ndarray:
    """The §4 AR1 row in 50-digit decimal arithmetic (its numerator cancels like (1 - phi)^3 in float)."""
    getcontext().prec = 50
    phi = (-Decimal(d)).exp()
    s2e = Decimal(var_gm) * (1 - phi * phi)  # innovation variance from the stationary one
    out = []
    for tau in TAUS.astype(int).tolist():
        h = Decimal(tau // 2)
        num = h - 3 * phi - h * phi**2 + 4 * phi ** (tau // 2 + 1) - phi ** (tau + 1)
        out.append(float(s2e * num / (2 * h**2 * (1 - phi) ** 2 * (1 - phi**2))))
    return np.array(out)


# ---------------------------------------------------------------------------
# the estimator


def test_recovers_wn_rw_ar1_long_record():
    truth = NoiseModel((WhiteRate(1e-3), GaussMarkov(1e-3, 20.0), RandomWalk(1e-4)))
    x = truth.simulate(2_000_000, FS, 0)
    r = fit_gmwm(x, FS, "wn+gm+rw")
    assert r.converged, r.message
    assert r.estimator == "GMWM" and r.model == "wn+gm+rw"
    assert r.sigma_w == pytest.approx(1e-3, rel=0.05)  # §4: WN within ~5 %
    assert r.sigma_b**2 == pytest.approx(1e-6, rel=0.2)  # AR1 sigma^2 within ~20 %
    phi_hat, phi = math.exp(-1 / (FS * r.tau_b)), math.exp(-1 / (FS * 20.0))
    assert phi_hat == pytest.approx(phi, rel=0.01)  # §4: phi to ~1 %
    assert abs(math.log(r.tau_b / 20.0)) < 3 * r.stderr["tau_b"] / r.tau_b
    # the random walk is weakly identified in 5.6 h (stderr ~14 %): within 3 standard errors
    sk = r.params["sigma_k"]
    assert abs(math.log(sk / 1e-4)) < 3 * r.stderr["sigma_k"] / sk
    assert r.ci90["sigma_k"][0] < sk < r.ci90["sigma_k"][1]


def test_recovers_standard_model_and_matches_mli_keys():
    truth = standard(1e-3, 1e-3, 20.0, b_on=0.01)
    x = truth.simulate(1_000_000, FS, 5)
    r = fit_gmwm(x, FS)
    assert isinstance(r, GMWMResult) and r.converged
    for name, true in (("sigma_w", 1e-3), ("sigma_b", 1e-3), ("tau_b", 20.0)):
        est = getattr(r, name)
        assert abs(math.log(est / true)) < 4 * r.stderr[name] / est, name
    assert r.b_on == pytest.approx(np.mean(x))
    m = fit_mli(x, FS)
    assert r.as_dict().keys() == m.as_dict().keys()
    assert r.stderr.keys() == m.stderr.keys() and r.ci90.keys() == m.ci90.keys()
    # the fitted model's WV is the model WV of the returned noise model
    np.testing.assert_allclose(r.wv_model, model_wv(r.noise_model, r.wv.scale, FS), rtol=1e-9)


def test_two_gm_terms_ordered_by_tau():
    truth = NoiseModel((WhiteRate(1e-3), GaussMarkov(3e-3, 2.0), GaussMarkov(3e-4, 300.0)))
    x = truth.simulate(1_000_000, FS, 2)
    r = fit_gmwm(x, FS, "wn+2gm")
    assert r.params["tau_b1"] < r.params["tau_b2"]
    assert r.tau_b == r.params["tau_b2"] and r.sigma_b == r.params["sigma_b2"]
    assert r.params["tau_b1"] == pytest.approx(2.0, rel=0.3)
    assert r.params["tau_b2"] == pytest.approx(300.0, rel=0.5)


@pytest.mark.parametrize(
    "kwargs, text",
    [
        ({"model": "wn+xx"}, "unknown term"),
        ({"starts": "many"}, "starts 'many'"),
        ({"reweight": -1}, "reweight"),
    ],
)
def test_bad_options_one_line(kwargs, text):
    x = np.random.default_rng(0).normal(size=4096)
    with pytest.raises(InputError, match=text) as e:
        fit_gmwm(x, FS, **kwargs)
    assert "\n" not in str(e.value)


def test_bad_data_one_line():
    with pytest.raises(InputError, match="too few for model"):
        fit_gmwm(np.random.default_rng(0).normal(size=9), FS, "wn+gm+rw")
    with pytest.raises(InputError, match="NaN"):
        fit_gmwm(np.array([1.0, np.nan] * 100), FS)
    with pytest.raises(InputError, match="fs_hz"):
        wavelet_variance(np.ones(100), -1.0)
    with pytest.raises(InputError, match="one-dimensional"):
        wavelet_variance(np.ones((10, 10)), FS)
    with pytest.raises(InputError, match="at least 3"):
        wavelet_variance(np.ones(2), FS)
    with pytest.raises(InputError, match="zero at some scale"):
        fit_gmwm(np.ones(1000), FS)
    with pytest.raises(InputError, match="confidence"):
        wavelet_variance(np.ones(100), FS, confidence=1.5)


# ---------------------------------------------------------------------------
# CLI and study


def test_analyze_method_both_json(tmp_path):
    x = standard(1e-3, 1e-3, 20.0).simulate(200_000, FS, 1)
    p = tmp_path / "x.npy"
    np.save(p, x)
    res = CliRunner().invoke(cli, ["analyze", str(p), "--rate", str(FS), "--method", "both", "--json"])
    assert res.exit_code == 0, res.output
    ch = json.loads(res.output)["channels"][0]
    assert ch["gmwm"].keys() == ch["mli"].keys()
    assert ch["gmwm"]["estimator"] == "GMWM" and ch["mli"]["estimator"] == "ML_i"
    table = CliRunner().invoke(cli, ["analyze", str(p), "--rate", str(FS), "--method", "gmwm", "--verbose"])
    assert table.exit_code == 0, table.output
    assert "  gmwm: GMWM " in table.output and "  mli: ML_i " not in table.output  # no ML_i comparison fit run
    bad = CliRunner().invoke(cli, ["analyze", str(p), "--rate", str(FS), "--method", "xx"])
    assert bad.exit_code == 2


def test_study_gmwm_column():
    from imustation.analysis.estimators.models.standard import StandardModel

    fits = run_study(StandardModel(1e-3, 1e-3, 20.0), records=2, duration_s=2000.0, fs_hz=FS, estimators=("gmwm",))
    assert [f.estimator for f in fits] == ["gmwm", "gmwm"]
    assert all(f.estimate["tau_b"] > 0 for f in fits)
