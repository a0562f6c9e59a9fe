"""One answer per file (issue 34): analyze, report, export and fleet cut the same warm-up and give the
same numbers for the same channel and options, and each says what it cut."""

from __future__ import annotations

import csv
import json

import pytest
from click.testing import CliRunner

from imustation.acquisition import capture, load_config
from imustation.cli import cli

_CONFIG = """[station]
name = "warm"
seed = 11

[[device]]
name = "bmx055"
driver = "bmx055"
bus = "i2c:1"
address = 0x68
rate_hz = 400
bandwidth_hz = 47
gyro_range_dps = 125
  [device.sim]
  temp_c = 24.0
  warmup_c = 4.0
  warmup_tau_s = 300.0
"""


@pytest.fixture(scope="module")
def warm_run(tmp_path_factory):
    """40 min of a BMX055 whose die warms 4 K with a 5 min time constant (settled after ~20 min)."""
    d = tmp_path_factory.mktemp("warm")
    (d / "warm.toml").write_text(_CONFIG)
    path = d / "warm.h5"
    capture(load_config(d / "warm.toml"), path, 2400.0, simulate=True)
    return str(path)


def test_analyze_report_export_and_fleet_cut_the_same_warm_up(warm_run, tmp_path):
    args = ["--channel", "bmx055/gyro/x", "--model", "wn+gm"]
    res = CliRunner().invoke(cli, ["analyze", warm_run, *args, "--json"])
    assert res.exit_code == 0, res.output
    (ch,) = json.loads(res.stdout)["channels"]
    cut = ch["warmup"]
    assert cut["option"] == "auto" and cut["state"] == "transient" and 900 < cut["cut_s"] < 1500
    assert ch["verdict"]["warmup_cut_s"] == pytest.approx(cut["cut_s"])
    assert not any("discard it" in r for r in ch["verdict"]["reasons"])  # cut, not left to the user
    sigma_w = ch["noise_model"]["sigma_w"]
    text = CliRunner().invoke(cli, ["analyze", warm_run, *args])
    assert f"warm-up bmx055: {cut['cut_s'] // 60:.0f}m" in text.stdout and "(auto: warm-up" in text.stdout

    rep = CliRunner().invoke(cli, ["report", warm_run, "-o", str(tmp_path / "r"), *args])
    assert rep.exit_code == 0, rep.output
    (row,) = list(csv.DictReader((tmp_path / "r" / "warm" / "summary.csv").open()))
    assert float(row["N"]) == pytest.approx(sigma_w, rel=1e-9)  # the same cut, the same numbers
    assert "bmx055: " in (tmp_path / "r" / "warm" / "index.html").read_text()

    exp = CliRunner().invoke(cli, ["export", warm_run, "--format", "kalibr", "--gyro-only", "--model", "wn+gm",
                                   "--force", "-o", str(tmp_path / "k.yaml")])  # fmt: skip
    assert exp.exit_code == 0, exp.output
    k = (tmp_path / "k.yaml").read_text()
    assert "# warm-up bmx055: " in k and "(auto: warm-up" in k
    x = next(ln for ln in k.splitlines() if ln.startswith("#   bmx055/gyro/x:"))
    assert float(x.split(":")[1].split(",")[0]) == pytest.approx(sigma_w, rel=1e-3)  # 4 printed digits

    fl = CliRunner().invoke(cli, ["fleet", warm_run, "-o", str(tmp_path / "f"), *args])
    assert fl.exit_code == 0, fl.output
    (frow,) = list(csv.DictReader((tmp_path / "f" / "fleet.csv").open()))
    assert float(frow["sigma_w"]) == pytest.approx(sigma_w, rel=1e-9) and "(auto: warm-up" in frow["warmup"]

    # N, B, K: the noise model's ieee952 block in analyze, the report's summary and noise table, and fleet
    # (the noise table and fleet took B and K from the classical Allan fit before: issue 34)
    block = ch["noise_model"]["ieee952"]
    (noise,) = list(csv.DictReader((tmp_path / "r" / "warm" / "noise.csv").open()))
    for q in ("N", "B", "K"):
        shown = block[q] if block.get(f"{q}_detected", True) else block[f"{q}_upper90"]
        for where in (row, noise, frow):
            assert float(where[q]) == pytest.approx(shown, rel=1e-9), (q, where)

    # --warmup 0 keeps everything, and the verdict then says what to discard
    keep = CliRunner().invoke(cli, ["analyze", warm_run, *args, "--json", "--warmup", "0"])
    (ch0,) = json.loads(keep.stdout)["channels"]
    assert ch0["warmup"]["cut_s"] == 0 and any("discard it" in r for r in ch0["verdict"]["reasons"])
