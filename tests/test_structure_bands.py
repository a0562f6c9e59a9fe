"""B's and K's intervals where they rest on the model's structure (issue 32): the Allan curve read as a
flicker floor and a walk takes them in when the chosen model does not fit, or when its walk leads only at
the record's last octaves."""

from __future__ import annotations

import math

import numpy as np

from imustation.analysis.estimators.classical.allan import oadev
from imustation.analysis.estimators.classical.allan_bounds import b_band, b_upper, k_band, with_bounds
from tests.realistic_records import flicker

FS = 200.0
N_TRUE, B_TRUE, K_TRUE = 8.7e-5, 5.7e-4, 2e-5  # the MPU-9150 datasheet gyro: the flicker leads from 0.1 s


def _record(hours: float, seed: int, B: float = B_TRUE, K: float = K_TRUE) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 * FS)
    x = rng.normal(0.0, N_TRUE * math.sqrt(FS), n) + flicker(n, FS, B, rng)
    return x + np.cumsum(rng.normal(0.0, K / math.sqrt(FS), n))


def test_b_is_read_from_the_flat_floor_not_below_the_flicker_corner():
    """The simulators' flicker starts at 0.25 s: read at 0.13 s the bound was 0.93 B (1 h MPU-9150 gyro x)."""
    held = 0
    for seed in range(3):
        allan = oadev(_record(0.5, seed), FS)
        held += b_upper(allan).value >= B_TRUE
        lo, hi = b_band(allan, 1.01 * N_TRUE, 1.5 * K_TRUE)
        assert lo <= B_TRUE <= hi and hi / lo < 1.3
    assert held == 3


def test_a_model_that_does_not_fit_gets_b_s_interval_widened_to_the_floor():
    allan = oadev(_record(0.5, 7), FS)
    # what wn+2gm+rw stated on the 1 h MPU-9150 gyro x: B from its dipping floor, -26 % with [-31, -21] %
    summary = {"N": N_TRUE, "N_ci90": [0.7 * N_TRUE, 1.08 * N_TRUE], "B": 0.74 * B_TRUE,
               "B_ci90": [0.69 * B_TRUE, 0.79 * B_TRUE], "B_from": "model floor", "K": None, "K_ci90": None,
               "gauss_markov": [{"sigma_b": 1e-4, "tau_b": 10.0}]}  # fmt: skip
    fits = with_bounds(summary, allan)
    assert fits["B_ci90"] == summary["B_ci90"] and fits["B_widened"] is None
    assert fits["B_band90"][0] <= B_TRUE <= fits["B_band90"][1]
    no_fit = with_bounds(summary, allan, model_fits=False)
    lo, hi = no_fit["B_ci90"]
    assert lo <= no_fit["B"] <= hi and lo <= B_TRUE <= hi and "does not fit" in no_fit["B_widened"]


def _walk_summary(k: float, start: float) -> dict:
    return {"N": N_TRUE, "N_ci90": [0.99 * N_TRUE, 1.01 * N_TRUE], "B": 4.85e-5, "B_ci90": [4.4e-5, 5.3e-5],
            "B_from": "fitted", "gauss_markov": [], "K": k, "K_ci90": [0.63 * k, 1.58 * k],
            "K_from_tau_s": start}  # fmt: skip


