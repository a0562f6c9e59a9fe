"""``capture --resume``: a capture killed (or stopped) and started again continues its run as the next part."""

from __future__ import annotations

import datetime as _dt
import json
import os
import signal
import subprocess
import sys

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from imustation.acquisition import capture, load_config
from imustation.analysis.pipeline.loaders import load_inputs
from imustation.cli import cli
from imustation.runfile import open_run, open_series
from imustation.runfile.holes import check_run, check_thermometers

CONFIG = """
[station]
name = "night"
flush_interval_s = 0.1
seed = 5

[[device]]
name = "gyro"
driver = "bmx055"
bus = "i2c:1"
rate_hz = 400
bandwidth_hz = 47

[[thermometer]]
name = "room"
driver = "mcp9804"
bus = "i2c:1"
rate_hz = 1
"""
RATE = 400
OUTAGE_S = 90.0


@pytest.fixture
def cfg_path(tmp_path):
    p = tmp_path / "night.toml"
    p.write_text(CONFIG)
    return p


def after_last_write(path, seconds):
    """A wall clock reading ``seconds`` after ``path`` was last written (the outage, on a virtual clock)."""
    t = _dt.datetime.fromtimestamp(os.path.getmtime(path), _dt.UTC) + _dt.timedelta(seconds=seconds)
    return lambda: t


def kill_after(cfg_path, out, virtual_s, *extra):
    """Start a paced simulated capture, SIGKILL it once ``virtual_s`` of samples are on disk."""
    cmd = [sys.executable, "-m", "imustation", "capture", str(cfg_path), "--simulate", "-o", str(out)]
    cmd += ["--sim-speed", "50", "--json-status", "--status-interval", "0.1", "--no-fsync", *extra]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for line in proc.stdout:
            status = json.loads(line)
            if status.get("on_disk", {}).get("gyro", 0) >= virtual_s * RATE:
                break
        else:
            raise AssertionError(f"capture ended before {virtual_s} s: {proc.stderr.read()}")
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL


def one_hole_each(series):
    """Every device and thermometer has exactly one hole, the outage, logged as one gap that matches it."""
    events = series.events()
    gaps = [e for e in events if e.kind == "gap"]
    assert sorted(e.source for e in gaps) == ["gyro", "room"], gaps
    assert all(e.detail.startswith("outage: no samples for") for e in gaps)
    dev = check_run(series)["gyro"]
    assert (
        len(dev.holes.lost) == 1
        and not dev.unlogged
        and dev.holes.samples == next(e.lost for e in gaps if e.source == "gyro")
    )
    th = check_thermometers(series)["room"]
    assert len(th.holes.lost) == 1 and not th.unlogged
    return next(e for e in gaps if e.source == "gyro")


def test_a_killed_rotated_capture_resumes_as_its_next_part(cfg_path, tmp_path):
    out = tmp_path / "night.h5"
    # killed 30 s into a 4 min part: at 50 virtual s per wall s, a reader lagging 4 s behind still kills part 1
    kill_after(cfg_path, out, 30, "--duration", "8m", "--rotate", "4m")
    killed = tmp_path / "night.001.h5"
    with open_run(killed) as run:
        assert not run.complete
        run_id, started, t_killed = run.attrs["run_id"], run.attrs["started_utc"], run.read("gyro", "t")[-1]
    summary = capture(
        load_config(cfg_path), out, 480.0, simulate=True, rotate_s=240.0, resume=True,
        resume_now=after_last_write(killed, OUTAGE_S), fsync=False,
    )  # fmt: skip
    assert summary.paths[0] == str(tmp_path / "night.002.h5")
    with open_series(str(out)) as series:
        assert series.complete and series.numbers == [1, 2, 3]
        parts = series.parts
        assert {p.attrs["run_id"] for p in parts} == {run_id} and {p.attrs["started_utc"] for p in parts} == {started}
        assert "recovered" in parts[0].attrs and parts[0].attrs["next_part"] == "night.002.h5"
        assert parts[1].attrs["previous_part"] == "night.001.h5"
        t = series.read("gyro", "t")
        assert np.all(np.diff(t) > 0)
        k = int(np.flatnonzero(np.diff(t) > 1.5e9 / RATE)[0])
        # the outage from the last sample on disk, the first sample after it within a poll of the restart
        assert t[k] == t_killed and OUTAGE_S - 0.2 <= (t[k + 1] - t[k]) * 1e-9 < OUTAGE_S + 1.0
        assert 479e9 < t[-1] <= 480e9  # the run ends when planned, from its start
        gap = one_hole_each(series)
        assert gap.lost == round((t[k + 1] - t[k]) * RATE * 1e-9) - 1
    # the analysis reads one run with one break per channel
    channels = load_inputs([str(out)], ["gyro/gyro/*"])
    assert len(channels) == 3 and all(len(ch.segments) == 2 for ch in channels)
    res = CliRunner().invoke(cli, ["inspect", str(out)])
    assert res.exit_code == 0 and "parts 1..3 read as one" in res.output and "holes found: 0 not logged" in res.output


