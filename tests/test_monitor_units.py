"""The monitor's overlay carries the units of its fitted values and says which ended at a bound (issue 23)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imustation.monitor.live_allan import GyroBuffer, allan_curves, model_curves, parameter_units


def test_overlay_values_have_units_and_bound_flags():
    rng = np.random.default_rng(5)
    fs, scale = 100.0, 1e-4
    counts = np.round(rng.normal(0, 1.7e-4 * math.sqrt(fs), (20_000, 3)) / scale).astype(np.int16)
    buf = GyroBuffer(fs, scale, counts.dtype, ("x", "y", "z"))
    buf.append(counts)
    snap = buf.snapshot()
    curves = allan_curves(snap)
    model = model_curves(snap, np.asarray(curves["tau"]))
    units = model["units"]
    assert units == parameter_units("gyro")
    assert units["sigma_w"]["si"] == "rad/s/√Hz" and units["sigma_w"]["display"] == "°/h/√Hz"
    assert units["sigma_w"]["factor"] == pytest.approx(180 / math.pi * 3600)
    assert units["sigma_b"]["display"] == "°/h/√h" and units["tau_b"]["si"] == "s"
    for axis in "xyz":
        m = model["axes"][axis]
        assert isinstance(m["at_bound"], list) and set(m["at_bound"]) <= {"sigma_b", "tau_b"}
        assert not (m["at_bound"] and m["converged"])  # a fit at a bound is not converged
    # white noise alone: the bias term has nothing to fit, at least one axis ends at a bound and says so
    assert any(model["axes"][a]["at_bound"] for a in "xyz")
    assert parameter_units("accel")["sigma_w"]["display"] == "µg/√Hz"
