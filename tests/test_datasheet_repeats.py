"""Repeated recordings from the project's own datasheet-profile simulator (issue 22, "Intervals").

The chip simulators' noise source (drivers/sim/sources.py) with the datasheet profile: the
device's output filter as its registers select it (drivers/sim/filters.py), bias instability
and rate random walk from the profile (drivers/sim/profiles.py); warm-up and temperature
coefficient off (the report's warm-up cut handles those, docs/reports.md). Truth for N is the
output's white-noise density (the profile's sigma_w times the filter's aliased gain at 0 Hz).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from imustation.analysis.estimators.selection.coefficients import ieee952_summary
from imustation.analysis.estimators.selection.model_choice import choose_model
from imustation.analysis.pipeline.devicefilter import filter_hint
from imustation.drivers.sim.filters import for_device
from imustation.drivers.sim.sources import NoiseSource

SETTINGS = {
    "bmx055": {"rate_hz": 400, "bandwidth_hz": 47},
    "adis16448": {"decimation": 1, "filter_taps": 4},
    "mpu9150": {"rate_hz": 200, "bandwidth_hz": 42},
}


def repeats(device: str, hours: float, seeds: range):
    """(choice, N/B summary, true N, true B) of one gyro axis per seed."""
    cf = for_device(device, SETTINGS[device])["gyro"]
    fs = cf.fs_out_hz
    hint = filter_hint({"driver": device, "settings": SETTINGS[device]}, fs)
    out = []
    for seed in seeds:
        sim = {"profile": "datasheet", "warmup_c": 0.0, "bias_tempco": 0.0}
        src = NoiseSource.for_device(device, "xyz", fs, sim, seed)
        src.use_filter(cf)
        x = src.next(int(hours * 3600 * fs))[:, 0]
        n_true = src.models[0].sigma_w * math.sqrt(float(cf.output_gain(np.array([0.0]))[0]))
        choice = choose_model(x, fs, hint=hint)
        out.append((choice, ieee952_summary(choice.chosen, len(x) / fs, choice.close), n_true, float(src._slow.b[0])))
    return out


@pytest.mark.parametrize("device", ["bmx055", "adis16448"])
def test_datasheet_repeats_n_within_one_percent_and_inside_the_intervals(device):
    got = repeats(device, 1.0, range(4))
    for choice, s, n_true, _ in got:
        assert "lp" in choice.chosen.model  # the device filter is found and carried
        assert s["N"] == pytest.approx(n_true, rel=0.01)
    # the one-per-decade flicker sum ripples by -2.2..+1.0 %: where the bias instability is strong
    # (ADIS16448) the adequacy test at 1 % sees it at one tau now and then (seed 1: 2.65 s)
    assert sum(choice.fits for choice, *_ in got) >= 3
    # four 90 % intervals: 2 or fewer covering happens in 5 % of sets
    assert sum(s["N_ci90"][0] <= n <= s["N_ci90"][1] for _, s, n, _ in got) >= 3
    assert sum(s["B_ci90"][0] <= b <= s["B_ci90"][1] for _, s, _, b in got) >= 3


def test_datasheet_mpu9150_gyro_is_flagged_where_it_is_not_right():
    """The MPU-9150 datasheet profile's bias instability dominates from 0.05 s (docs/noise-model.md,
    "Limit"): sigma_w is then not within 1 %; the choice must say that no model fits, the fit that
    sigma_w rests on the slow terms' shape, and N's stated interval must still hold the truth (its
    upper end reaches the bound of finescale.white_bound; before it, 3 of 4 repeats stated no
    interval and the fourth's missed the truth)."""
    for choice, s, n_true, _ in repeats("mpu9150", 1.0, range(2)):
        assert abs(s["N"] / n_true - 1.0) <= 0.01 or not choice.fits
        assert "slow terms reach the fine scales" in choice.chosen.message
        lo, hi = s["N_ci90"]
        assert lo <= n_true <= hi
        assert hi <= 1.15 * n_true  # a bound the data set, not an interval without an end
