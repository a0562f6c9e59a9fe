"""The noise-model-level virtual capture (acquisition/synthesize.py) and `demo --lab`."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.acquisition import load_config
from imustation.acquisition.synthesize import synthesize
from imustation.analysis.estimators.ml.composite import fit_composite
from imustation.analysis.pipeline.loaders import load_run
from imustation.cli import cli
from imustation.configs import config_path
from imustation.drivers.sim import device_sources, simulated_truth, station_device_seed
from imustation.runfile import open_run


@pytest.fixture(scope="module")
def lab():
    return load_config(config_path("demo-lab.toml"))


@pytest.fixture(scope="module")
def lab_run(lab, tmp_path_factory):
    path = tmp_path_factory.mktemp("synth") / "lab.h5"
    fractions = []
    summary = synthesize(lab, path, 600.0, progress=fractions.append)
    return path, summary, fractions


def test_every_device_and_thermometer_is_written_at_its_rate(lab, lab_run):
    path, summary, fractions = lab_run
    assert fractions[-1] == pytest.approx(1.0) and fractions == sorted(fractions)
    with open_run(path) as run:
        assert set(run.devices) == {d.name for d in lab.devices}
        for name, dev in run.devices.items():
            assert dev.n == summary.samples[name] == math.floor(600.0 * dev.rate_hz + 1e-9)
            t = run.read(name, "t")
            np.testing.assert_array_equal(t, np.rint(np.arange(dev.n) * 1e9 / dev.rate_hz).astype(np.int64))
        for th in lab.thermometers:
            t, c = run.temperatures(th.name)
            assert len(t) == summary.readings[th.name] == int(600 * th.settings["rate_hz"])
            assert np.all((c > 15) & (c < 30))
        assert any("noise-model level" in e.detail for e in run.events())


def test_counts_are_the_sources_values_converted_as_the_chips_do(lab, lab_run):
    """Oracle: the same source with the same seed, converted by rint(value / scale)."""
    path, _, _ = lab_run
    with open_run(path) as run:
        for dev in lab.devices:
            for name, src in device_sources(dev, station_device_seed(lab.seed, dev.name)).items():
                expected = np.concatenate([src.next(100) for _ in range(10)])  # small asks, as chips make
                raw = run.read(dev.name, name)[:1000]
                scale = run.devices[dev.name].channels[name].scale
                want = (expected / scale).reshape(raw.shape)
                if raw.dtype.kind == "f":  # float channels (Xsens MTi) hold the values
                    np.testing.assert_allclose(raw, want, rtol=1e-6, err_msg=dev.name)
                else:
                    np.testing.assert_array_equal(raw, np.rint(want), err_msg=dev.name)


def test_the_identified_noise_matches_the_simulated_truth(lab, lab_run):
    path, _, _ = lab_run
    truth = simulated_truth(lab)
    for ch in load_run(str(path), ["bmx055/gyro/z", "adis/gyro/x"]):
        res = fit_composite(ch.data, ch.fs_hz, scale=ch.scale)
        # 10 min at 400 Hz: the fine-scale sigma_w is good to ~0.1 %; quantisation adds a little
        assert res.sigma_w == pytest.approx(truth[ch.id].sigma_w, rel=0.03), ch.id


def test_demo_lab_synthesises_by_default_and_writes_its_table(tmp_path):
    table = tmp_path / "lab.csv"
    res = CliRunner().invoke(cli, ["demo", "--lab", "--duration", "10m", "--table", str(table)])
    assert res.exit_code == 0, res.output
    assert "synthesised, no bus transport" in res.output
    with open(table, newline="") as fh:
        rows = list(csv.DictReader(fh))
    ids = {r["channel"] for r in rows}
    for dev in ("bmx055", "mpu9150", "mpu6500", "adis", "mti"):
        assert f"{dev}/gyro/x" in ids
    assert "fog/gyro/z" in ids
    sw = [abs(float(r["error_pct"])) for r in rows if r["param"] == "sigma_w" and "/gyro/" in r["channel"]]
    assert max(sw) < 5.0
