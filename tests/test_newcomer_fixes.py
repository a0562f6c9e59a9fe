"""The second newcomer run's findings on issue 34 (each failed on the old code)."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from imustation.cli import cli


def _log(path, n: int = 24_000, fs: float = 200.0) -> None:
    """A timed text log whose columns state no unit (gx.., ax..)."""
    rng = np.random.default_rng(3)
    t = np.arange(n) / fs
    data = np.column_stack([t, rng.normal(0, 0.1, (n, 3)), rng.normal(0, 1e-3, (n, 3)) + [0, 0, 1]])
    np.savetxt(path, data, delimiter=",", header="t,gx,gy,gz,ax,ay,az", comments="", fmt="%.6f")


def test_analyze_asks_only_the_units_of_the_selected_channels(tmp_path):
    """``analyze log.csv --gyro-unit deg/s --channel '*/gyro/x'`` demanded --accel-unit although no accel
    channel was selected; an accel channel selected still needs its unit."""
    log = tmp_path / "log.csv"
    _log(log)
    r = CliRunner().invoke(cli, ["analyze", str(log), "--gyro-unit", "deg/s", "--channel", "*/gyro/x"])
    assert r.exit_code == 0, r.output
    assert "imu/gyro/x" in r.stdout and "accel-unit" not in r.output
    assert "'ax', 'ay', 'az' not read (no accel channel selected)" in r.stderr
    r = CliRunner().invoke(cli, ["analyze", str(log), "--gyro-unit", "deg/s", "--channel", "*/accel/x"])
    assert r.exit_code == 2 and "--accel-unit" in r.output


def test_verbose_text_names_command_line_options_not_api_arguments():
    """``analyze --verbose`` printed 'sigma_w is biased - give fine_samples' (an argument of the Python API
    that no command has): user text gives what a command-line user can do."""
    from dataclasses import replace

    from imustation.analysis.pipeline.channel import analyze_channel
    from imustation.analysis.pipeline.loaders import Channel
    from imustation.analysis.reports.analyzetable import results_table
    from imustation.analysis.reports.wording import user_text

    rng = np.random.default_rng(1)
    ch = Channel("imu/gyro/x", 100.0, "rad/s", rng.normal(0, 1e-3, 60_000))
    res = analyze_channel(ch, model="wn+rw")
    msg = "noise not white at any fine scale up to 8 samples (device filter?): sigma_w is biased - give fine_samples"
    fit = replace(res.noise_model, converged=False, message=msg)
    text = results_table([replace(res, noise_model=fit)], verbose=True)
    assert "fine_samples" not in text and "--model auto, or a model with +lp" in text
    assert "fine_samples" not in user_text("z = +5.1: noise not white at 0.01 s - raise fine_samples")


def test_a_part_longer_than_the_run_is_refused(tmp_path):
    """``setup service --duration "2 h" --rotate 3h`` was accepted (and capture with it): one line, exit 2;
    the service's default part (1h) with a shorter run becomes the run's length instead of a unit that fails."""
    cfg = "configs/demo.toml"
    out = str(tmp_path / "x.h5")
    r = CliRunner().invoke(cli, ["setup", "service", cfg, "-o", out, "--duration", "2 h", "--rotate", "3h"])
    assert r.exit_code == 2 and "--rotate 3h is longer than --duration 2 h" in r.output
    assert len(r.output.strip().splitlines()) == 1
    r = CliRunner().invoke(cli, ["setup", "service", cfg, "-o", out, "--duration", "30m"])
    assert r.exit_code == 0 and "--duration 30m --rotate 30m" in r.output
    r = CliRunner().invoke(cli, ["capture", cfg, "-o", out, "--simulate", "--duration", "20s", "--rotate", "1m"])
    assert r.exit_code == 2 and "--rotate 1m is longer than --duration 20s" in r.output
    assert not (tmp_path / "x.h5").exists() and not list(tmp_path.glob("x.*.h5"))


def test_live_rate_is_shown_over_a_window_long_enough_to_mean_something():
    """The status showed 429.6/400 Hz: the samples counted over one 1 s status interval, in which a FIFO
    read of a few dozen samples falls or not. The view shows the rate over the last 10 s of station time
    (within 0.5 % here), and '…' while it has less than 5 s to measure over."""
    import io

    from imustation.cli.statusview import StatusView

    def status(elapsed: float, samples: int, recent: float) -> dict:
        dev = {"state": "ok", "samples": samples, "rate_hz": samples / elapsed, "rate_recent_hz": recent,
               "rate_cfg_hz": 400.0, "gaps": 0, "lost": 0, "faults": 0, "temp_c": None}  # fmt: skip
        return {"state": "recording", "reason": "", "elapsed_s": elapsed, "duration_s": 3600.0,
                "remaining_s": 3600.0 - elapsed, "devices": {"imu": dev}}  # fmt: skip

    out = io.StringIO()
    view = StatusView(out)
    burst = 43  # samples per FIFO read: 400 Hz arrive as ~9.3 reads a second
    delivered = []
    for k in range(1, 31):
        got = (k * 400 // burst) * burst  # what has been read by k s
        delivered.append(got)
        recent = got - (delivered[-2] if k > 1 else 0)
        view.show(status(float(k), got, float(recent)))
    lines = out.getvalue().splitlines()
    shown = [ln.split("| imu ")[1].split("/")[0] for ln in lines]
    assert shown[:4] == ["…"] * 4  # fewer than 5 s to tell
    assert all(abs(float(x) - 400.0) < 2.0 for x in shown[9:])  # 10 s windows: within 0.5 %
    # the status interval's own count swings by a burst (the 429.6 Hz of the newcomer run)
    assert max(abs(delivered[k] - delivered[k - 1] - 400) for k in range(1, 30)) >= 20


def test_an_imported_rate_is_printed_with_the_digits_it_has(tmp_path):
    """``inspect`` printed an imported device's ``rate_hz=200.00000000000074`` (the least-squares fit of its
    stamps, kept whole in the file for the analysis): settings print to 10 significant digits."""
    from imustation.cli.inspect import setting_text

    assert setting_text(np.float64(200.00000000000074)) == "200" and setting_text(409.6) == "409.6"
    assert setting_text("stream") == "stream" and setting_text(3) == "3"
    log, out = tmp_path / "log.csv", tmp_path / "log.h5"
    _log(log)
    r = CliRunner().invoke(cli, ["import", str(log), "-o", str(out), "--gyro-unit", "rad/s", "--accel-unit", "g"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["inspect", str(out)])
    assert "rate_hz=200," in r.output and "200.0000000" not in r.output


def test_fleet_shows_a_short_identity(tmp_path):
    """fleet.md's identity column held an imported device's whole column mapping (300 characters); it shows
    the part-naming fields or the import's source, the CSV and JSON keep the identity whole."""
    import csv
    import json

    from imustation.analysis.reports.fleettable import short_identity

    assert short_identity("adis16448", "prod_id=0x4040 lot=0x12345678 serial=0x0042") == "serial=0x0042 lot=0x12345678"
    assert short_identity("bmx055", "chip_id=0x0F") == "chip_id=0x0F"
    assert short_identity("kvh", "x" * 80).endswith("…") and len(short_identity("kvh", "x" * 80)) == 32
    log, run = tmp_path / "log.csv", tmp_path / "log.h5"
    _log(log)
    assert CliRunner().invoke(cli, ["import", str(log), "-o", str(run), "--gyro-unit", "rad/s",
                                    "--accel-unit", "g"]).exit_code == 0  # fmt: skip
    out = tmp_path / "fleet"
    r = CliRunner().invoke(cli, ["fleet", str(run), "-o", str(out), "--channel", "*/gyro/x"])
    assert r.exit_code == 0, r.output
    row = next(ln for ln in (out / "fleet.md").read_text().splitlines() if "| x-gyro |" in ln)
    assert "| text: log.csv |" in row and "<-" not in row
    (line,) = list(csv.DictReader((out / "fleet.csv").open(encoding="utf-8")))
    assert "gx" in line["identity"]  # the whole mapping stays in the machine-readable outputs
    doc = json.loads((out / "fleet.json").read_text())
    assert doc["rows"][0]["identity_short"] == "text: log.csv" and "gx" in doc["rows"][0]["identity"]


def test_analyze_help_says_where_the_comparison_fits_are_shown():
    # --method promised 'rows below it' and --estimator 'the table's first row per channel', but the table has
    # one row per channel and the comparison fits appear only under --verbose (second newcomer run)
    import re

    out = re.sub(r"\s+", " ", CliRunner().invoke(cli, ["analyze", "--help"]).output)
    assert "rows below it" not in out and "first row per channel" not in out
    assert "shown under 'details:' with --verbose" in out
    assert "lp on samples that show no filter" in out