def test_a_walk_seen_only_at_the_last_octaves_gets_the_curve_s_interval():
    """The 2 h BMX055 datasheet gyro y: K +77 % with [+11, +180] %, the walk leading from 320 s on."""
    b, hours = 4.85e-5, 1.0
    k = 0.0383 * b  # K^2 tau / 3 = 0.441 B^2 at 900 s: the walk leads the last two octaves of the hour
    rng = np.random.default_rng(11)
    n = int(hours * 3600 * FS)
    x = rng.normal(0.0, N_TRUE * math.sqrt(FS), n) + flicker(n, FS, b, rng)
    allan = oadev(x + np.cumsum(rng.normal(0.0, k / math.sqrt(FS), n)), FS)
    lo, hi = k_band(allan, 1.01 * N_TRUE, 5.3e-5)
    assert lo <= k <= hi
    late = with_bounds(_walk_summary(1.77 * k, 900.0), allan)  # the realised walk read 77 % high
    assert late["K_ci90"][0] <= k <= late["K_ci90"][1] and "degrees of freedom" in late["K_widened"]
    early = with_bounds(_walk_summary(1.77 * k, 2.0), allan)  # a walk leading from 2 s: the likelihood's interval
    assert early["K_ci90"] == [0.63 * 1.77 * k, 1.58 * 1.77 * k] and early["K_widened"] is None


def test_a_barely_seen_walk_is_judged_by_its_bound_as_an_undetected_one():
    """Repeats of one device: a walk detected at the record's last clusters (a wide interval: 'not enough')
    and one not detected (its bound) gave two verdicts to one sensor."""
    from imustation.analysis.pipeline.verdict import IEEE_NEED, data_verdict, ieee_intervals

    base = {"N": 1e-3, "N_ci90": [0.99e-3, 1.01e-3], "B": 2e-5, "B_ci90": [1.8e-5, 2.2e-5], "B_detected": True,
            "K_upper90": 4e-7}  # fmt: skip
    seen = base | {"K": 2e-7, "K_ci90": [2e-8, 6e-7], "K_detected": True, "K_widened": "the walk leads ..."}
    unseen = base | {"K": None, "K_ci90": None, "K_detected": False}
    verdicts = []
    for summary in (seen, unseen):
        iv = ieee_intervals(summary, IEEE_NEED)
        v = data_verdict(7200.0, math.inf, 300.0, intervals=iv, need=IEEE_NEED, judge_tau_b=False)
        verdicts.append(v.verdict)
    assert verdicts == ["enough", "enough"]
    iv = ieee_intervals(seen, IEEE_NEED)["K"]
    assert iv.upper == 6e-7 and iv.note == "barely detected"
    # a walk the likelihood pins down is still judged by its interval
    pinned = ieee_intervals(base | {"K": 2e-7, "K_ci90": [1.5e-7, 2.6e-7], "K_detected": True}, IEEE_NEED)["K"]
    assert pinned.lo == 1.5e-7 and math.isnan(pinned.upper)


def test_a_close_model_that_only_adds_a_walk_is_not_another_structure():
    from dataclasses import replace as dc_replace

    from imustation.analysis.estimators.selection.model_choice import choose_model

    rng = np.random.default_rng(21)
    n = int(0.25 * 3600 * FS)
    choice = choose_model(rng.normal(0.0, 1e-3 * math.sqrt(FS), n) + flicker(n, FS, 2e-5, rng), FS)
    chosen = dc_replace(choice.chosen, model="wn+fl")
    same = dc_replace(choice, chosen=chosen, close=(dc_replace(chosen, model="wn+fl+rw"),))
    assert same.indistinct() is None
    other = dc_replace(same, close=(dc_replace(chosen, model="wn+gm+rw"),))
    assert "cannot tell wn+fl from wn+gm+rw" in other.indistinct()


def test_an_end_too_large_to_square_leaves_nothing_of_the_curve_not_an_overflow():
    """A fit on a cut bag gave K's upper end 1e200: squaring it as a Python float raised OverflowError out
    of ``analyze`` (found by the fuzz corpus, one-bz2-cut.bag with --estimator gmwm); such an end takes the
    whole curve, so the other term's lower end is 0 and its upper end stands."""
    allan = oadev(_record(0.1, 3), FS)
    lo, hi = b_band(allan, 1.01 * N_TRUE, 1e200)
    assert lo == 0.0 and math.isfinite(hi) and hi > 0
    lo, hi = k_band(allan, 1e200, B_TRUE)
    assert lo == 0.0 and math.isfinite(hi) and hi > 0
