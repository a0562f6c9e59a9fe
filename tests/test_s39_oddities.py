"""Small oddities a newcomer run found (issue 34, third pass); each test failed on the old code."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.analysis.estimators.classical.temperature import MIN_WARMUP_RECORD_S, fit_warmup
from imustation.cli import cli
from imustation.errors import InputError
from imustation.units import parse_duration

DEMO = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"


def test_analyze_of_a_text_log_prints_its_column_mapping_once(tmp_path):
    log = tmp_path / "log.csv"
    rng = np.random.default_rng(4)
    n, fs = 6000, 100.0
    data = np.column_stack([np.arange(n) / fs, rng.normal(0, 0.01, (n, 3))])
    np.savetxt(log, data, delimiter=",", header="time,gx [rad/s],gy [rad/s],gz [rad/s]", comments="", fmt="%.6f")
    r = CliRunner().invoke(cli, ["analyze", str(log), "--channel", "*/gyro/x"])
    assert r.exit_code == 0, r.output
    assert r.stderr.count("gyro x <- 'gx [rad/s]'") == 1
    assert f"{log}: imu: 6000 samples" in r.stderr


@pytest.mark.parametrize("text", ["-5m", "- 1h30m", "-0.5h"])
def test_a_negative_duration_is_refused_as_not_positive(text):
    with pytest.raises(InputError, match="must be positive"):
        parse_duration(text, "--duration")
    with pytest.raises(InputError, match="use a positive number with a unit"):
        parse_duration("-5x", "--duration")


def test_a_short_record_s_warm_up_state_says_whose_span_it_reads_and_what_it_needs():
    """A 12 s record whose thermometer read from 1 s to 11 s said 'record too short (10 s)'."""
    t = np.arange(1.0, 11.5, 1.0)
    w = fit_warmup(t, np.full(len(t), 30.5))
    assert w.state == "unknown" and math.isclose(w.duration_s, 10.0)
    text = w.describe()
    assert "temperature readings span 10 s" in text and f"needs {MIN_WARMUP_RECORD_S:.0f} s" in text
    assert "record too short" not in text


def test_export_counts_the_samples_it_fits_after_the_warm_up_cut():
    """export printed 'fitting … (719983 samples)': the count before the warm-up cut."""
    from imustation.analysis.pipeline.loaders import Channel
    from imustation.analysis.pipeline.warmup import WarmupCut, apply_warmup
    from imustation.analysis.reports.export import fit_axes

    ch = Channel("d/gyro/x", 100.0, "rad/s", np.random.default_rng(5).normal(0, 1e-2, 60_000), meta={"device": "d"})
    apply_warmup(ch, WarmupCut("d", "60s", 60.0))
    lines: list[str] = []
    fit_axes([ch], "gyroscope", "run.h5", "wn+rw", [], lines.append)
    assert lines[0] == "fitting d/gyro/x (54000 samples; the warm-up cut left out 6000 of 60000) ..."


def test_inspect_of_a_simulated_run_ends_it_at_its_virtual_duration(tmp_path):
    """inspect printed ended_utc, the wall clock at the close (seconds after the start for a 2 h simulation)."""
    import datetime as dt

    out = tmp_path / "sim.h5"
    r = CliRunner().invoke(cli, ["capture", str(DEMO), "--simulate", "--duration", "10m", "-o", str(out)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["inspect", str(out)])
    assert r.exit_code == 0, r.output
    line = next(ln for ln in r.stdout.splitlines() if ln.strip().startswith("started"))
    started, ended = line.split()[1], line.split()[3]
    span = (dt.datetime.fromisoformat(ended) - dt.datetime.fromisoformat(started)).total_seconds()
    assert 599.0 <= span <= 600.0
    assert "end of the simulated data" in line and "wall clock" in line
