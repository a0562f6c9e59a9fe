"""The model family of real sensors (issue 22): bias instability, device filter, fine statistics, choice."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imustation.analysis.estimators.classical.allan import oadev
from imustation.analysis.estimators.engine.fitting import Problem, full_nll
from imustation.analysis.estimators.engine.kalman import Layout, kalman_profile
from imustation.analysis.estimators.engine.paramspec import ParamSpec
from imustation.analysis.estimators.engine.pattern import integrate
from imustation.analysis.estimators.ml.composite import fine_scale, fit_composite, fit_composite_data
from imustation.analysis.estimators.ml.finescale import FilterHint, allan_corr, fine_statistics
from imustation.analysis.estimators.models.noise_models import NoiseModel, TermBlock, WhiteRate, parse_model, van_loan
from imustation.analysis.estimators.models.sensor_terms import (
    FLICKER_FLOOR,
    BiasInstability,
    LowPass,
    flicker_times,
)
from imustation.analysis.estimators.selection.adequacy import model_adequacy
from imustation.analysis.estimators.selection.coefficients import ieee952_summary
from imustation.analysis.estimators.selection.model_choice import choose_model
from imustation.errors import InputError
from tests.realistic_records import filtered_white, record

SIGMA_W = 2.44e-4  # BMX055 datasheet 0.014 deg/s/sqrt(Hz)


# ---------------------------------------------------------------------------
# terms


def test_flicker_sum_is_within_its_stated_error_of_the_ideal_floor():
    times = flicker_times(400.0, 43200.0)
    assert times[0] == pytest.approx(1e-3) and times[-1] == pytest.approx(1e6)
    term = BiasInstability(1.0, times)
    tau = np.logspace(math.log10(10 * times[0]), math.log10(times[-1] / 10), 400)
    ratio = np.sqrt(term.avar(tau)) / FLICKER_FLOOR
    # the error stated in sensor_terms and docs/noise-model.md
    assert ratio.min() > 1 - 0.023 and ratio.max() < 1 + 0.011
    # the sampled form agrees with the continuous one away from the sample time
    np.testing.assert_allclose(term.avar(tau[tau > 1.0], 400.0), term.avar(tau[tau > 1.0]), rtol=2e-3)


def test_flicker_state_space_is_its_gauss_markov_sum():
    times = (1.0, 10.0, 100.0)
    model = NoiseModel((WhiteRate(1e-3), BiasInstability(2e-5, times)))
    assert model.n_states == 4
    Phi, Qd = model.discretize(np.array([3.0]))
    ss = model.state_space()
    keep = [0, 1, 2, 4]
    F = ss["F"][np.ix_(keep, keep)]
    GQG = (ss["G"] @ ss["Q"] @ ss["G"].T)[np.ix_(keep, keep)]
    P_ref, Q_ref = van_loan(F, GQG, 3.0)
    np.testing.assert_allclose(Phi[0], P_ref, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(Qd[0], Q_ref, rtol=1e-7, atol=1e-20)


def test_parse_model_knows_the_family_and_rejects_wa_with_lp():
    assert parse_model("lp+fl+wn+rw") == ("wn", "fl", "rw", "lp")
    assert ParamSpec(parse_model("wn+gm+fl+rw+lp")).name == "wn+gm+fl+rw+lp"
    with pytest.raises(InputError, match="cannot be told apart"):
        parse_model("wa+wn+lp")
    with pytest.raises(InputError, match="may appear once"):
        parse_model("wn+fl+fl")


def _fir_acov(sigma_w: float) -> tuple[np.ndarray, float]:
    """Autocovariance at output lags of the ADIS16448-like chain of tests/realistic_records.py."""
    fi, r = 819.2, 2
    h = np.convolve(np.convolve(np.ones(4) / 4, np.ones(4) / 4), np.ones(r) / r)
    full = np.correlate(h, h, "full")[len(h) - 1 :] * sigma_w**2 * fi
    return full[::r], r / fi


def test_device_filter_as_negative_angle_noise_is_the_exact_likelihood_beyond_its_memory():
    """Filtered white noise (FIR, finite memory) summed over intervals of 6-12 samples: the Kalman
    filter with angle noise -sigma_w^2 tau_lp/2 equals the dense Gaussian likelihood written out
    from the filter's autocovariance."""
    gam, dt = _fir_acov(1.0)
    assert len(np.flatnonzero(gam > 1e-15)) <= 5  # memory: 4 output samples
    s2 = dt * (gam[0] + 2 * gam[1:].sum())  # low-frequency density (unit DC gain: 1)
    tau_lp = dt * 2 * np.sum(np.arange(1, len(gam)) * gam[1:]) / (gam[0] + 2 * gam[1:].sum())
    assert s2 == pytest.approx(1.0, rel=1e-12)
    rng = np.random.default_rng(5)
    lens = rng.integers(6, 13, 25)
    edges = np.concatenate([[0], np.cumsum(lens)])
    n = int(edges[-1])
    lag = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    cov_x = np.where(lag < len(gam), gam[np.minimum(lag, len(gam) - 1)], 0.0) * dt * dt
    S = np.zeros((len(lens), n))
    for i in range(len(lens)):
        S[i, : edges[i + 1]] = 1.0  # angle at the pattern point = sum of all samples so far x dt
    C = S @ cov_x @ S.T
    X = edges[1:] * dt
    Y = rng.multivariate_normal(0.3 * X, C)
    Ci = np.linalg.inv(C)
    s_uu = X @ Ci @ X
    b_on = X @ Ci @ Y / s_uu
    res = Y - b_on * X
    dense = 0.5 * (np.linalg.slogdet(C)[1] + res @ Ci @ res + np.log(s_uu) + (len(Y) - 1) * math.log(2 * math.pi))
    lay = Layout(Y, X, lens * dt, np.r_[True, np.zeros(len(lens) - 1, bool)], np.zeros(len(lens)))
    prof = kalman_profile([TermBlock("wn", np.array([1.0]))], np.array([-tau_lp / 2]), lay)
    ours = float(full_nll(prof, np.array([1.0]))[0])
    assert ours == pytest.approx(dense, abs=1e-8)
    assert float(prof.b_on[0]) == pytest.approx(b_on, abs=1e-9)
    # and the Allan variance beyond the memory is -1.5 sigma_w^2 tau_lp / tau^2 below white
    lp = LowPass(1.0, tau_lp, memory_s=4 * dt)
    for m in (4, 8, 32):
        # AVAR = Var(mean of m) - Cov(neighbouring means), written out from the autocovariance
        g = np.concatenate([gam, np.zeros(2 * m)])
        var = (m * g[0] + 2 * sum((m - k) * g[k] for k in range(1, m))) / m**2
        cov = sum(min(k, 2 * m - k) * g[k] for k in range(1, 2 * m)) / m**2
        assert var - cov == pytest.approx(1.0 / (m * dt) + float(lp.avar(np.array([m * dt]))[0]), rel=1e-10)


