"""A bias instability whose 1/f spectrum stops below the sampling rate (IEEE 952's cut-off f0, issue 22).

The uncut sum of sensor_terms adds flicker down to the sample time; a sensor (or a
simulator) whose flicker starts at a few tenths of a second then "does not fit"
between 0.02 and 5 s although N and B are right. The model choice refits such a
model with a cut-off (model_choice.try_cuts / screen_cut).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from imustation.analysis.estimators.engine.paramspec import ParamSpec
from imustation.analysis.estimators.models.noise_models import NoiseModel, WhiteRate
from imustation.analysis.estimators.models.sensor_terms import (
    FLICKER_FLOOR,
    BiasInstability,
    flicker_times,
    flicker_weights,
)
from imustation.analysis.estimators.selection.model_choice import choose_model, flicker_cut, flicker_cuts


def test_a_cut_at_a_decade_is_the_sum_started_there():
    times = flicker_times(400.0, 43200.0, 0.1)
    assert times[0] == pytest.approx(0.01) and times[-1] == pytest.approx(1e6)
    w = flicker_weights(times, 0.1)
    assert w[0] == 0.0  # the decade below carries no share at an exact decade
    np.testing.assert_allclose(w[1:], flicker_weights(times[1:]), rtol=1e-12)
    tau = np.logspace(-2, 4, 60)
    cut = BiasInstability(1.0, times, 0.1).avar(tau, 400.0)
    started = BiasInstability(1.0, times[1:]).avar(tau, 400.0)
    np.testing.assert_allclose(cut, started, rtol=1e-12)


def test_the_cut_sum_falls_below_the_floor_only_below_its_cut_off():
    tau = np.logspace(-2.5, 3, 200)
    full = np.sqrt(BiasInstability(1.0, flicker_times(400.0, 43200.0)).avar(tau, 400.0))
    curves = {c: np.sqrt(BiasInstability(1.0, flicker_times(400.0, 43200.0, c), c).avar(tau, 400.0)) for c in
              (0.1, 0.3, 1.0)}  # fmt: skip
    # a later cut-off removes more: the curves are ordered at every tau, and continuous in the cut-off
    assert np.all(curves[1.0] <= curves[0.3] + 1e-15) and np.all(curves[0.3] <= curves[0.1] + 1e-15)
    assert np.all(curves[0.1] <= full + 1e-15)
    # far above the cut-off the floor is the uncut sum's (within its stated error of 0.664 B)
    far = tau > 100 * 0.3
    assert np.all(np.abs(curves[0.3][far] / FLICKER_FLOOR - 1) < 0.03)
    # well below it the flicker is mostly gone
    assert curves[0.3][tau < 0.01].max() < 0.3 * FLICKER_FLOOR


def test_the_layout_carries_the_cut_off_into_the_likelihood_and_the_model():
    spec = ParamSpec.for_record("wn+fl", 100.0, 7200.0, 0.3)
    assert spec.flicker_cut_s == 0.3 and spec.flicker_times[0] == pytest.approx(0.1)
    theta = np.array([[math.log(1.0)]])
    taus = np.array([0.05, 0.3, 3.0, 30.0])
    model = spec.model(np.array([0.0, 0.0]), 0.0)
    np.testing.assert_allclose(spec.unit_avar(theta, taus, 100.0)[0], model.avar(taus, 100.0), rtol=1e-9)
    assert flicker_cut(type("R", (), {"noise_model": model})()) == 0.3


def test_cut_offs_tried_are_two_per_decade_up_to_one_second():
    cuts = flicker_cuts(400.0, 43200.0)
    np.testing.assert_allclose(cuts, 10.0 ** (np.arange(-5, 1) / 2.0))
    assert flicker_cuts(1.0, 43200.0) == [] and flicker_cuts(0.2, 43200.0) == []  # the sum starts at 1 s or later


def test_without_cut_offs_to_try_the_choice_goes_on_uncut(monkeypatch):
    """A record sampled at 1 Hz or slower has no cut-off to try (its sum starts at 1 s)."""
    from imustation.analysis.estimators.selection import model_choice

    monkeypatch.setattr(model_choice, "flicker_cuts", lambda fs, duration: [])
    fs = 100.0
    truth = NoiseModel((WhiteRate(1e-3), BiasInstability(1e-3, flicker_times(fs, 7200.0, 0.3), 0.3)))
    choice = choose_model(truth.simulate(int(7200 * fs), fs, 2), fs, paper=False)
    assert all(c.cut_s == 0.0 for c in choice.candidates) and not choice.fits


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_flicker_cut_off_at_0_3_s_is_found_and_the_model_then_fits(seed):
    """White noise 1e-3 and a bias instability of 1e-3 starting at 0.3 s, 2 h at 100 Hz: the uncut
    sum does not fit (it adds flicker from 0.01 s on); the choice refits with a cut-off near the
    truth and that model fits, with N and B right."""
    fs, sigma_w, B = 100.0, 1e-3, 1e-3
    truth = NoiseModel((WhiteRate(sigma_w), BiasInstability(B, flicker_times(fs, 7200.0, 0.3), 0.3)))
    x = truth.simulate(int(7200 * fs), fs, seed)
    choice = choose_model(x, fs, paper=False)
    uncut = next(c for c in choice.candidates if c.result.model == "wn+fl" and not c.cut_s)
    assert not uncut.passes and any(m.tau_lo < 1.0 for m in uncut.check.misfit)
    assert choice.fits and "fl" in choice.chosen.model.split("+")
    assert 0.1 <= flicker_cut(choice.chosen) <= 0.32
    assert "cut off below" in choice.reason
    assert choice.selection_dict()["flicker_cut_s"] == flicker_cut(choice.chosen)
    assert choice.chosen.sigma_w == pytest.approx(sigma_w, rel=0.01)
    lo, hi = choice.chosen.ci90["B"]
    assert lo <= B <= hi


def test_an_uncut_flicker_that_fits_is_not_cut():
    fs = 100.0
    truth = NoiseModel((WhiteRate(1e-3), BiasInstability(3e-4, flicker_times(fs, 7200.0))))
    choice = choose_model(truth.simulate(int(7200 * fs), fs, 4), fs, paper=False)
    assert choice.fits and flicker_cut(choice.chosen) == 0.0
    assert all(c.cut_s == 0.0 for c in choice.candidates)


def test_fleet_takes_a_models_fit_that_passes_whether_cut_or_not():
    """A run's model fitted with and without a cut-off is one model for the fleet: the fit that passes."""
    from types import SimpleNamespace as NS

    from imustation.analysis.pipeline.fleet import by_model

    def cand(model, bic, passes, converged=True):
        return NS(result=NS(model=model, bic=bic, converged=converged), passes=passes)

    uncut, cut = cand("wn+fl+rw", 100.0, False), cand("wn+fl+rw", 100.4, True)
    other = cand("wn+gm", 90.0, False)
    unconverged = cand("wn+gm+fl", 50.0, True, converged=False)
    got = by_model([other, uncut, cut, unconverged])
    assert got == {"wn+fl+rw": cut, "wn+gm": other}
    # none passes: the smallest BIC
    assert by_model([uncut, cand("wn+fl+rw", 101.0, False)])["wn+fl+rw"] is uncut
