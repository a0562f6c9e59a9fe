"""Exports for Kalibr / OpenVINS / VINS-Fusion / ORB-SLAM3 (docs/reference/noise-formulas.md §3)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from imustation.analysis.estimators.models.noise_models import GaussMarkov, NoiseModel, RandomWalk, WhiteRate
from imustation.analysis.pipeline.channel import analyze_channel
from imustation.analysis.pipeline.loaders import Channel
from imustation.analysis.reports.export import (
    AxisNoise,
    SensorNoise,
    axis_noise,
    export_dict,
    export_text,
    gm_to_rw_at_tau_b,
    random_walk_from_params,
)
from imustation.cli import cli
from imustation.drivers.sim import simulated_truth

KALIBR_KEYS = [
    "rostopic",
    "update_rate",
    "accelerometer_noise_density",
    "accelerometer_random_walk",
    "gyroscope_noise_density",
    "gyroscope_random_walk",
]


def _load(text: str) -> dict:
    """Parse with PyYAML; the OpenCV ``%YAML:1.0`` directive is not YAML 1.1, so drop it first."""
    if text.startswith("%YAML:1.0"):
        text = text.split("\n", 1)[1]
    return yaml.safe_load(text)


def _sensors():
    gyro = SensorNoise(
        "gyro", 200.0, (AxisNoise("d/gyro/x", 1.6968e-4, 1.9393e-5), AxisNoise("d/gyro/y", 1.2e-4, 1e-5)), "mli", "x"
    )
    accel = SensorNoise("accel", 200.0, (AxisNoise("d/accel/x", 2.0e-3, 3.0e-3),), "mli", "x")
    return gyro, accel


def test_kalibr_keys_and_values_round_trip():
    # EuRoC ADIS16448 values (docs/reference/noise-formulas.md §3.1) must come back unchanged, as the largest axis
    gyro, accel = _sensors()
    d = _load(export_text(gyro, accel, "kalibr", topic="/imu0"))
    assert list(d) == KALIBR_KEYS
    assert d["rostopic"] == "/imu0" and d["update_rate"] == 200.0
    assert d["gyroscope_noise_density"] == pytest.approx(1.6968e-4, rel=1e-6)
    assert d["gyroscope_random_walk"] == pytest.approx(1.9393e-5, rel=1e-6)
    assert d["accelerometer_noise_density"] == pytest.approx(2.0e-3, rel=1e-6)
    assert d["accelerometer_random_walk"] == pytest.approx(3.0e-3, rel=1e-6)
    assert all(isinstance(d[k], float) for k in KALIBR_KEYS[1:])


def test_other_formats_keys():
    gyro, accel = _sensors()
    ov = _load(export_text(gyro, accel, "openvins"))
    assert set(KALIBR_KEYS) <= set(ov["imu0"]) and ov["imu0"]["gyroscope_noise_density"] == pytest.approx(1.6968e-4)
    vins = _load(export_text(gyro, accel, "vins"))
    assert vins["gyr_n"] == pytest.approx(1.6968e-4) and vins["acc_w"] == pytest.approx(3.0e-3)
    assert {"imu", "imu_topic", "acc_n", "acc_w", "gyr_n", "gyr_w", "g_norm"} == set(vins)
    orb = _load(export_text(gyro, accel, "orbslam3"))
    assert orb == {
        "IMU.NoiseGyro": pytest.approx(1.6968e-4),
        "IMU.NoiseAcc": pytest.approx(2.0e-3),
        "IMU.GyroWalk": pytest.approx(1.9393e-5),
        "IMU.AccWalk": pytest.approx(3.0e-3),
        "IMU.Frequency": 200,
    }
    for fmt in ("openvins", "vins", "orbslam3"):
        assert export_text(gyro, accel, fmt).startswith("%YAML:1.0\n")  # cv::FileStorage files


def test_inflation_is_explicit_and_both_values_are_written():
    from imustation.analysis.reports.export import inflate_sensors, parse_inflation
    from imustation.errors import InputError

    gyro, accel = _sensors()
    assert parse_inflation("10") == (10.0, 10.0) and parse_inflation("10, 4") == (10.0, 4.0)
    for bad in ("0.5", "ten", "1,2,3", "nan"):
        with pytest.raises(InputError, match="--inflate"):
            parse_inflation(bad)
    g10, a10 = inflate_sensors(gyro, accel, 10.0, 20.0)
    text = export_text(g10, a10, "orbslam3")
    d = _load(text)
    assert d["IMU.NoiseGyro"] == pytest.approx(1.6968e-3, rel=1e-6) and d["IMU.GyroWalk"] == pytest.approx(3.8786e-4)
    assert d["IMU.NoiseAcc"] == pytest.approx(2.0e-2, rel=1e-6) and d["IMU.AccWalk"] == pytest.approx(6.0e-2)
    assert "# INFLATED gyro: noise density x10, random walk x20 (--inflate); measured 1.6968e-04, 1.9393e-05" in text
    assert "#   d/gyro/x: 1.6968e-04, 1.9393e-05" in text  # the per-axis lines are the measured values
    assert "INFLATED" not in export_text(gyro, accel, "orbslam3")


def test_gyro_only_leaves_accel_keys_out():
    gyro, _ = _sensors()
    d = export_dict(gyro, None, "kalibr")
    assert "accelerometer_noise_density" not in d and d["gyroscope_noise_density"] == 1.6968e-4


def test_diffusion_conversion_bounds_gm_at_every_tau():
    # K = sigma_b: equal AVAR slope for tau << tau_b, never below the GM (IEEE 952 closed forms)
    gm = GaussMarkov(2e-6, 500.0)
    K = random_walk_from_params({"sigma_w": 1e-4, "sigma_b": 2e-6, "tau_b": 500.0})
    assert K == 2e-6
    tau = np.logspace(-2, 5, 200)
    rw = RandomWalk(K).avar(tau)
    assert np.all(rw >= gm.avar(tau))
    assert gm.avar(np.array([0.01]))[0] == pytest.approx(rw[0], rel=1e-4)


def test_tau_b_conversion_matches_adev_at_tau_b():
    # independent closed form: AVAR_GM(T) = q T [1 - (3 - 4/e + 1/e^2)/2] (docs/reference/noise-formulas.md §5)
    sigma_b, T = 2e-6, 500.0
    K = random_walk_from_params({"sigma_b": sigma_b, "tau_b": T}, "tau_b")
    ratio2 = 3.0 * (1.0 - (3.0 - 4.0 * math.exp(-1.0) + math.exp(-2.0)) / 2.0)
    assert K == pytest.approx(sigma_b * math.sqrt(ratio2), rel=1e-12)
    assert K / sigma_b == pytest.approx(0.710, abs=1e-3)
    assert RandomWalk(K).avar(np.array([T]))[0] == pytest.approx(GaussMarkov(sigma_b, T).avar(np.array([T]))[0])
    assert gm_to_rw_at_tau_b(sigma_b, T) == K
    # a random-walk term passes through; terms add in variance
    assert random_walk_from_params({"sigma_k": 3e-6, "sigma_b": 4e-6, "tau_b": math.inf}) == pytest.approx(5e-6)


@pytest.fixture(scope="module")
def wn_rw_analysis():
    """White + rate random walk, 2000 s at 200 Hz: both the Allan fit and ML_i see N and K."""
    fs, N, K = 200.0, 1.7e-4, 2e-5
    rate = NoiseModel((WhiteRate(N), RandomWalk(K))).simulate(int(2000 * fs), fs, seed=3)
    return analyze_channel(Channel("sim/gyro/x", fs, "rad/s", rate), model="wn+rw"), N, K


def test_sigma_g_is_N_and_sigma_bg_is_K(wn_rw_analysis):
    res, N, K = wn_rw_analysis
    ieee = axis_noise(res, "ieee")
    assert ieee.noise_density == res.ieee.N and ieee.random_walk == res.ieee.K  # not N*sqrt(rate), not K/sqrt 3
    mli = axis_noise(res, "mli")
    assert mli.noise_density == res.mli.sigma_w and mli.random_walk == res.mli.params["sigma_k"]
    # and both estimate the simulated densities (tolerances: a few standard errors of each estimator)
    assert ieee.noise_density == pytest.approx(N, rel=0.05) and mli.noise_density == pytest.approx(N, rel=0.02)
    assert ieee.random_walk == pytest.approx(K, rel=0.5) and mli.random_walk == pytest.approx(K, rel=0.5)


def test_cli_export_sim_run(sim_run, demo_config, tmp_path):
    path, _ = sim_run
    out = tmp_path / "imu.yaml"
    runner = CliRunner()
    r = runner.invoke(cli, ["export", str(path), "--format", "kalibr", "--gyro-only", "-o", str(out)])
    assert r.exit_code == 0, r.output
    d = yaml.safe_load(out.read_text())
    assert d["update_rate"] == 400.0 and d["rostopic"] == "/imu0"
    truth = simulated_truth(demo_config)
    # the largest simulated sigma_w of the three axes, recovered by ML_i within a few percent
    sw = max(truth[f"bmx055/gyro/{a}"].sigma_w for a in "xyz")
    assert d["gyroscope_noise_density"] == pytest.approx(sw, rel=0.05)
    assert d["gyroscope_random_walk"] > 0
    # without an accelerometer the export refuses rather than writing a file Kalibr would reject
    r = runner.invoke(cli, ["export", str(path), "--format", "kalibr"])
    assert r.exit_code == 2 and "no accelerometer channels" in r.output
    # inflated on request only: the values written are x10 / x5, the measured ones stay in the comments
    big = tmp_path / "inflated.yaml"
    r = runner.invoke(
        cli, ["export", str(path), "--format", "kalibr", "--gyro-only", "-o", str(big), "--inflate", "10,5"]
    )
    assert r.exit_code == 0, r.output
    assert "inflated gyro: noise density" in r.stderr
    text = big.read_text()
    di = yaml.safe_load(text)
    assert di["gyroscope_noise_density"] == pytest.approx(10 * d["gyroscope_noise_density"], rel=1e-5)
    assert di["gyroscope_random_walk"] == pytest.approx(5 * d["gyroscope_random_walk"], rel=1e-5)
    assert "# INFLATED gyro: noise density x10, random walk x5" in text
    assert f"measured {d['gyroscope_noise_density']:.4e}" in text
    assert "INFLATED" not in out.read_text()  # never silently


def test_short_record_random_walk_is_flagged(tmp_path, demo_config):
    # 30 s of the demo BMX055: far too short for its bias (tau_b ~ 10^3 s); the export says so
    from imustation.acquisition import capture

    path = tmp_path / "short.h5"
    capture(demo_config, path, 30.0, simulate=True)
    out = tmp_path / "k.yaml"
    # no axis's bias fit vouches for a random walk: nothing written, exit 2, the axes named with why
    r = CliRunner().invoke(cli, ["export", str(path), "--format", "kalibr", "--gyro-only", "-o", str(out)])
    assert r.exit_code == 2 and not out.exists()
    (line,) = [ln for ln in r.stderr.splitlines() if ln.startswith("imustation: error:")]
    assert "nothing written" in line and "gyro random walk" in line and "--force" in line
    assert all(f"bmx055/gyro/{a}: " in line for a in "xyz"), line
    # --force writes it, marked in the file and flagged per axis
    r = CliRunner().invoke(cli, ["export", str(path), "--format", "kalibr", "--gyro-only", "--force"])
    assert r.exit_code == 0, r.output
    assert "#   FORCED gyro random walk: the largest of every axis (x, y, z)" in r.output
    flagged = [ln for ln in r.output.splitlines() if ln.startswith("#   WARNING")]
    assert flagged, r.output


def test_cli_random_walk_conversions_differ_by_the_closed_form(sim_run):
    # the demo's x axis is fitted with a finite tau_b: 'tau_b' gives 0.710 x the 'diffusion' figure
    path, _ = sim_run
    runner = CliRunner()
    vals = {}
    for rw in ("diffusion", "tau_b"):
        args = ["export", str(path), "--format", "vins", "--gyro-only", "--random-walk", rw, "--model", "wn+gm"]
        r = runner.invoke(cli, args)
        assert r.exit_code == 0, r.output
        x = next(ln for ln in r.output.splitlines() if ln.startswith("#   bmx055/gyro/x:"))
        vals[rw] = float(x.split(",")[1])
    ratio = math.sqrt(3.0 * (1.0 - (3.0 - 4.0 * math.exp(-1.0) + math.exp(-2.0)) / 2.0))
    assert vals["tau_b"] / vals["diffusion"] == pytest.approx(ratio, rel=1e-3)  # 4 printed digits


def test_a_noise_density_the_model_cannot_vouch_for_is_flagged(wn_rw_analysis, tmp_path):
    # the model fits and sigma_w is tight: no flag
    res, _, _ = wn_rw_analysis
    assert axis_noise(res, "model").noise_warning == ""
    # the MPU-9150 gyro of the datasheet profile (bias instability dominating from 0.05 s behind a
    # 42 Hz DLPF): no model fits and sigma_w's interval reaches the bound of finescale.white_bound
    from imustation.analysis.pipeline.devicefilter import filter_hint
    from imustation.drivers.sim.filters import for_device
    from imustation.drivers.sim.sources import NoiseSource

    settings = {"rate_hz": 200, "bandwidth_hz": 42}
    cf = for_device("mpu9150", settings)["gyro"]
    src = NoiseSource.for_device("mpu9150", "xyz", 200.0, {"profile": "datasheet", "warmup_c": 0.0}, 0)
    src.use_filter(cf)
    ch = Channel(
        "mpu/gyro/x", 200.0, "rad/s", src.next(720_000)[:, 0], meta={"driver": "mpu9150", "settings": settings}
    )
    assert filter_hint(ch.meta, 200.0).on
    a = axis_noise(analyze_channel(ch), "model")
    assert "does not fit the Allan deviation" in a.noise_warning and "90 % interval" in a.noise_warning
    gyro = SensorNoise("gyro", 200.0, (a,), "model", "diffusion")
    text = export_text(gyro, None, "kalibr")
    assert "WARNING mpu/gyro/x: noise density doubtful: the model does not fit" in text


def test_each_quantity_comes_from_the_axes_whose_fit_vouches_for_it():
    """The Kalibr case of issue 34: the y axis's fit put tau_b at 0.3 s and the 'largest axis' rule wrote its
    random walk, ~100x the others. Each quantity now comes from the axes whose fit vouches for it, the rule and
    what was left out stated in the file; nothing left: one error naming every axis and why; --force marks it."""
    from imustation.analysis.reports.export import Untrustworthy, choose_axes

    fast = "tau_b = 0.3 s < 1 s: that bias acts as white noise"
    axes = (
        AxisNoise("mpu/gyro/x", 1.6e-4, 2.1e-5),
        AxisNoise("mpu/gyro/y", 1.7e-4, 2.14e-3, warning=fast, walk_untrusted=fast),
        AxisNoise("mpu/gyro/z", 1.5e-4, 1.9e-5),
    )
    gyro = choose_axes(SensorNoise("gyro", 200.0, axes, "model", "diffusion"))
    assert gyro.random_walk == 2.1e-5 and gyro.noise_density == 1.7e-4  # y's noise density is fine
    text = export_text(gyro, None, "kalibr")
    assert yaml.safe_load(text)["gyroscope_random_walk"] == pytest.approx(2.1e-5)
    assert f"#   gyro random walk: the largest of the axes whose fit vouches for it (x, z); y left out: {fast}" in text
    assert "#   gyro noise density: the largest of the axes whose fit vouches for it (x, y, z)" in text
    bad = "the model does not fit the Allan deviation (does not fit (p<1e-4))"
    none = tuple(replace(a, noise_untrusted=bad, walk_untrusted=bad) for a in axes)
    with pytest.raises(Untrustworthy) as err:
        choose_axes(SensorNoise("gyro", 200.0, none, "model", "diffusion"))
    msg = str(err.value)
    assert "nothing written" in msg and all(f"mpu/gyro/{a}: {bad}" in msg for a in "xyz")
    forced = choose_axes(SensorNoise("gyro", 200.0, none, "model", "diffusion"), force=True)
    assert forced.forced == ("noise", "walk") and forced.random_walk == 2.14e-3
    assert "#   FORCED gyro random walk: the largest of every axis (x, y, z); no fit vouches for it" in export_text(
        forced, None, "kalibr"
    )


def test_a_sigma_b_column_never_holds_a_random_walk(wn_rw_analysis):
    """The noise table's sigma_b column held sigma_b on one axis and K (tau_b inf) on the next: a model
    without a Gauss-Markov term now shows '—' there, in the noise table and in the report's summary."""
    from imustation.analysis.reports.summary import summary_rows
    from imustation.analysis.reports.tables import NOT_FITTED, noise_rows, table_markdown

    res, _, _ = wn_rw_analysis
    assert res.noise_model.model == "wn+rw" and math.isinf(res.noise_model.tau_b)  # sigma_b is its sigma_k
    (row,) = noise_rows([res])
    assert row.flag("sigma_b") == NOT_FITTED and row.flag("tau_b") == NOT_FITTED
    cells = table_markdown([row]).split("\n\n")[1].splitlines()[-1].split(" | ")  # the main table, not the Allan fit's
    assert cells[4:7] == ["—", "—", "—"] and cells[11] not in ("—", "")  # sigma_b SI, display, tau_b; K shown
    (summary,) = summary_rows([res])
    assert summary.values["sigma_b"].flag == NOT_FITTED and summary.values["tau_b"].flag == NOT_FITTED