def test_folded_flicker_components_leave_the_likelihood_unchanged():
    fs = 50.0
    model = NoiseModel((WhiteRate(1e-3), BiasInstability(3e-5, flicker_times(fs, 4 * 3600.0))))
    x = model.simulate(int(4 * 3600 * fs), fs, 3)
    inc = integrate(x, fs, m=500, pattern="uniform")
    spec = ParamSpec.for_record("wn+fl", fs, inc.duration)
    theta = np.array([[2 * math.log(3e-5 / 1e-3)], [2 * math.log(1e-5 / 1e-3)]])
    p = Problem(inc, spec)
    folded = p.nll(theta)
    p.fold_below = 0.0
    unfolded = p.nll(theta)
    assert p.spec.flicker_times[0] < 0.1 * inc.dt.min()  # some components were folded
    np.testing.assert_allclose(folded, unfolded, rtol=0, atol=2e-3)


# ---------------------------------------------------------------------------
# fine-scale statistics and the filter test


def test_allan_correlation_of_neighbouring_scales_matches_simulation():
    rng = np.random.default_rng(1)
    d = []
    for _ in range(300):
        x = rng.normal(size=4000)
        r = oadev(x, 1.0, [2.0, 4.0])
        d.append(r.adev**2)
    d = np.array(d)
    rho = np.corrcoef(d.T)[0, 1]
    assert rho == pytest.approx(allan_corr(2, 4), abs=0.1)
    assert allan_corr(1, 2) == pytest.approx(0.463, abs=1e-3) and allan_corr(64, 128) == pytest.approx(0.530, abs=1e-3)


