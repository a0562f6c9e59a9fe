"""Noise-model library, general Kalman filter, ML_i for every model, classical ML, study.

Oracles: Van Loan's matrix exponential (eq. 21) for the closed-form
discretisation; dense Gaussian likelihoods (covariances written out by hand)
for both filters; an in-test overlapping Allan variance of simulated records
for the closed-form AVAR; the PSD's integral (= the sampled process' variance);
simulate-then-fit with tolerances from the fit's own standard errors.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.analysis import StandardModel
from imustation.analysis.estimators.engine.fitting import ParamSpec, Problem, profiled_nll
from imustation.analysis.estimators.engine.kalman import Layout, kalman_profile
from imustation.analysis.estimators.engine.pattern import integrate, pattern_avar
from imustation.analysis.estimators.engine.scan import standard_profile
from imustation.analysis.estimators.ml.ml_rate import fit_ml_rate, rate_filter
from imustation.analysis.estimators.ml.mli import compare_models, fit_integrated, fit_mli
from imustation.analysis.estimators.models.noise_models import (
    GaussMarkov,
    NoiseModel,
    Quantization,
    RandomWalk,
    RateRamp,
    TermBlock,
    WhiteAngle,
    WhiteRate,
    parse_model,
    standard,
)
from imustation.analysis.pipeline.study import markdown, run_study, summarize
from imustation.cli import cli
from imustation.errors import InputError

FS = 100.0


def oavar(x: np.ndarray, fs: float, n: int) -> float:
    """Overlapping Allan variance of rate samples at cluster size n (NIST SP 1065 eq. 14)."""
    c = np.concatenate([[0.0], np.cumsum(x)]) / fs
    tau = n / fs
    d = c[2 * n :] - 2 * c[n:-n] + c[: -2 * n]
    return float(np.mean(d * d) / (2 * tau * tau))


# ---------------------------------------------------------------------------
# library


def test_parse_model_canonical_and_errors():
    assert parse_model("gm+wn") == ("wn", "gm")
    assert parse_model("wn+2gm+wa") == ("wa", "wn", "gm", "gm")
    with pytest.raises(InputError, match="exactly one 'wn'"):
        parse_model("gm")
    with pytest.raises(InputError, match="unknown term"):
        parse_model("wn+flicker")


@pytest.mark.parametrize("dt", [1e-3, 0.7, 40.0, 3e3, 1e6])
def test_closed_form_discretisation_equals_van_loan(dt):
    model = NoiseModel((WhiteRate(1e-4), GaussMarkov(2e-5, 3.0), GaussMarkov(1e-6, 700.0), RandomWalk(3e-7)))
    Pa, Qa = model.discretize(np.array([dt]))
    Pv, Qv = model.discretize(np.array([dt]), method="vanloan")
    np.testing.assert_allclose(Pv, Pa, rtol=1e-9, atol=1e-12 * np.abs(Pa).max())
    np.testing.assert_allclose(Qv, Qa, rtol=1e-7, atol=1e-9 * np.abs(Qa).max())


def test_state_space_matrices_of_the_standard_model_are_eq_23():
    ss = standard(1e-4, 1e-6, 500.0).state_space()
    np.testing.assert_array_equal(ss["F"], [[-1 / 500.0, 0, 0], [0, 0, 0], [1, 1, 0]])
    np.testing.assert_array_equal(ss["H"], [[0, 0, 1]])
    np.testing.assert_allclose(ss["G"] @ ss["Q"] @ ss["G"].T, np.diag([1e-12, 0.0, 1e-8]))


@pytest.mark.parametrize(
    "term",
    [WhiteRate(1e-3), GaussMarkov(2e-3, 0.5), RandomWalk(1e-3), WhiteAngle(2e-5)],
    ids=["wn", "gm", "rw", "wa"],
)
def test_discrete_avar_matches_simulated_oavar(term):
    """Exact sampled AVAR vs overlapping AVAR of 5 simulated records (tolerance: 4 x the seed scatter)."""
    n_samples, taus = 400_000, [1, 10, 100]
    sims = np.array(
        [[oavar(term.simulate(n_samples, 1 / FS, np.random.default_rng(s)), FS, n) for n in taus] for s in range(5)]
    )
    mean, sem = sims.mean(axis=0), sims.std(axis=0, ddof=1) / math.sqrt(5)
    closed = term.avar(np.array(taus) / FS, FS)
    assert np.all(np.abs(mean - closed) < 4 * sem + 1e-12 * closed), (mean, closed, sem)


def test_continuous_and_discrete_avar_agree_away_from_the_sample_time():
    gm, rw = GaussMarkov(1e-6, 500.0), RandomWalk(1e-6)
    tau = np.array([1.0, 10.0, 1e3, 1e4])
    np.testing.assert_allclose(gm.avar(tau, 400.0), gm.avar(tau), rtol=1e-4)
    np.testing.assert_allclose(rw.avar(tau, 400.0), rw.avar(tau), rtol=1e-5)
    # small-tau limit sigma_b^2 tau / 3 (eq. 7)
    np.testing.assert_allclose(gm.avar(np.array([1e-3])), 1e-12 * 1e-3 / 3, rtol=1e-5)


def test_gm_avar_peak_matches_noise_formulas():
    """docs/reference/noise-formulas.md §5: peak at tau = 1.8926 T with sigma_max = 0.6174 s (s^2 = stationary var)."""
    gm = GaussMarkov(1.0, 2.0)
    tau = np.geomspace(0.1, 100, 20001)
    adev = gm.adev(tau)
    s = math.sqrt(gm.sigma_b**2 * gm.tau_b / 2)
    assert tau[np.argmax(adev)] == pytest.approx(1.8926 * 2.0, rel=1e-3)
    assert adev.max() == pytest.approx(0.6174 * s, rel=1e-3)


@pytest.mark.parametrize("term", [WhiteRate(1e-3), GaussMarkov(2e-3, 0.5), WhiteAngle(2e-5)], ids=["wn", "gm", "wa"])
def test_discrete_psd_integrates_to_the_sample_variance(term):
    """Two-sided PSD over [-fs/2, fs/2] = variance of one rate sample (Parseval)."""
    f = np.linspace(-FS / 2, FS / 2, 400_001)
    var = np.trapezoid(term.psd(f, FS), f)
    expected = {
        "wn": 1e-6 * FS,
        "gm": 4e-6 * 0.5 / 2,
        "wa": 2 * (2e-5) ** 2 * FS**2,
    }[term.code]
    assert var == pytest.approx(expected, rel=1e-6)
    np.testing.assert_allclose(term.psd(f[:5], FS, onesided=True), 2 * term.psd(f[:5], FS))


def test_overlay_terms():
    q, rr = Quantization(1e-6), RateRamp(1e-5)
    tau = np.array([0.1, 1.0, 10.0])
    np.testing.assert_allclose(q.avar(tau), 3e-12 / tau**2)
    np.testing.assert_allclose(rr.avar(tau), 0.5e-10 * tau**2)
    np.testing.assert_allclose(rr.psd(np.array([1.0])), 1e-10 / (2 * np.pi) ** 3)
    with pytest.raises(InputError, match="overlay-only"):
        NoiseModel((WhiteRate(1e-4), q)).state_space()
    with pytest.raises(InputError, match="fs_hz"):
        q.psd(np.array([1.0]))


# ---------------------------------------------------------------------------
# filters


def _pattern_data(model: NoiseModel, seconds: float, m: int, seed: int, segments=None):
    x = model.simulate(int(seconds * FS), FS, seed)
    return integrate(x, FS, m=m, segments=segments)


def test_general_kalman_filter_equals_scan_filter():
    inc = _pattern_data(standard(1e-4, 5e-6, 40.0, 0.003), 1800, 200, 5)
    spec = ParamSpec(("wn", "gm"))
    theta = np.log([[1e-3, 30.0], [0.2, 0.5], [1e-7, 3e4]])
    a = Problem(inc, spec, "scan").nll(theta)
    b = Problem(inc, spec, "kalman").nll(theta)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)


def test_general_and_scan_filters_agree_across_gaps():
    n = int(1800 * FS)
    segs = [(0, n // 3), (n // 3 + 5000, n - 2000)]
    inc = _pattern_data(standard(1e-4, 5e-6, 40.0, 0.003), 1800, 200, 6, segments=segs)
    assert inc.new_segment.sum() == 2 and inc.gap[inc.new_segment][1] == pytest.approx(50.0)
    spec = ParamSpec(("wn", "gm"))
    theta = np.log([[1e-3, 30.0], [0.2, 0.5]])
    np.testing.assert_allclose(
        Problem(inc, spec, "scan").nll(theta), Problem(inc, spec, "kalman").nll(theta), rtol=0, atol=1e-6
    )


def test_general_kalman_filter_equals_dense_gaussian_likelihood():
    """wa+wn+rw with two segments: the filter's diffuse likelihood vs the covariance written out.

    Within a segment the observed angle is Y_i = W(t_i) + K int_0^t_i RW + b_on t_i + n_i - n_0;
    across the gap the random walk carries over (its value at the segment start
    adds a slope), the angle restarts.
    """
    rng = np.random.default_rng(3)
    t1 = np.cumsum(rng.uniform(0.2, 2.0, 12))
    t2 = np.cumsum(rng.uniform(0.2, 2.0, 9))
    gap = 4.0
    q_w, q_k, r_a = 1.0, 0.3, 0.05  # sigma_w = 1 units
    # random-walk value b(s) with s absolute time; segment 1 starts at 0, segment 2 at S2
    S2 = t1[-1] + gap
    abs_t = np.concatenate([t1, S2 + t2])
    start = np.concatenate([np.zeros_like(t1), np.full_like(t2, S2)])
    N = len(abs_t)
    C = np.zeros((N, N))
    for i in range(N):
        for j in range(N):
            # white part: only within the same segment
            same = start[i] == start[j]
            if same:
                C[i, j] += q_w * min(abs_t[i], abs_t[j]) - q_w * start[i]
                C[i, j] += r_a * (1.0 + (i == j))
            # RW part: int_{s_i}^{T_i} int_{s_j}^{T_j} min(u, v) du dv  (RW starts at 0 at time 0)
            C[i, j] += q_k * _int_min(start[i], abs_t[i], start[j], abs_t[j])
    X = abs_t - start
    Y = rng.multivariate_normal(0.7 * X, C)
    Ci = np.linalg.inv(C)
    s_uu = X @ Ci @ X
    b_on = X @ Ci @ Y / s_uu
    res = Y - b_on * X
    dense = 0.5 * (np.linalg.slogdet(C)[1] + res @ Ci @ res + np.log(s_uu))
    dt = np.diff(np.concatenate([[0.0], t1, [0.0], t2]))
    dt = np.delete(dt, len(t1))
    new_seg = np.zeros(N, bool)
    new_seg[[0, len(t1)]] = True
    gaps = np.zeros(N)
    gaps[len(t1)] = gap
    lay = Layout(Y, X, dt, new_seg, gaps)
    prof = kalman_profile([TermBlock("wn", np.array([q_w])), TermBlock("rw", np.array([q_k]))], np.array([r_a]), lay)
    ours = 0.5 * (prof.logdet[0] + prof.s_tilde[0] + prof.log_suu[0])
    assert ours == pytest.approx(dense, abs=1e-9)
    assert prof.b_on[0] == pytest.approx(b_on, abs=1e-9)


def _int_min(a1, b1, a2, b2, n=4001):
    """int_{a1}^{b1} int_{a2}^{b2} min(u, v) dv du, exactly via the closed form of the inner integral."""

    def inner(u):  # int_{a2}^{b2} min(u, v) dv
        lo, hi = a2, b2
        below = np.clip(u, lo, hi)
        return (below**2 - lo**2) / 2 + u * (hi - below)

    # inner is piecewise quadratic in u: Simpson on a fine grid with the kinks as nodes is exact enough
    knots = np.unique(np.clip([a1, a2, b2, b1], a1, b1))
    total = 0.0
    for lo, hi in zip(knots[:-1], knots[1:], strict=False):
        u = np.linspace(lo, hi, 3)
        total += (hi - lo) / 6 * (inner(u[0]) + 4 * inner(u[1]) + inner(u[2]))
    return total


def test_rate_filter_equals_dense_gaussian_likelihood():
    rng = np.random.default_rng(4)
    idx = np.sort(rng.choice(2000, 40, replace=False))
    t = idx / FS
    r, tau = 0.02, 3.0
    C = r * tau / 2 * np.exp(-np.abs(t[:, None] - t[None, :]) / tau) + FS * np.eye(len(t))
    z = rng.multivariate_normal(np.full(len(t), 0.3), C)
    one = np.ones(len(t))
    Ci = np.linalg.inv(C)
    s_uu = one @ Ci @ one
    res = z - (one @ Ci @ z) / s_uu
    dense = 0.5 * (np.linalg.slogdet(C)[1] + res @ Ci @ res + np.log(s_uu))
    prof = rate_filter(z, np.r_[0.0, np.diff(t)], FS, np.array([r]), np.array([tau]))
    assert 0.5 * (prof.logdet[0] + prof.s_tilde[0] + prof.log_suu[0]) == pytest.approx(dense, abs=1e-9)


def test_scan_filter_with_gap_equals_dense_gaussian():
    """The fast path's gap treatment against the covariance of the increments written out."""
    rng = np.random.default_rng(5)
    dt = rng.uniform(0.1, 3.0, 15)
    gap = np.zeros(15)
    gap[7] = 5.0
    r, tau = 0.3, 2.0
    ends = np.cumsum(dt + gap)
    starts = ends - dt
    # increments y_i = int_{s_i}^{e_i} b + white; Cov of GM integrals
    C = np.diag(dt.copy())
    k = r * tau / 2
    for i in range(15):
        for j in range(15):
            if i == j:
                a = dt[i] / tau
                C[i, i] += 2 * k * tau * tau * (a - 1 + math.exp(-a))
            else:
                lo, hi = (i, j) if starts[i] < starts[j] else (j, i)
                C[i, j] += (
                    k
                    * tau
                    * tau
                    * (1 - math.exp(-dt[lo] / tau))
                    * (1 - math.exp(-dt[hi] / tau))
                    * math.exp(-(starts[hi] - ends[lo]) / tau)
                )
    y = rng.multivariate_normal(0.2 * dt, C)
    Ci = np.linalg.inv(C)
    s_uu = dt @ Ci @ dt
    res = y - (dt @ Ci @ y) / s_uu * dt
    dense = 0.5 * (np.linalg.slogdet(C)[1] + res @ Ci @ res + np.log(s_uu))
    prof = standard_profile(y, dt, np.array([r]), np.array([tau]), gap)
    assert 0.5 * (prof.logdet[0] + prof.s_tilde[0] + prof.log_suu[0]) == pytest.approx(dense, abs=1e-9)