def test_a_random_walk_converted_from_b_says_so_beside_the_axis():
    """lab-realistic 1 h, --device mpu9150: the Kalibr file wrote gyroscope_random_walk 1.16e-4 from the z
    axis's wn+fl+lp fit (its bias instability converted) while analyze printed that axis's K as '< 397 °/h/√h'
    (3.2e-5): the file now names what the random walk is made of (second newcomer run, issue 34)."""
    from imustation.analysis.reports.export import walk_terms

    assert walk_terms({"sigma_w": 8.2e-5, "B": 1.1e-4}) == "bias instability B"
    assert walk_terms({"sigma_w": 1e-4, "sigma_k": 2e-6}) == "rate random walk K"
    assert walk_terms({"sigma_w": 1e-4, "sigma_b": 2e-6, "tau_b": 300.0, "sigma_k": 1e-7}) == (
        "rate random walk K, Gauss-Markov sigma_b"
    )
    gyro = SensorNoise(
        "gyro",
        200.0,
        (
            AxisNoise("d/gyro/x", 8.2e-5, 1.16e-4, walk_terms="bias instability B"),
            AxisNoise("d/gyro/y", 8.0e-5, 2.0e-5, walk_terms="rate random walk K"),
        ),
        "model",
        "diffusion",
    )
    text = export_text(gyro, None, "kalibr")
    assert "#   d/gyro/x: random walk from bias instability B (analyze's K: the rate random walk alone)\n" in text
    assert "#   d/gyro/y: 8.0000e-05, 2.0000e-05\n" in text and "d/gyro/y: random walk from" not in text