@pytest.mark.parametrize("device", ["bmx055", "mpu9150", "adis16448"])
def test_filter_test_finds_the_filter_and_sigma_w_within_one_percent(device):
    fs = {"bmx055": 400.0, "mpu9150": 200.0, "adis16448": 409.6}[device]
    x = filtered_white(int(2 * 3600 * fs), device, SIGMA_W, np.random.default_rng(3))
    f = fine_statistics(x, fs)
    assert f.term == "lp" and f.linear and f.angle_z > 4
    assert 1 < f.samples <= 32
    assert 1.5e-3 < f.tau_lp < 3e-3
    t1 = f.taus[0]
    s = 2 * f.avar[1] * 2 * t1 - f.avar[0] * t1
    assert math.sqrt(s) == pytest.approx(SIGMA_W, rel=0.01)  # its standard error here: ~0.3 %


def test_white_noise_has_no_angle_term_and_the_sample_scale():
    x = filtered_white(1_000_000, "none", SIGMA_W, np.random.default_rng(4))
    f = fine_statistics(x, 400.0)
    assert f.term == "" and f.samples == 1 and abs(f.angle_z) < 4
    assert f.taus.shape == (1,) and f.nuisance.shape == (1, 0)
    # a filter the settings announce but the data do not show is not carried, and moves nothing
    g = fine_statistics(x, 400.0, hint=FilterHint(True, 0.02, "test"))
    assert g.term == "" and g.samples == 1 and "settings: test" in g.source


def test_composite_with_lp_needs_the_two_scale_statistic():
    x, fs = record("bmx055", 0.5, SIGMA_W, seed=2)
    inc = integrate(x, fs, m=200, pattern="uniform")
    with pytest.raises(InputError, match="two-scale"):
        fit_composite_data(inc, fine_scale(x, fs), "wn+rw+lp")
    res = fit_composite(x, fs, "wn+rw+lp")
    assert res.sigma_w == pytest.approx(SIGMA_W, rel=0.01)
    assert res.params["tau_lp"] == pytest.approx(fine_statistics(x, fs).tau_lp, rel=0.25)  # z ~ 7 on 0.5 h
    assert res.memory_s > 0 and "device filter" in res.message


# ---------------------------------------------------------------------------
# the automatic choice


@pytest.mark.parametrize("device", ["bmx055", "mpu9150", "adis16448"])
def test_auto_on_filtered_devices_sigma_w_within_one_percent_and_nothing_at_a_bound(device):
    x, fs = record(device, 2, SIGMA_W, B=1.5e-5, K=2e-7, seed=7)
    choice = choose_model(x, fs)
    r = choice.chosen
    assert "lp" in r.model.split("+")
    assert r.sigma_w == pytest.approx(SIGMA_W, rel=0.01)
    assert not r.at_bound and r.converged
    lo, hi = r.ci90["sigma_w"]
    assert lo < r.sigma_w < hi
    # the paper's model is reported beside it
    assert choice.paper is not None and choice.paper.model == "wn+gm"
    summary = ieee952_summary(r, len(x) / fs)
    assert summary["N"] == r.sigma_w and summary["B"] > 0
    assert summary["B_ci90"][0] < summary["B"] < summary["B_ci90"][1]


def test_auto_on_the_paper_model_keeps_the_paper_model():
    from imustation.analysis.estimators.models.noise_models import standard

    fs = 10.0  # 12 h: the Gauss-Markov roll-off beyond tau_b is seen over two decades
    x = standard(1e-3, 2e-5, 60.0, 0.01).simulate(int(12 * 3600 * fs), fs, 12)
    choice = choose_model(x, fs)
    assert choice.fits and choice.chosen.model == "wn+gm"
    assert choice.fine.term == ""
    assert choice.chosen.sigma_w == pytest.approx(1e-3, rel=0.01)


def test_choice_checks_candidates_with_the_adequacy_test_from_the_filter_memory_on():
    from imustation.analysis.estimators.models.noise_models import standard

    fs = 100.0
    truth = standard(1e-3, 2e-5, 60.0)
    x = truth.simulate(int(3 * 3600 * fs), fs, 13)
    allan = oadev(x, fs)
    assert model_adequacy(allan, truth, fs, [len(x)]).fits
    wrong = standard(1e-3, 2e-5, 600.0)
    bad = model_adequacy(allan, wrong, fs, [len(x)])
    assert not bad.fits and bad.misfit
    # taus below tau_min are not tested: the misfit there no longer counts
    beyond = model_adequacy(allan, wrong, fs, [len(x)], tau_min=2.0 * allan.tau[-1])
    assert beyond.verdict == "not tested" and beyond.z[0] == pytest.approx(bad.z[0])
    # the choice's candidates carry that verdict, and the chosen model passes it
    y, fsy = record("mpu9150", 0.5, SIGMA_W, B=1.5e-5, seed=3)
    choice = choose_model(y, fsy)
    assert all(c.check.method == "mahalanobis-avar" for c in choice.candidates)
    assert choice.fits and next(c for c in choice.candidates if c.result.model == choice.chosen.model).passes


