"""Simulated capture -> run file -> inspect/analyze, through the library and the CLI."""

import json

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from imustation.cli import cli
from imustation.runfile import FORMAT, FORMAT_VERSION, open_run


def test_run_file_layout(sim_run):
    path, summary = sim_run
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == FORMAT and f.attrs["format_version"] == FORMAT_VERSION
        for key in ("station", "started_utc", "ended_utc", "config", "software_version", "host", "simulated"):
            assert key in f.attrs
        g = f["devices/bmx055"]
        assert g.attrs["driver"] == "bmx055"
        assert g.attrs["rate_hz"] == 400.0 and g.attrs["bandwidth_hz"] == 47.0
        assert g.attrs["gyro_range_dps"] == 125
        assert g["gyro"].dtype == np.int16 and g["gyro"].shape == (480000, 3)
        assert g["gyro"].attrs["units"] == "rad/s"
        assert g["gyro"].chunks is not None and g["gyro"].compression == "gzip"
        assert g["t"].dtype == np.int64
        assert "events" in f
    assert summary.samples["bmx055"] == 480000


def test_timestamps_are_monotonic_and_at_rate(sim_run):
    path, _ = sim_run
    with open_run(path) as run:
        t = run.read("bmx055", "t")
    dt = np.diff(t)
    assert (dt > 0).all()
    assert np.median(dt) == pytest.approx(2.5e6, rel=1e-6)


def test_samples_written_equal_samples_produced(sim_run):
    path, summary = sim_run
    with open_run(path) as run:
        lost = sum(e.lost for e in run.events())
        n = run.devices["bmx055"].n
    assert n == summary.samples["bmx055"]
    assert lost == summary.lost["bmx055"] == 0


def test_inspect_cli(sim_run):
    path, _ = sim_run
    res = CliRunner().invoke(cli, ["inspect", str(path)])
    assert res.exit_code == 0, res.output
    assert "bmx055" in res.output and "samples 480000" in res.output and "complete" in res.output
    assert "bandwidth_hz=47," in res.output  # settings to 10 significant digits (docs/import.md)


def test_analyze_json_contract(sim_run):
    path, _ = sim_run
    res = CliRunner().invoke(cli, ["analyze", str(path), "--channel", "bmx055/gyro/z", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["format"] == "imustation-analysis" and doc["version"] == 1
    (ch,) = doc["channels"]
    assert ch["id"] == "bmx055/gyro/z" and ch["fs_hz"] == 400.0 and ch["n"] == 480000
    assert ch["units"] == "rad/s"
    mli = ch["mli"]
    for key in ("model", "sigma_w", "sigma_b", "tau_b", "b_on", "stderr", "pattern", "m", "nll"):
        assert key in mli
    assert mli["model"] == "wn+gm" and mli["pattern"] == "log" and mli["m"] == 1000
    assert set(mli["stderr"]) == {"sigma_w", "sigma_b", "tau_b"}
    assert set(ch["allan"]) >= {"tau", "adev", "adev_lo", "adev_hi"}
    assert len(ch["allan"]["tau"]) == len(ch["allan"]["adev"]) > 10
    assert set(ch["ieee"]) >= {"N", "B", "K"}
    # sigma_w of the BMX055 z gyro in Table IV is 9.97e-5; 20 min of data gives ~5 %
    assert mli["sigma_w"] == pytest.approx(9.97e-5, rel=0.15)


def test_analyze_table_and_glob(sim_run):
    path, _ = sim_run
    res = CliRunner().invoke(cli, ["analyze", str(path), "--channel", "bmx055/gyro/[xy]"])
    assert res.exit_code == 0, res.output
    assert "bmx055/gyro/x" in res.output and "bmx055/gyro/y" in res.output
    assert "bmx055/gyro/z" not in res.output


def test_capture_cli_refuses_existing_output(sim_run, demo_config, tmp_path):
    path, _ = sim_run
    res = CliRunner().invoke(cli, ["capture", demo_config.path, "--simulate", "--duration", "1s", "-o", str(path)])
    assert res.exit_code == 2
    assert "file exists" in res.output


def test_capture_cli_small_run(demo_config, tmp_path):
    out = tmp_path / "small.h5"
    res = CliRunner().invoke(
        cli, ["capture", demo_config.path, "--simulate", "--duration", "30s", "-o", str(out), "--quiet"]
    )
    assert res.exit_code == 0, res.output
    with open_run(out) as run:
        assert run.devices["bmx055"].n == 12000
        assert run.complete


def test_same_seed_gives_same_samples(demo_config, tmp_path):
    from imustation.acquisition import capture

    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    capture(demo_config, a, 5.0, simulate=True)
    capture(demo_config, b, 5.0, simulate=True)
    with open_run(a) as ra, open_run(b) as rb:
        assert np.array_equal(ra.read("bmx055", "gyro"), rb.read("bmx055", "gyro"))
