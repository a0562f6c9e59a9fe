"""A rotated capture read as one run: the series reader and every command that reads runs (issue 23)."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.acquisition import capture
from imustation.acquisition.config import parse_config
from imustation.analysis.pipeline.loaders import load_inputs, load_run
from imustation.channels import ChannelSpec
from imustation.cli import cli
from imustation.errors import RunFileError
from imustation.runfile import (
    DeviceSpec,
    RunSeries,
    RunWriter,
    join_parts,
    latest_part,
    open_run,
    open_series,
    part_path,
)
from imustation.runfile.series import range_name

GYRO = {"driver": "bmx055", "rate_hz": 400, "bandwidth_hz": 47}


@pytest.fixture(scope="module")
def week(tmp_path_factory):
    """A simulated 25 s capture rotated every 10 s (parts of 4000, 4000, 2000 samples) with a thermometer."""
    d = tmp_path_factory.mktemp("week")
    cfg = parse_config(
        {
            "station": {"seed": 5, "flush_interval_s": 0.2},
            "device": [{"name": "g", "bus": "i2c:1", **GYRO}],
            "thermometer": [{"name": "amb", "driver": "mcp9804", "bus": "i2c:1"}],
        }
    )
    out = d / "week.h5"
    summary = capture(cfg, out, 25.0, simulate=True, rotate_s=10.0)
    assert summary.paths == [part_path(str(out), k) for k in (1, 2, 3)]
    return out


def _parts(week):
    return [part_path(str(week), k) for k in (1, 2, 3)]


def test_the_base_name_reads_every_part_as_one_record(week):
    parts = _parts(week)
    with open_series(str(week)) as run:
        assert isinstance(run, RunSeries) and run.numbers == [1, 2, 3] and run.complete
        assert run.devices["g"].n == 10_000 and run.devices["g"].channels["gyro"].n == 10_000
        t = run.read("g", "t")
        gyro = run.read("g", "gyro", 3_990, 4_010)  # across the first hand-over
        assert len(run.temperatures("amb")[0]) == 25
        kinds = [(e.kind, e.source) for e in run.events()]
        assert "part" not in run.attrs and run.attrs["run_id"]
        ds = run.dataset("g", "gyro")
        assert len(ds) == 10_000 and ds.shape == (10_000, 3)
        np.testing.assert_array_equal(ds[3_990:4_010, 1], gyro[:, 1])
        assert int(run.dataset("g", "t")[-1]) == int(t[-1])
    singles = []
    for p in parts:
        with open_run(p) as one:
            singles.append((one.read("g", "t"), one.read("g", "gyro")))
    np.testing.assert_array_equal(t, np.concatenate([s[0] for s in singles]))
    np.testing.assert_array_equal(gyro, np.concatenate([s[1] for s in singles])[3_990:4_010])
    assert np.all(np.diff(t) == 2_500_000)  # the hand-overs lose nothing: no gap added
    assert kinds == [("note", "station")] * 4


def test_inputs_naming_parts_are_joined_and_checked(week):
    p1, p2, p3 = _parts(week)
    assert join_parts([p1, p2, p3]) == [str(week)]
    assert join_parts([p3, p1, p2]) == [str(week)]  # by part number, at the place of the first named
    assert join_parts([p2, p3]) == [range_name(str(week), 2, 3)]
    assert join_parts([p2]) == [p2]  # a single part is a file of its own
    with pytest.raises(RunFileError, match="part 2 missing; name every part from 1 to 3, or the base name"):
        join_parts([p1, p3])
    with open_series(range_name(str(week), 2, 3)) as run:
        assert run.numbers == [2, 3] and run.devices["g"].n == 6_000
    assert latest_part(str(week)) == p3 and latest_part(p1) == p1


def test_parts_of_two_captures_or_missing_parts_are_one_clear_error(week, tmp_path):
    for p in _parts(week):
        shutil.copy(p, tmp_path)
    base = str(tmp_path / "week.h5")
    cfg = parse_config(
        {"station": {"seed": 6, "flush_interval_s": 0.2}, "device": [{"name": "g", "bus": "i2c:1", **GYRO}]}
    )
    capture(cfg, tmp_path / "other.h5", 15.0, simulate=True, rotate_s=10.0)
    os.replace(tmp_path / "other.002.h5", tmp_path / "week.002.h5")  # a part of another capture
    with pytest.raises(RunFileError, match=r"week.h5: week.002.h5 belongs to capture \w+, not \w+ like week.001.h5"):
        open_series(base)
    os.remove(tmp_path / "week.002.h5")
    with pytest.raises(RunFileError, match="parts 1, 3 are not consecutive"):
        open_series(base)
    with pytest.raises(RunFileError, match="part week.002.h5 is missing"):
        open_series(range_name(base, 1, 3))
    with pytest.raises(RunFileError, match="no such file"):
        open_series(str(tmp_path / "nothing.h5"))


def _part(path, k, t, *, run_id="r1", events=()):
    spec = DeviceSpec(
        "imu",
        "test",
        "test",
        "bus",
        "id",
        100.0,
        {},
        (ChannelSpec("gyro", "int16", "rad/s", 1e-3, 0.0, ("x", "y", "z")),),
    )
    previous = "" if k == 1 else f"s.{k - 1:03d}.h5"
    started = "2026-01-01T00:00:00+00:00"
    with RunWriter(
        path, station="t", config_text="", simulated=True, devices=[spec], part=k, run_id=run_id,
        previous_part=previous, started_utc=started,
    ) as w:  # fmt: skip
        w.append("imu", np.asarray(t, dtype=np.int64), {"gyro": np.ones((len(t), 3), dtype=np.int16)})
        for ev in events:
            w.event(*ev)


def test_a_jump_at_a_hand_over_is_a_gap_unless_the_station_logged_it(tmp_path):
    period = 10_000_000  # 100 Hz
    _part(tmp_path / "s.001.h5", 1, np.arange(1000) * period)
    # part 2 starts 51 periods after part 1's last sample: 50 samples missing, nothing logged
    _part(tmp_path / "s.002.h5", 2, (np.arange(1000) + 1050) * period)
    with open_series(str(tmp_path / "s.h5")) as run:
        gaps = [e for e in run.events() if e.kind == "gap"]
    assert [(e.source, e.lost, e.t_ns) for e in gaps] == [("imu", 50, 1050 * period)]
    assert "between s.001.h5 and s.002.h5" in gaps[0].detail
    [ch, *_] = load_run(str(tmp_path / "s.h5"))
    assert ch.n == 2000 and ch.segments == [(0, 1000), (1000, 2000)] and ch.gaps == 1
    # the station logged the loss itself (at the first read of part 2): counted once
    t2 = (np.arange(1000) + 1050) * period
    _part(tmp_path / "s.002.h5.new", 2, t2, events=[(int(t2[7]), "imu", "overrun", "FIFO overflow", 50)])
    os.replace(tmp_path / "s.002.h5.new", tmp_path / "s.002.h5")
    with open_series(str(tmp_path / "s.h5")) as run:
        assert [(e.kind, e.lost) for e in run.events()] == [("overrun", 50)]
    # a part that starts before the previous one ended is not its continuation
    _part(tmp_path / "s.003.h5", 3, np.arange(10) * period)
    with pytest.raises(RunFileError, match="s.003.h5 starts \\(imu\\) before s.002.h5 ends"):
        open_series(str(tmp_path / "s.h5"))


def test_analyze_of_the_base_name_equals_analyze_of_the_parts(week):
    runner = CliRunner()
    args = ["analyze", "--channel", "g/gyro/x", "--json"]
    by_base = json.loads(runner.invoke(cli, [*args, str(week)], catch_exceptions=False).output)
    by_parts = json.loads(runner.invoke(cli, [*args, *_parts(week)], catch_exceptions=False).output)
    [a], [b] = by_base["channels"], by_parts["channels"]
    assert a["n"] == b["n"] == 10_000 and a["source"] == b["source"] == str(week)
    assert a["noise_model"] == b["noise_model"]
    # a channel read from the series equals the same samples joined by hand
    [ch] = load_inputs(_parts(week), ["g/gyro/x"])
    joined = []
    for p in _parts(week):
        with open_run(p) as one:
            joined.append(one.read("g", "gyro")[:, 0])
    np.testing.assert_array_equal(ch.data, np.concatenate(joined))


def test_analyze_of_several_inputs_names_the_input_of_each_row(week, tmp_path):
    p1, p2, p3 = _parts(week)
    single = tmp_path / "single.h5"
    shutil.copy(p3, single)
    res = CliRunner().invoke(cli, ["analyze", "--channel", "g/gyro/x", str(week), str(single)], catch_exceptions=False)
    rows = [line for line in res.stdout.splitlines() if line.split()[1:2] == ["g/gyro/x"]]
    # progress per channel on stderr, naming the input of each
    assert "[1/2] week.h5 g/gyro/x (" in res.stderr and "[2/2] single.h5 g/gyro/x (" in res.stderr
    assert rows[0].split()[:2] == ["week.h5", "g/gyro/x"] and rows[1].split()[:2] == ["single.h5", "g/gyro/x"]
    assert res.stdout.splitlines()[1].split()[:2] == ["input", "channel"]  # under the sensor kind's title
    assert "single.h5: g/gyro/x: " in res.stdout  # named with its input under 'needs attention'
    # parts that are not consecutive: one line, exit 2
    res = CliRunner().invoke(cli, ["analyze", p1, p3])
    assert res.exit_code == 2 and "with part 2 missing" in res.output and len(res.output.splitlines()) == 1


def test_inspect_shows_the_series(week):
    res = CliRunner().invoke(cli, ["inspect", str(week)], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    out = res.output
    assert "rotated capture (run_id" in out and "parts 1..3 read as one" in out
    assert "part 2: week.002.h5" in out and "samples 10000, duration 25s" in out
    res = CliRunner().invoke(cli, ["inspect", *_parts(week)], catch_exceptions=False)
    assert res.output == out  # the parts named one by one: the same series


def test_export_and_the_monitor_take_the_base_name(week, tmp_path):
    res = CliRunner().invoke(
        cli,
        ["export", str(week), "--format", "kalibr", "--gyro-only", "-o", str(tmp_path / "k.yaml"), "--force"],
        catch_exceptions=False,
    )  # fmt: skip  (--force: 25 s of a synthetic gyro identify no random walk)
    assert res.exit_code == 0, res.output
    assert str(week) in (tmp_path / "k.yaml").read_text()
    from imustation.monitor import Monitor

    mon = Monitor(str(week), poll_s=1.0)  # the part being written: the newest
    mon.poll()
    assert mon.status()["part"] == 3 and mon.status()["devices"]["g"]["samples"] == 2_000


def test_report_of_the_parts_is_one_report_of_the_series(week, tmp_path):
    res = CliRunner().invoke(
        cli, ["report", *_parts(week), "-o", str(tmp_path / "rep"), "--channel", "g/gyro/x", "--warmup", "0"],
        catch_exceptions=False,
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert sorted(os.listdir(tmp_path / "rep")) == ["week"]  # one run, one folder, no table over runs
    page = (tmp_path / "rep" / "week" / "index.html").read_text()
    assert "Noise report — week.h5" in page
    rows = (tmp_path / "rep" / "week" / "noise.csv").read_text().splitlines()
    assert len(rows) == 2