# ---------------------------------------------------------------------------
# IEEE-952 and GMWM on filtered devices


@pytest.mark.parametrize("device", ["bmx055", "mpu9150", "adis16448"])
def test_ieee_and_gmwm_beyond_the_filter_memory_get_sigma_w_within_one_percent(device):
    from imustation.analysis.estimators.classical.ieee import ieee_coefficients
    from imustation.analysis.estimators.ml.gmwm import fit_gmwm

    x, fs = record(device, 2, SIGMA_W, B=1.5e-5, K=2e-7, seed=3)
    allan = oadev(x, fs)
    memory = fine_statistics(x, fs).memory_s
    plain = ieee_coefficients(allan)
    assert plain.N < 0.9 * SIGMA_W  # the bend below the white line read as a Gauss-Markov term
    c = ieee_coefficients(allan, tau_min=memory)
    assert c.N == pytest.approx(SIGMA_W, rel=0.01)
    assert c.tau_lp == pytest.approx(2.2e-3, rel=0.2) and c.tau_min == memory
    # no Gauss-Markov term at the shortest correlation time the fit allows
    assert math.isnan(c.gm_T) or c.gm_T > 2 * memory
    g = fit_gmwm(x, fs, "wn+fl+lp", tau_min=memory)
    assert g.sigma_w == pytest.approx(SIGMA_W, rel=0.01)
    assert "tau_lp" not in g.at_bound and "sigma_w" not in g.at_bound


def test_filter_hints_from_device_settings():
    from imustation.analysis.pipeline.devicefilter import filter_hint

    h = filter_hint({"driver": "bmx055", "settings": {"bandwidth_hz": 47.0, "rate_hz": 400}}, 400.0)
    assert h.on and h.memory_s == pytest.approx(0.5 / 47) and "47" in h.source
    assert filter_hint({"driver": "mpu9150", "settings": {"bandwidth_hz": 42}}, 200.0).on
    adis = filter_hint({"driver": "adis16448", "settings": {"filter_taps": 4, "decimation": 1}}, 409.6)
    assert adis.on and adis.memory_s == pytest.approx(8 / 819.2)
    assert not filter_hint({"driver": "adis16448", "settings": {"filter_taps": 1, "decimation": 1}}, 409.6).on
    assert not filter_hint({"driver": "mti", "settings": {}}, 400.0).on
    assert filter_hint({"driver": "somebody_else"}, 100.0) is None


def test_model_help_names_every_term_code():
    from imustation.analysis.estimators.models.noise_models import TERM_CODES
    from imustation.analysis.estimators.selection import model_choice
    from imustation.analysis.pipeline.choices import MODEL_HELP, PAPER_MODEL

    # the CLI's vocabulary loads without numpy, so it names the paper's model on its own: the same one
    assert PAPER_MODEL == model_choice.PAPER_MODEL

    assert all(f"{code} " in MODEL_HELP for code in TERM_CODES)


def test_export_turns_a_bias_instability_into_the_random_walk_meeting_its_floor():
    from imustation.analysis.reports.export import random_walk_from_params

    sw, B = 1e-4, 1e-5
    K = random_walk_from_params({"sigma_w": sw, "B": B})
    tau_x = sw**2 / (FLICKER_FLOOR * B) ** 2  # where the floor meets the white line
    assert K * math.sqrt(tau_x / 3) == pytest.approx(FLICKER_FLOOR * B, rel=1e-12)
    assert random_walk_from_params({"sigma_w": sw, "B": B, "sigma_k": 3 * K}) == pytest.approx(math.sqrt(10) * K)


# ---------------------------------------------------------------------------
# intervals on repeated recordings of one device


