"""Every command that writes refuses to replace an output without --overwrite, and checks its output paths
before any work: one line, exit status 2 (issue 23)."""

from __future__ import annotations

import os

import numpy as np
import pytest
from click.testing import CliRunner

import imustation.acquisition
import imustation.acquisition.importers
import imustation.acquisition.synthesize as synthesize_module
import imustation.analysis.pipeline.channel
import imustation.analysis.pipeline.parallel
import imustation.analysis.pipeline.study
import imustation.analysis.reports.runreport
import imustation.outputs
from imustation.channels import ChannelSpec
from imustation.cli import cli
from imustation.runfile import DeviceSpec, RunWriter


def _one_line(res, *needles):
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in res.output, res.output
    for needle in needles:
        assert needle in lines[0], lines[0]


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture
def no_work(monkeypatch):
    """Every long step of the writing commands fails the test if it is reached: the checks come first."""

    def work(*args, **kwargs):
        raise AssertionError("the work started before the outputs were checked")

    for mod, name in (
        (imustation.acquisition, "capture"),
        (imustation.acquisition.importers, "import_recording"),
        (imustation.analysis.pipeline.channel, "analyze_channel"),
        (imustation.analysis.pipeline.study, "run_study"),
        (imustation.analysis.reports.runreport, "report_run"),
        (imustation.analysis.pipeline.parallel, "plan_tasks"),
    ):
        monkeypatch.setattr(mod, name, work)
    monkeypatch.setattr(synthesize_module, "synthesize", work)


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """A 40 s, 100 Hz run file with a gyro and an accelerometer (white noise)."""
    path = tmp_path_factory.mktemp("out") / "small.h5"
    chans = (
        ChannelSpec("gyro", "int16", "rad/s", 1e-4, 0.0, ("x", "y", "z")),
        ChannelSpec("accel", "int16", "m/s^2", 1e-3, 0.0, ("x", "y", "z")),
    )
    spec = DeviceSpec("imu", "test", "test", "bus", "id", 100.0, {}, chans)
    rng = np.random.default_rng(1)
    n = 4000
    with RunWriter(path, station="t", config_text="", simulated=True, devices=[spec]) as w:
        data = {c.name: rng.normal(0, 50, (n, 3)).astype(np.int16) for c in chans}
        w.append("imu", np.arange(1, n + 1, dtype=np.int64) * 10_000_000, data)
    return path


def test_an_existing_output_is_refused_by_every_command_without_overwrite(tmp_path, demo_config, small_run, no_work):
    existing = tmp_path / "capture.h5"
    existing.write_bytes(b"138 MiB of a night's capture")
    refused = "file exists; choose another name or --overwrite"
    _one_line(_run("demo", "-o", existing), str(existing), refused)
    _one_line(_run("demo", "--lab", "--table", existing), "--table", refused)
    _one_line(_run("capture", demo_config.path, "--simulate", "-o", existing), refused)
    _one_line(_run("import", small_run, "-o", existing), refused)
    _one_line(_run("export", small_run, "--format", "kalibr", "-o", existing), refused)
    _one_line(_run("study", "-o", existing), refused)
    assert existing.read_bytes() == b"138 MiB of a night's capture"
    (tmp_path / "rep" / "small").mkdir(parents=True)
    (tmp_path / "rep" / "small" / "index.html").write_text("an earlier report")
    _one_line(_run("report", small_run, "-o", tmp_path / "rep"), "small exists; choose another folder or --overwrite")
    (tmp_path / "fl").mkdir()
    (tmp_path / "fl" / "fleet.md").write_text("an earlier fleet")
    _one_line(_run("fleet", small_run, "-o", tmp_path / "fl"), "fleet.md exists; choose another folder or --overwrite")
    trace = tmp_path / "bus.trace"
    trace.write_text("{}")
    _one_line(_run("capture", demo_config.path, "--simulate", "-o", tmp_path / "new.h5", "--trace", trace), "--trace")


def test_output_paths_are_checked_before_the_work(tmp_path, demo_config, small_run, no_work):
    missing = tmp_path / "missing" / "dir"
    gone = "does not exist"
    _one_line(_run("export", small_run, "--format", "kalibr", "-o", missing / "k.yaml"), "k.yaml", gone)
    _one_line(_run("import", small_run, "-o", missing / "x.h5"), "x.h5", gone)
    _one_line(_run("demo", "-o", missing / "d.h5"), gone)
    _one_line(_run("study", "-o", missing / "s.md"), gone)
    _one_line(_run("capture", demo_config.path, "--simulate", "-o", missing / "c.h5"), gone)
    _one_line(
        _run("capture", demo_config.path, "--simulate", "-o", tmp_path / "c.h5", "--status-file", missing / "s"), gone
    )
    assert not os.path.exists(str(tmp_path / "c.h5") + ".lock")
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    _one_line(_run("report", small_run, "-o", a_file), "is a file; give a folder")
    _one_line(_run("fleet", small_run, "-o", a_file / "sub"), "is a file, not a folder")
    _one_line(_run("export", small_run, "--format", "kalibr", "-o", a_file / "k.yaml"), "is a file, not a folder")
    _one_line(_run("export", small_run, "--format", "kalibr", "-o", tmp_path), "is a folder; give a file name")
    assert sorted(os.listdir(tmp_path)) == ["a_file"]  # nothing made on the way


def test_an_unwritable_folder_is_named(tmp_path, monkeypatch, small_run, no_work):
    # root may write anywhere, so the permission is taken from the check's own view of it
    real = os.access
    monkeypatch.setattr(imustation.outputs.os, "access", lambda p, mode: real(p, mode) and str(p) != str(tmp_path))
    _one_line(_run("export", small_run, "--format", "kalibr", "-o", tmp_path / "k.yaml"), "is not writable")
    _one_line(_run("report", small_run, "-o", tmp_path / "rep"), f"{tmp_path} is not writable")


def test_a_failed_report_leaves_no_folder_and_overwrite_replaces(tmp_path, small_run):
    out = tmp_path / "rep"
    _one_line(_run("report", tmp_path / "nothing.h5", "-o", out), "no such file")
    assert not out.exists()
    res = _run("report", small_run, "-o", out, "--warmup", "0", "--channel", "imu/gyro/x")
    assert res.exit_code == 0, res.output
    # a second run that fails after the first was written: the first stays, the failed one leaves nothing
    (tmp_path / "bad.h5").write_bytes(b"not hdf5")
    res = _run(
        "report", small_run, tmp_path / "bad.h5", "-o", tmp_path / "two", "--warmup", "0", "--channel", "imu/gyro/x"
    )
    assert res.exit_code == 2 and sorted(os.listdir(tmp_path / "two")) == ["small"]
    before = (out / "small" / "noise.csv").stat().st_mtime_ns
    res = _run("report", small_run, "-o", out, "--warmup", "0", "--channel", "imu/gyro/x", "--overwrite")
    assert res.exit_code == 0, res.output
    assert (out / "small" / "noise.csv").stat().st_mtime_ns >= before


def test_export_overwrite_replaces_the_file(tmp_path, small_run):
    k = tmp_path / "k.yaml"
    k.write_text("old")
    # 10 s of a synthetic gyro identify no random walk: refused, the old file left alone ...
    res = _run("export", small_run, "--format", "kalibr", "-o", k, "--overwrite")
    assert res.exit_code == 2 and k.read_text() == "old"
    # ... and with --force replaced
    res = _run("export", small_run, "--format", "kalibr", "-o", k, "--overwrite", "--force")
    assert res.exit_code == 0, res.output
    assert "gyroscope_noise_density" in k.read_text()