def test_a_single_file_run_becomes_part_one(cfg_path, tmp_path):
    out = tmp_path / "run.h5"
    capture(load_config(cfg_path), out, 60.0, simulate=True, fsync=False)
    capture(
        load_config(cfg_path), out, 120.0, simulate=True, resume=True,
        resume_now=after_last_write(out, 15.0), fsync=False,
    )  # fmt: skip
    assert not out.exists() and (tmp_path / "run.001.h5").exists() and (tmp_path / "run.002.h5").exists()
    with open_series(str(out)) as series:
        assert series.numbers == [1, 2]
        # a simulated run that ended cleanly goes on at its last sample on its virtual clock: the 15 s of
        # wall time between the runs are no outage (they were a 15 s hole: newcomer run, issue 34)
        assert not [e for e in series.events() if e.kind == "gap"]
        assert any("virtual clock" in e.detail for e in series.events() if e.kind == "note")
        assert len(check_run(series)["gyro"].holes.lost) == 0
        assert len(check_thermometers(series)["room"].holes.lost) == 0
        t = series.read("gyro", "t")
        assert np.all(np.diff(t) > 0) and np.max(np.diff(t)) < 1.5e9 / RATE
        assert 119e9 < t[-1] <= 120e9 and len(t) == pytest.approx(120 * RATE, abs=2)


def test_resume_without_a_run_starts_one_and_after_the_end_records_nothing(cfg_path, tmp_path):
    out = tmp_path / "n.h5"
    args = ["capture", str(cfg_path), "--simulate", "-o", str(out), "--duration", "20s", "--resume", "--quiet"]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    with open_run(out) as run:  # nothing to resume: an ordinary capture
        assert run.complete and "part" not in run.attrs
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert "planned duration ended" in res.output and "nothing to resume" in res.output
    assert sorted(p.name for p in tmp_path.glob("n*.h5")) == ["n.h5"]  # left as it was


def test_resume_refuses_changed_devices(cfg_path, tmp_path):
    out = tmp_path / "r.h5"
    capture(load_config(cfg_path), out, 20.0, simulate=True, fsync=False)
    cfg_path.write_text(
        CONFIG.replace("bandwidth_hz = 47", "bandwidth_hz = 23").replace("rate_hz = 400", "rate_hz = 200")
    )
    res = CliRunner().invoke(cli, ["capture", str(cfg_path), "--simulate", "-o", str(out), "--resume", "--quiet"])
    assert res.exit_code == 2 and "cannot resume: gyro now differ(s)" in res.output
    assert not (tmp_path / "r.002.h5").exists()
    res = CliRunner().invoke(cli, ["capture", str(cfg_path), "-o", str(out), "--resume", "--overwrite"])
    assert res.exit_code == 2 and "--resume" in res.output


def test_a_wall_clock_behind_the_last_sample_is_noted(cfg_path, tmp_path):
    """A Raspberry Pi without RTC boots with an old time: the outage is unknown, the run goes on regardless."""
    out = tmp_path / "pi.h5"
    capture(load_config(cfg_path), out, 20.0, simulate=True, fsync=False)
    with h5py.File(out, "r") as f:
        started = _dt.datetime.fromisoformat(f.attrs["started_utc"])
    from imustation.acquisition.resume import prepare_resume

    point = prepare_resume(str(out), load_config(cfg_path), 60.0, simulated=False, now=lambda: started)
    assert point is not None and point.outage_s == 1.0 and "outage's length is unknown" in point.note


def test_resume_refuses_a_thermometer_polled_at_another_rate(cfg_path, tmp_path):
    out = tmp_path / "t.h5"
    capture(load_config(cfg_path), out, 20.0, simulate=True, fsync=False)
    cfg_path.write_text(CONFIG.replace('bus = "i2c:1"\nrate_hz = 1', 'bus = "i2c:1"\nrate_hz = 2'))
    res = CliRunner().invoke(cli, ["capture", str(cfg_path), "--simulate", "-o", str(out), "--resume", "--quiet"])
    assert res.exit_code == 2 and "cannot resume: thermometer room now differ(s)" in res.output
    assert out.exists() and not (tmp_path / "t.001.h5").exists()  # nothing renamed, nothing added
