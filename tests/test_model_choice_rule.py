"""The stage walk of ``--model auto`` with scripted fits and verdicts (issue 22, "Models ... chosen
automatically"): the rule of analysis/estimators/selection/model_choice.py on its own, without depending
on what a record happens to give.

The fits and the adequacy verdicts are replaced by a script (BIC and "fits" per model name);
the integration, the fine scales and the start points run as usual on a short white record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pytest

from imustation.analysis.estimators.selection import model_choice
from imustation.analysis.estimators.selection.adequacy import FITS, NO_FIT


@dataclass(frozen=True)
class ScriptedFit:
    """What the choice reads of a fit."""

    model: str
    bic: float
    converged: bool = True
    sigma_w: float = 1.0
    k: int = 2
    memory_s: float = 0.0
    message: str = "scripted"
    phi: np.ndarray | None = None
    params: dict = field(default_factory=dict)
    ci90: dict = field(default_factory=dict)
    noise_model: SimpleNamespace = field(default_factory=lambda: SimpleNamespace(terms=()))


def scripted_choice(monkeypatch, script: dict[str, tuple[float, bool]]):
    """choose_model on a white record with each candidate's (BIC, fits) taken from ``script``
    (bias structure -> values; a structure not in the script does not converge)."""

    def fake_fit(inc, fine, spec, **kwargs):
        bias = model_choice._bias_of(spec.name).replace("gm+gm", "2gm")
        bic, _ = script.get(bias, (math.inf, False))
        return ScriptedFit(spec.name, bic, converged=bias in script)

    def fake_check(allan, res, fs_hz, lengths):
        fits = script[model_choice._bias_of(res.model).replace("gm+gm", "2gm")][1]
        # a misfit far beyond any flicker cut-off: no cut-off is tried
        misfit = () if fits else (SimpleNamespace(tau_lo=1e6),)
        return SimpleNamespace(verdict=FITS if fits else NO_FIT, misfit=misfit, p_value=0.5, summary=lambda: "scripted")

    monkeypatch.setattr(model_choice, "fit_composite_data", fake_fit)
    monkeypatch.setattr(model_choice, "fit_adequacy", fake_check)
    x = np.random.default_rng(0).normal(0.0, 1e-3, 18000)
    return model_choice.choose_model(x, 10.0, paper=False)


def test_a_larger_model_that_fits_is_chosen_when_nothing_smaller_fits_even_without_a_lower_bic(monkeypatch):
    # stage 1: nothing fits, gm has the smallest BIC; stage 2: gm+fl fits with a BIC 4 above it.
    # "The first stage with a model that fits gives the choice": gm+fl, and it fits. (The walk used
    # to stop at stage 2 because its BIC was not 10 below stage 1's, reporting gm as "no model fits";
    # measured on the 12 h bench lab's ADIS16448 accelerometer x.)
    script = {"gm": (100.0, False), "fl": (120.0, False), "rw": (102.0, False),
              "gm+rw": (105.0, False), "gm+fl": (104.0, True), "2gm": (110.0, False),
              "gm+fl+rw": (109.0, True), "2gm+rw": (115.0, False)}  # fmt: skip
    choice = scripted_choice(monkeypatch, script)
    assert choice.fits
    assert model_choice._bias_of(choice.chosen.model) == "gm+fl"
    # its extension fits too but does not lower the BIC by 10: kept as a close model, not chosen
    assert [model_choice._bias_of(r.model) for r in choice.close] == ["gm+fl+rw"]


def test_without_any_model_that_fits_the_walk_stops_when_a_larger_model_does_not_help(monkeypatch):
    script = {"gm": (100.0, False), "fl": (120.0, False), "rw": (102.0, False),
              "gm+rw": (105.0, False), "gm+fl": (104.0, False), "2gm": (110.0, False),
              "gm+fl+rw": (50.0, True), "2gm+rw": (115.0, False)}  # fmt: skip
    choice = scripted_choice(monkeypatch, script)
    assert not choice.fits
    assert model_choice._bias_of(choice.chosen.model) == "gm"
    # stage 3 is not fitted: stage 2 did not lower the BIC by 10
    assert all(c.stage <= 2 for c in choice.candidates)
    assert "no model of the family fits" in choice.reason


@pytest.mark.parametrize("gain, chosen", [(9.0, "gm"), (11.0, "gm+rw")])
def test_a_model_that_fits_is_replaced_only_by_a_bic_lower_by_more_than_ten(monkeypatch, gain, chosen):
    script = {"gm": (100.0, True), "fl": (105.0, False), "rw": (130.0, False),
              "gm+rw": (100.0 - gain, True), "gm+fl": (98.0, False), "2gm": (99.0, True),
              "gm+fl+rw": (95.0, False), "2gm+rw": (98.0, False)}  # fmt: skip
    choice = scripted_choice(monkeypatch, script)
    assert choice.fits and model_choice._bias_of(choice.chosen.model) == chosen
