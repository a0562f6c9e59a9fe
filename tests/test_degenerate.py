"""Degenerate channels (constant, saturated, stuck, all quantisation) are named and skipped (issue 22)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.analysis.estimators.selection.screen import screen
from imustation.cli import cli
from imustation.runfile import ChannelSpec, DeviceSpec, RunWriter

N = 40_000
RNG = np.random.default_rng(3)


def _noise(sd=30.0, n=N, seed=None):
    rng = RNG if seed is None else np.random.default_rng(seed)
    return rng.normal(0.0, sd, n)


def _saturated():
    x = np.round(_noise(3000.0))
    x[RNG.random(N) < 0.05] = 32767  # rotated past full scale for 5 % of the time
    return x


def _stuck():
    x = np.round(_noise())
    x[10_000:20_000] = x[10_000]  # the output froze for a quarter of the record
    return x


KINDS = {
    "constant": lambda: np.full(N, 17.0),
    "saturated": _saturated,
    "stuck": _stuck,
    "quantisation": lambda: np.round(_noise(0.2)),
}


@pytest.mark.parametrize("kind", list(KINDS))
def test_each_kind_is_named(kind):
    deg = screen(KINDS[kind]().astype(np.int16), scale=1e-4, units="rad/s")
    assert deg is not None and deg.kind == kind and deg.reason.startswith(("constant", "saturated", "stuck", "all"))


def test_ordinary_channels_pass():
    assert screen(np.round(_noise(2.0)).astype(np.int16)) is None  # ~2 LSB of noise: a MEMS gyro
    assert screen(np.round(_noise(0.6)).astype(np.int16)) is None  # just above the quantisation limit
    assert screen(_noise(1e-4) + 0.3) is None  # floats (e.g. a fibre-optic gyro's rate)
    # a slow drift over the quantised noise is still a sensor
    x = np.round(_noise(1.0) + np.linspace(0, 50, N)).astype(np.int32)
    assert screen(x) is None


def test_quantised_floats_are_recognised():
    # counts stored as float32 rad/s: the grid is recovered from the smallest change
    x = (np.round(_noise(0.2)) * 1.2e-3 + 0.05).astype(np.float32)
    assert screen(x, units="rad/s").kind == "quantisation"
    assert screen((np.round(_noise(3.0)) * 1.2e-3).astype(np.float32)) is None


def _run(path):
    """Two gyroscopes: imu (x good, y constant, z saturated), imu2 (x stuck, y all quantisation, z good)."""
    fs = 100.0
    chan = (ChannelSpec("gyro", "<i2", "rad/s", 1e-4, 0.0, ("x", "y", "z")),)
    specs = [DeviceSpec(d, "sim", "model", "sim", "id", fs, {}, chan) for d in ("imu", "imu2")]
    t = np.arange(1, N + 1, dtype=np.int64) * int(1e9 / fs)
    imu = np.stack([np.round(_noise(seed=1)), KINDS["constant"](), KINDS["saturated"]()], axis=1)
    imu2 = np.stack([KINDS["stuck"](), KINDS["quantisation"](), np.round(_noise(seed=2))], axis=1)
    with RunWriter(path, station="t", config_text="", simulated=True, devices=specs) as w:
        w.append("imu", t, {"gyro": imu.astype(np.int16)})
        w.append("imu2", t, {"gyro": imu2.astype(np.int16)})


SKIPPED = {"imu/gyro/y": "constant", "imu/gyro/z": "saturated", "imu2/gyro/x": "stuck", "imu2/gyro/y": "quantisation"}


@pytest.fixture(scope="module")
def degenerate_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("degenerate") / "run.h5"
    _run(path)
    return str(path)


def test_analyze_skips_and_names_them(degenerate_run):
    res = CliRunner().invoke(cli, ["analyze", degenerate_run, "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert {c["id"] for c in doc["channels"]} == {"imu/gyro/x", "imu2/gyro/z"}
    assert {f["channel"]: f["skipped"] for f in doc["failures"]} == SKIPPED
    assert all(f["error"].startswith(f"skipped {f['channel']}: {f['skipped'].replace('quantisation', 'all')}")
               for f in doc["failures"])  # fmt: skip
    text = CliRunner().invoke(cli, ["analyze", degenerate_run])
    assert text.exit_code == 0
    for cid in SKIPPED:
        assert any(line.startswith(f"skipped {cid}: ") for line in text.stdout.splitlines()), cid
    assert "4 skipped" in text.stderr


def test_report_skips_and_names_them(degenerate_run, tmp_path):
    res = CliRunner().invoke(cli, ["report", degenerate_run, "-o", str(tmp_path), "--warmup", "0"])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "run" / "index.html").read_text()
    assert "Skipped channels" in page
    for cid in SKIPPED:
        assert f"skipped {cid}: " in page
    rows = (tmp_path / "run" / "noise.csv").read_text().splitlines()[1:]
    assert sorted(r.split(",")[0] + "/" + r.split(",")[2] for r in rows) == ["imu/x", "imu2/z"]
    assert "4 channels skipped" in res.stdout


@pytest.mark.parametrize("device", ["imu", "imu2"])
def test_export_skips_and_names_them(degenerate_run, device):
    # the short synthetic record does not identify the bias: --force writes it (marked); the skips are named
    args = ["export", degenerate_run, "--format", "kalibr", "--device", device, "--gyro-only", "--force"]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    skipped = [c for c in SKIPPED if c.startswith(device + "/")]
    for cid in skipped:
        assert f"# skipped {cid}: " in res.stdout.replace("#   skipped", "# skipped")
        assert f"warning: skipped {cid}: " in res.stderr
    assert "gyroscope_noise_density" in res.stdout
