"""ML_i-F (analysis/estimators/ml/composite.py): the integrated likelihood plus the fine-scale Allan variance."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.signal import lfilter

from imustation.analysis.estimators.classical.allan import oadev
from imustation.analysis.estimators.engine.fitting import ParamSpec, full_nll
from imustation.analysis.estimators.engine.pattern import integrate
from imustation.analysis.estimators.ml.composite import (
    ESTIMATOR,
    CompositeProblem,
    fine_scale,
    fit_composite,
    fit_composite_data,
)
from imustation.analysis.estimators.ml.mli import fit_integrated
from imustation.analysis.estimators.models.noise_models import GaussMarkov, gm_unit_avar, parse_model, standard
from imustation.analysis.pipeline.study import run_study, summarize
from imustation.cli import cli
from imustation.errors import InputError

FS = 100.0
TRUTH = dict(sigma_w=1e-3, sigma_b=2e-5, tau_b=60.0)


@pytest.fixture(scope="module")
def record():
    """4 h at 100 Hz of the standard model: 240 tau_b, 1.44 M samples."""
    m = standard(TRUTH["sigma_w"], TRUTH["sigma_b"], TRUTH["tau_b"], 0.02)
    return m.simulate(int(4 * 3600 * FS), FS, np.random.default_rng(11))


@pytest.mark.parametrize("tau_b", [0.03, 2.0, 530.0, 1e6])
@pytest.mark.parametrize("samples", [1, 7])
def test_vectorised_gm_avar_is_the_library_closed_form(tau_b, samples):
    tau = samples / FS
    ref = GaussMarkov(1.0, tau_b).avar(np.array([tau]), FS)[0]
    assert gm_unit_avar(np.array([tau_b]), tau, FS)[0] == pytest.approx(ref, rel=1e-12)


def test_fine_scale_is_the_overlapping_allan_variance_at_one_sample(record):
    fine = fine_scale(record, FS)
    assert fine.tau == pytest.approx(1 / FS)
    assert fine.avar == pytest.approx(oadev(record, FS, [1 / FS]).adev[0] ** 2, rel=1e-12)
    # chi-square variance with the white-noise EDF ~ 2N/3
    assert fine.edf == pytest.approx(2 * len(record) / 3, rel=0.02)
    assert fine.var == pytest.approx(2 * fine.avar**2 / fine.edf)


def test_counts_and_scaled_floats_give_the_same_statistic():
    rng = np.random.default_rng(2)
    counts = rng.integers(-3000, 3000, 50_000).astype(np.int16)
    a = fine_scale(counts, FS, scale=1e-3)
    b = fine_scale(counts.astype(float) * 1e-3, FS)
    assert a.avar == pytest.approx(b.avar, rel=1e-12)


def test_composite_nll_is_ml_i_likelihood_plus_the_fine_term_at_the_profiled_sigma_w(record):
    inc = integrate(record, FS, m=500, pattern="uniform")
    fine = fine_scale(record, FS)
    problem = CompositeProblem(inc, ParamSpec(parse_model("wn+gm")), fine)
    theta = np.array([[math.log((2e-5 / 1e-3) ** 2), math.log(60.0)], [math.log(1e-6), math.log(500.0)]])
    prof = problem.profile(theta)
    A = problem.unit_avar(theta)  # (K, 1): one fine scale
    s = problem.sigma_w2(prof, A)

    def total(sw2):
        return full_nll(prof, sw2) + (fine.avar - sw2 * A[:, 0]) ** 2 / (2 * fine.var)

    np.testing.assert_allclose(problem.nll(theta), total(s), rtol=1e-12)
    # s is the minimiser over sigma_w^2: nudging it either way costs
    for k in (1 + 1e-4, 1 - 1e-4):
        assert np.all(total(s * k) > total(s))
    # and the physical-parameter form agrees at the profiled point
    phi = np.column_stack([0.5 * np.log(s), 0.5 * (theta[:, 0] + np.log(s)), theta[:, 1]])
    np.testing.assert_allclose(problem.full_nll(phi), total(s), rtol=1e-10)


def test_fit_recovers_the_model_and_sigma_w_far_better_than_ml_i(record):
    res = fit_composite(record, FS)
    assert res.converged, res.message
    assert res.estimator == ESTIMATOR == "ML_i-F"
    assert res.pattern == "uniform"
    # fine-scale precision: sqrt(3/N)/2 = 0.07 % on 1.44 M samples; 5 sigma
    assert res.sigma_w == pytest.approx(TRUTH["sigma_w"], rel=0.004)
    mli = fit_integrated(integrate(record, FS))
    assert res.stderr["sigma_w"] < 0.2 * mli.stderr["sigma_w"]
    for p in ("sigma_b", "tau_b"):
        lo, hi = res.ci90[p]
        assert lo < getattr(res, p) < hi
        assert math.exp(-4) < getattr(res, p) / TRUTH[p] < math.exp(4)
    assert abs(res.fine_scale_z) < 4
    assert res.data_time_s > 0 and res.fit_time_s > 0


def test_profile_interval_of_tau_b_is_skewed_like_the_likelihood(record):
    res = fit_composite(record, FS)
    lo, hi = res.ci90["tau_b"]
    # the likelihood in tau_b has a long upper tail: the upper end is further away in log
    assert math.log(hi / res.tau_b) > math.log(res.tau_b / lo)


def test_low_pass_filtered_noise_moves_the_fine_scale_and_says_so():
    """A device filter below Nyquist makes the sample-scale AVAR too small: the scale moves up, visibly."""
    rng = np.random.default_rng(4)
    n = int(2 * 3600 * FS)
    white = rng.normal(0.0, 1e-3 * math.sqrt(FS), n)
    a = math.exp(-2 * math.pi * 10.0 / FS)  # first-order low-pass, 10 Hz corner at 100 Hz (tau_c 16 ms)
    rate = lfilter([1 - a], [1, -a], white)
    fine = fine_scale(rate, FS, samples="auto")
    assert fine.white and fine.samples >= 8
    res = fit_composite(rate, FS)
    assert "fine scale raised to" in res.message
    forced = fit_composite(rate, FS, fine_samples=1)
    # forcing the sample scale: the filter's deficit shows up as a far smaller sigma_w
    assert abs(res.sigma_w / 1e-3 - 1) < 0.1 < abs(forced.sigma_w / 1e-3 - 1)
    white_fine = fine_scale(white, FS, samples="auto")
    assert white_fine.samples == 1 and white_fine.white


def test_other_models_use_the_general_filter(record):
    res = fit_composite(record[: int(3600 * FS)], FS, "wn+gm+rw", m=400)
    assert res.model == "wn+gm+rw" and math.isfinite(res.nll)
    assert res.sigma_w == pytest.approx(TRUTH["sigma_w"], rel=0.01)


def test_single_start_option_and_bad_input(record):
    inc = integrate(record, FS, m=300, pattern="uniform")
    one = fit_composite_data(inc, fine_scale(record, FS), single_start=True)
    assert one.starts == 1
    with pytest.raises(InputError, match="fine_samples"):
        fit_composite(record, FS, fine_samples=0)
    with pytest.raises(InputError, match="NaN"):
        fit_composite(np.array([1.0, np.nan] * 100), FS)


def test_profile_intervals_of_a_fit_at_its_bounds_raise_no_numpy_warnings():
    """100 quantised white-noise samples: the fit ends at both search bounds, where the likelihood is flat
    along one coordinate (zero curvature) and undefined at some profile points (nll = inf). These used to
    reach the user as RuntimeWarnings (divide by zero, inf - inf); pyproject turns RuntimeWarnings from
    imustation.* into errors, so this test fails on them."""
    counts = np.round(np.random.default_rng(2).normal(0.0, 1e-3, 100) / 2e-3).astype(np.int16)
    res = fit_composite(counts, 100.0, "wn+gm", scale=2e-3)
    assert set(res.at_bound) == {"sigma_b", "tau_b"} and not res.converged
    for name in ("sigma_b", "tau_b"):
        lo, hi = res.ci90[name]
        assert not (math.isfinite(lo) and math.isfinite(hi)) or lo <= hi


def test_study_reports_mli_f_and_single_start_outcomes():
    from imustation.analysis.estimators.models.standard import StandardModel

    fits = run_study(
        StandardModel(1e-3, 1e-4, 20.0),
        records=2,
        duration_s=1500.0,
        fs_hz=FS,
        estimators=("mli-log", "gmwm", "mli-f"),
        check_starts=True,
    )
    rows = summarize(fits)
    assert {r.estimator for r in rows} == {"mli-log", "gmwm", "mli-f"}
    assert all(0 <= r.other_optimum <= 2 for r in rows)


def test_analyze_json_has_a_noise_model_block_with_the_mli_keys_plus_method(tmp_path, record):
    p = tmp_path / "x.npy"
    np.save(p, record[: int(3600 * FS)])
    res = CliRunner().invoke(cli, ["analyze", str(p), "--rate", str(FS), "--json"])
    assert res.exit_code == 0, res.output
    ch = json.loads(res.output)["channels"][0]
    # the mli keys plus method, the IEEE-952 summary and (model auto) the selection and robust intervals
    assert set(ch["noise_model"]) == set(ch["mli"]) | {"method", "ieee952", "selection", "robust", "ci90_model"}
    assert ch["noise_model"]["method"] == "ML_i-F" and ch["mli"]["estimator"] == "ML_i"
    other = CliRunner().invoke(cli, ["analyze", str(p), "--rate", str(FS), "--json", "--estimator", "gmwm"])
    assert json.loads(other.output)["channels"][0]["noise_model"]["method"] == "GMWM"
    table = CliRunner().invoke(cli, ["analyze", str(p), "--rate", str(FS), "--verbose"])
    assert "  noise_model: ML_i-F " in table.output and "  mli: ML_i " in table.output
    bad = CliRunner().invoke(cli, ["analyze", str(p), "--rate", str(FS), "--estimator", "nope"])
    assert bad.exit_code == 2


@pytest.mark.slow
def test_monte_carlo_coverage_of_the_intervals():
    """40 records of 2 h: every 90 % interval covers the truth 75-100 % of the time (binomial 4 sigma)."""
    from imustation.analysis.estimators.models.standard import StandardModel

    fits = run_study(StandardModel(1e-3, 5e-5, 30.0), records=40, duration_s=7200.0, fs_hz=FS, estimators=("mli-f",))
    for row in summarize(fits):
        assert 0.75 <= row.coverage90 <= 1.0, row