# ---------------------------------------------------------------------------
# fits


RECOVERY = {
    "wn+rw": NoiseModel((WhiteRate(1e-4), RandomWalk(3e-6)), 0.01),
    "wa+wn+gm": NoiseModel((WhiteAngle(2e-5), WhiteRate(1e-4), GaussMarkov(1e-5, 100.0)), -0.02),
    "wn+gm+rw": NoiseModel((WhiteRate(1e-4), GaussMarkov(2e-5, 20.0), RandomWalk(3e-6))),
}


@pytest.mark.parametrize("name", list(RECOVERY))
def test_simulate_then_fit_recovers_each_model(name):
    """2 h at 100 Hz, m = 300: every parameter within 4 of its reported standard errors."""
    truth = RECOVERY[name]
    x = truth.simulate(int(2 * 3600 * FS), FS, 11)
    res = fit_mli(x, FS, name, m=300)
    assert res.converged, res.message
    assert res.model == name
    for key, value in truth.params().items():
        if key == "b_on":
            continue
        assert abs(res.params[key] - value) < 4 * res.stderr[key], (key, value, res.params[key], res.stderr[key])
    assert res.b_on == pytest.approx(truth.b_on, abs=2e-4)


def test_fit_with_gaps_recovers_the_standard_model():
    truth = standard(1e-4, 2e-6, 300.0, 0.01)
    n = int(4 * 3600 * FS)
    x = truth.simulate(n, FS, 12)
    segs = [(0, n // 2 - 30_000), (n // 2, n)]
    res = fit_mli(x, FS, segments=segs)
    assert res.converged
    for key in ("sigma_w", "sigma_b", "tau_b"):
        assert abs(res.params[key] - truth.params()[key]) < 4 * res.stderr[key]
    whole = fit_mli(x, FS, segments=[(0, n)])
    plain = fit_mli(x, FS)
    assert whole.nll == pytest.approx(plain.nll, abs=1e-6)


def test_bad_segments_are_user_errors():
    x = np.zeros(1000)
    with pytest.raises(InputError, match="segment"):
        fit_mli(x, FS, segments=[(0, 600), (500, 1000)])
    with pytest.raises(InputError, match="unknown term"):
        fit_mli(x, FS, model="wn+xx")


def test_bic_picks_the_true_model():
    """Two well separated Gauss-Markov terms -> wn+2gm; the standard model -> wn+gm."""
    two = NoiseModel((WhiteRate(1e-4), GaussMarkov(3e-4, 1.0), GaussMarkov(4e-6, 300.0)))
    inc = integrate(two.simulate(int(2 * 3600 * FS), FS, 21), FS, m=300)
    ranked = compare_models(inc, ("wn+gm", "wn+2gm"))
    assert ranked[0].model == "wn+2gm"
    assert ranked[0].nll < ranked[1].nll - 10
    one = standard(1e-4, 4e-6, 300.0)
    inc = integrate(one.simulate(int(2 * 3600 * FS), FS, 22), FS, m=300)
    ranked = compare_models(inc, ("wn+gm", "wn+2gm"))
    assert ranked[0].model == "wn+gm"
    # nested: the richer model is never worse in likelihood
    assert ranked[1].nll <= ranked[0].nll + 1e-3


def test_fit_mli_public_result_fields():
    from imustation.analysis import fit_mli as public

    res = public(standard(1e-4, 2e-6, 300.0, 0.01).simulate(200_000, FS, 1), FS, model="wn+gm")
    for key in ("sigma_w", "sigma_b", "tau_b", "b_on", "stderr", "nll"):
        assert hasattr(res, key)
    d = res.as_dict()
    assert {"model", "sigma_w", "sigma_b", "tau_b", "b_on", "stderr", "pattern", "m", "nll"} <= set(d)
    assert d["aic"] == pytest.approx(2 * res.nll + 2 * res.k)


def test_pattern_avar_follows_the_white_noise_line():
    inc = _pattern_data(NoiseModel((WhiteRate(1e-3),)), 3600, 1000, 2)
    tau, avar, count = pattern_avar(inc)
    good = count > 50
    np.testing.assert_allclose(avar[good] * tau[good], 1e-6, rtol=0.4)


def test_classical_ml_recovers_a_strong_bias():
    """Fig. 10: with strong bias diffusion classical ML on uniformly sampled rate works too."""
    truth = standard(1e-4, 1e-4, 20.0, 0.01)
    x = truth.simulate(int(3600 * FS), FS, 8)
    res = fit_ml_rate(x, FS, pattern="uniform", m=2000)
    assert res.estimator == "ML"
    for key in ("sigma_w", "sigma_b", "tau_b"):
        assert abs(res.params[key] - truth.params()[key]) < 4 * res.stderr[key], key


def test_sigma_w_interval_coverage_small():
    """20 seeds of 1 h records: the 90 % interval of sigma_w covers the truth in 15..20 of them
    (binomial(20, 0.9): P(< 15) = 1 %)."""
    truth = standard(1.05e-4, 1.26e-5, 200.0, 0.01)
    hits = 0
    for seed in range(20):
        res = fit_mli(truth.simulate(int(3600 * 400.0), 400.0, 100 + seed), 400.0)
        lo, hi = res.ci90["sigma_w"]
        hits += lo <= truth.params()["sigma_w"] <= hi
    assert hits >= 15


@pytest.mark.slow
def test_interval_coverage_over_100_seeds_of_12h():
    """Coverage of all three 90 % intervals over 100 seeds of 12 h BMX055-like records: 80-98 %."""
    from imustation.analysis.estimators.models.reference import TABLE_III_MEAN as T

    fits = run_study(StandardModel(T.sigma_w, T.sigma_b, T.tau_b), records=100, duration_s=12 * 3600)
    for row in summarize(fits):
        assert 0.80 <= row.coverage90 <= 0.98, row


def test_small_study_and_markdown():
    fits = run_study(StandardModel(1.05e-4, 1.26e-5, 200.0), records=3, duration_s=3600, estimators=("mli-log",))
    rows = summarize(fits)
    assert [r.param for r in rows] == ["sigma_w", "sigma_b", "tau_b"]
    assert all(r.count == 3 and 0 <= r.coverage90 <= 1 for r in rows)
    assert abs(rows[0].bias_rel) < 0.05  # sigma_w: 3 records with ~2 % spread each
    assert markdown(rows).count("\n") == 5


def test_study_cli_writes_markdown(tmp_path):
    out = tmp_path / "study.md"
    res = CliRunner().invoke(
        cli, ["study", "--records", "2", "--duration", "20m", "--estimators", "mli-log,ml-uniform", "--out", str(out)]
    )
    assert res.exit_code == 0, res.output
    text = out.read_text()
    assert "| mli-log | x1 | sigma_w |" in text and "| ml-uniform |" in text
    bad = CliRunner().invoke(cli, ["study", "--estimators", "nope", "--records", "2", "--duration", "1m"])
    assert bad.exit_code == 2 and "estimator 'nope'" in bad.output


def test_analyze_json_models_block(tmp_path):
    x = standard(1e-4, 2e-6, 300.0, 0.01).simulate(200_000, FS, 3)
    np.save(tmp_path / "g.npy", x)
    args = ["analyze", str(tmp_path / "g.npy"), "--rate", "100", "--json", "--compare-models", "--model", "wn+gm"]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    ch = json.loads(res.output)["channels"][0]
    assert ch["mli"]["model"] == "wn+gm"
    assert {m["model"] for m in ch["models"]} == {"wn+gm", "wn+gm+rw", "wn+2gm"}
    assert all({"nll", "aic", "bic", "params"} <= set(m) for m in ch["models"])


def test_fit_integrated_reuses_one_integration():
    x = standard(1e-4, 2e-6, 300.0).simulate(300_000, FS, 4)
    inc = integrate(x, FS)
    a = fit_integrated(inc)
    b = fit_mli(x, FS)
    assert a.nll == pytest.approx(b.nll, abs=1e-9)
    assert profiled_nll is not None
