"""Figures: every plot writes a non-empty PNG and PDF; the model curves drawn are the model's."""

from __future__ import annotations

import numpy as np
import pytest

from imustation.analysis.pipeline.channel import analyze_channel
from imustation.analysis.pipeline.loaders import load_run
from imustation.analysis.reports import plots


@pytest.fixture(scope="module")
def analysed(sim_run):
    path, _ = sim_run
    return [analyze_channel(ch, model="wn+gm") for ch in load_run(str(path))]


def _files_ok(paths):
    assert [p[-4:] for p in paths] == [".png", ".pdf"]
    with open(paths[0], "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    with open(paths[1], "rb") as fh:
        assert fh.read(5) == b"%PDF-"
    import os

    assert all(os.path.getsize(p) > 5000 for p in paths)


def test_allan_figure(analysed, tmp_path):
    res = analysed[2]
    s = plots.settings_line(res.channel, (24.5, 25.25))
    assert s.startswith("rate 400 Hz, bandwidth 47 Hz") and "duration 20m00s" in s and "24.50–25.25 °C" in s
    fig = plots.allan_figure(res, s)
    ax = fig.axes[0]
    model_line = next(ln for ln in ax.get_lines() if ln.get_label().startswith("identified"))
    tau, adev = model_line.get_data()
    np.testing.assert_allclose(adev, res.noise_model.noise_model.adev(tau, res.channel.fs_hz))
    labels = [ln.get_label() for ln in ax.get_lines()]
    assert any(lb.startswith("earth rate") for lb in labels)
    assert sum(lb.startswith(("WhiteRate", "GaussMarkov")) for lb in labels) == 2
    # every fitted value in the legend carries its unit (issue 23): display units of a gyro
    gm = next(lb for lb in labels if lb.startswith("GaussMarkov"))
    assert "°/h/√h" in gm and gm.rstrip(")").endswith(" s")
    assert "°/h/√Hz" in next(lb for lb in labels if lb.startswith("WhiteRate"))
    assert ax.get_ylabel() == "Allan deviation [rad/s]"
    _files_ok(plots.save_figure(fig, tmp_path / "allan"))


def test_accelerometer_figures_carry_accelerometer_units():
    from imustation.analysis.pipeline.loaders import Channel

    rng = np.random.default_rng(3)
    res = analyze_channel(Channel("imu/accel/x", 100.0, "m/s^2", 9.8 + rng.normal(0, 7e-3, 20_000)))
    ax = plots.allan_figure(res).axes[0]
    labels = [ln.get_label() for ln in ax.get_lines()]
    assert ax.get_ylabel() == "Allan deviation [m/s²]" and not any("earth rate" in lb for lb in labels)
    assert "µg/√Hz" in next(lb for lb in labels if lb.startswith("WhiteRate"))
    assert all("°" not in lb for lb in labels)
    assert plots.attitude_figure(res).axes[0].get_ylabel() == "angle error std [m/s]"


def test_multi_psd_temperature(analysed, tmp_path):
    _files_ok(plots.save_figure(plots.allan_multi_figure(analysed), tmp_path / "multi"))
    res = analysed[2]
    fig = plots.psd_figure(res, "s")
    line = next(ln for ln in fig.axes[0].get_lines() if ln.get_label().startswith("identified"))
    f, p = line.get_data()
    assert f[-1] == pytest.approx(200.0)
    np.testing.assert_allclose(p, res.noise_model.noise_model.psd(f, 400.0))
    _files_ok(plots.save_figure(fig, tmp_path / "psd"))
    rate = res.channel.rate()
    bt, b = plots.bias_track(rate, 400.0, 60.0)
    assert len(b) == 20 and b[0] == pytest.approx(rate[:24000].mean())
    t = np.linspace(0, 1200, 50)
    fig = plots.temperature_figure(
        t, 25 + 0.1 * np.sin(t / 200), [("z", bt, b)], label="d", bias_unit="rad/s", warmup_s=1
    )
    _files_ok(plots.save_figure(fig, tmp_path / "temp"))


def test_attitude_figure(analysed, tmp_path):
    from imustation.analysis.reports.attitude import angle_error_std

    res = analysed[0]
    fig = plots.attitude_figure(res, "s")
    line = next(ln for ln in fig.axes[0].get_lines() if "record mean" in ln.get_label())
    t, s = line.get_data()
    np.testing.assert_allclose(s, angle_error_std(res.noise_model.noise_model, t, record_s=1200.0))
    assert t[-1] == pytest.approx(1200.0 / 10, rel=1e-6)
    _files_ok(plots.save_figure(fig, tmp_path / "att"))


def test_a_term_at_its_search_bound_says_so_in_the_legend():
    from imustation.analysis.pipeline.loaders import Channel

    x = np.random.default_rng(1).normal(0, 1e-3, 2000)
    res = analyze_channel(Channel("fog/gyro/z", 100.0, "rad/s", x), model="wn+gm")  # the paper's model
    assert "tau_b" in res.noise_model.at_bound
    labels = [ln.get_label() for ln in plots.allan_figure(res).axes[0].get_lines()]
    gm = next(lb for lb in labels if lb.startswith("GaussMarkov"))
    assert "tau_b at bound (" in gm and "sigma_b at bound" not in gm


def test_a_device_filter_term_is_not_drawn_and_leaks_no_warning():
    # a lab-realistic report ended with numpy's 'RuntimeWarning: invalid value encountered in sqrt' from the
    # dashed curve of a wn+fl+lp model's lp term, a variance deficit (second newcomer run, issue 34)
    import warnings

    from imustation.analysis.estimators.models.noise_models import WhiteRate
    from imustation.analysis.estimators.models.sensor_terms import LowPass
    from imustation.analysis.reports.plots import term_adev

    tau = np.logspace(-2, 3, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lp = term_adev(LowPass(1e-4, 0.005), tau)
        wn = term_adev(WhiteRate(1e-4), tau)
    assert np.isnan(lp).all()
    np.testing.assert_allclose(wn, 1e-4 / np.sqrt(tau))