def test_repeated_recordings_of_one_device_stay_inside_the_stated_intervals():
    """Six 1 h recordings of one MPU-9150-like axis (DLPF, bias instability, a weak random walk):
    the automatic choice's 90 % intervals cover the device's output white-noise density and B in
    at least 5 and 4 of 6 (a binomial 90 % coverage gives fewer in 1.6 % and 11 % of such sets),
    and the run-to-run scatter of N is no wider than twice its stated standard error."""
    from tests.realistic_records import low_frequency_gain

    B = 1.5e-5
    n_true = SIGMA_W * math.sqrt(low_frequency_gain("mpu9150"))
    est, se, cover_n, cover_b = [], [], 0, 0
    for seed in range(300, 306):
        x, fs = record("mpu9150", 1.0, SIGMA_W, B=B, K=2e-7, seed=seed)
        choice = choose_model(x, fs)
        s = ieee952_summary(choice.chosen, len(x) / fs, choice.close)
        lo, hi = s["N_ci90"]
        cover_n += lo <= n_true <= hi
        cover_b += s["B_ci90"][0] <= B <= s["B_ci90"][1]
        est.append(math.log(s["N"]))
        se.append(math.log(hi / lo) / (2 * 1.6449))
    assert cover_n >= 5 and cover_b >= 4
    assert np.std(est, ddof=1) <= 2 * np.median(se)


def test_block_allan_variances_equal_the_allan_variance_of_each_block():
    from imustation.analysis.estimators.classical.allan import block_oavar

    x, fs = record("none", 0.1, 1e-3, seed=1)
    n = len(x)
    got = block_oavar(x, fs, [1, 4, 16], 4)
    for i in range(4):
        part = x[i * n // 4 : (i + 1) * n // 4]
        np.testing.assert_allclose(got[i], oadev(part, fs, [1 / fs, 4 / fs, 16 / fs]).adev ** 2, rtol=1e-10)
    # a gap: no term spans it, in any block
    segs = [(0, n // 3), (n // 3 + 50, n)]
    gapped = block_oavar(x, fs, [4], 2, segments=segs)
    first = oadev(x[: n // 2], fs, [4 / fs], segments=[(0, n // 3), (n // 3 + 50, n // 2)]).adev[0] ** 2
    assert gapped[0, 0] == pytest.approx(first, rel=1e-10)
    counts = (np.arange(n) * 3).astype(np.int16)[: n // 2]  # integer counts take the same path
    np.testing.assert_allclose(block_oavar(counts, fs, [2], 2, scale=0.5)[:, 0],
                               [oadev(c, fs, [2 / fs], scale=0.5).adev[0] ** 2 for c in np.array_split(counts, 2)],
                               rtol=1e-9)  # fmt: skip


def test_the_chosen_models_adequacy_is_the_choices_own_test():
    """analyze reuses the adequacy the choice computed for the chosen model: it must be the test
    the block would get on its own (same taus, degrees of freedom, verdict)."""
    from imustation.analysis.pipeline.channel import analyze_channel, fit_adequacy
    from imustation.analysis.pipeline.loaders import Channel

    x, fs = record("bmx055", 0.5, SIGMA_W, B=1.5e-5, seed=2)
    ch = Channel("imu/gyro/x", fs, "rad/s", x)
    res = analyze_channel(ch)
    reused = res.adequacy["noise_model"]
    assert any(reused is c.check for c in res.choice.candidates)
    fresh = fit_adequacy(ch, res.allan, res.noise_model)
    assert (reused.verdict, reused.dof) == (fresh.verdict, fresh.dof)
    assert reused.p_value == pytest.approx(fresh.p_value) and np.allclose(reused.z, fresh.z, equal_nan=True)


def test_the_choice_tests_only_what_it_needs_and_the_rule_still_holds():
    x, fs = record("adis16448", 2.0, SIGMA_W, B=1.5e-5, K=2e-7, seed=4)
    choice = choose_model(x, fs)
    chosen = next(c for c in choice.candidates if c.result.model == choice.chosen.model)
    assert chosen.tested and chosen.passes
    untested = [c for c in choice.candidates if not c.tested]
    assert untested  # on 2 h the stage's worse models are left alone
    assert all(c.as_dict()["fits"] is None for c in untested)
    # the rule as if every candidate were tested: nothing converged in the chosen stage with a
    # smaller BIC passes, and the close models (BIC within 10) all pass
    for c in choice.candidates:
        if c.stage == chosen.stage and c.result.converged and c.result.bic < chosen.result.bic:
            assert not c.passes
        # a later, larger model would have replaced it with a BIC lower by 10 had it passed
        if c.stage > chosen.stage and c.result.converged and c.result.bic < chosen.result.bic - 10:
            assert not c.passes
    assert all(next(c for c in choice.candidates if c.result is r).passes for r in choice.close)
