"""``imustation report`` on a small simulated run writes the tables, figures and one HTML page."""

from __future__ import annotations

import csv
import re

from click.testing import CliRunner

from imustation.cli import cli


def test_report_writes_expected_files(sim_run, tmp_path):
    path, _ = sim_run
    out = tmp_path / "rep"
    r = CliRunner().invoke(cli, ["report", str(path), "-o", str(out), "--warmup", "2m"])
    assert r.exit_code == 0, r.output
    d = out / path.stem
    names = {p.name for p in d.iterdir()}
    for stem in ["allan_bmx055_gyro"] + [f"{k}_bmx055_gyro_{a}" for k in ("allan", "psd", "attitude") for a in "xyz"]:
        assert {stem + ".png", stem + ".pdf"} <= names
    assert {"temperature_bmx055_gyro.png", "noise.csv", "noise.md", "noise.tex", "index.html"} <= names
    rows = list(csv.DictReader((d / "noise.csv").open(encoding="utf-8")))
    assert [row["axis"] for row in rows] == ["x", "y", "z"]
    page = (d / "index.html").read_text(encoding="utf-8")
    links = re.findall(r'(?:src|href)="([^"]+)"', page)
    assert links and all("/" not in ln and ":" not in ln for ln in links)  # relative, same folder, no CDN
    assert all(ln in names for ln in links)
    assert "bmx055: 2m00s" in page and "rate 400 Hz, bandwidth 47 Hz" in page


def test_report_opens_with_the_summary_then_figures_then_details(sim_run, tmp_path):
    """Issue 23: one summary row per axis first (display units, intervals, verdicts), the figures, then the
    details; only the temperature coefficients that pass the autocorrelation-aware test are listed."""
    path, _ = sim_run
    out = tmp_path / "rep"
    r = CliRunner().invoke(cli, ["report", str(path), "-o", str(out), "--warmup", "0"])
    assert r.exit_code == 0, r.output
    d = out / path.stem
    page = (d / "index.html").read_text(encoding="utf-8")
    heads = re.findall(r"<h2>([^<]+)</h2>", page)
    assert heads == ["Summary", "Figures", "Details"]
    summary = page[page.index("<h2>Summary</h2>") : page.index("<h2>Figures</h2>")]
    assert "N [°/h/√Hz]" in summary and "B [°/h]" in summary and "enough data?" in summary
    assert summary.count("<tr>") == 1 + 3  # header + one row per gyro axis
    assert page.index("<figure>") > page.index("<h2>Figures</h2>")
    summ = list(csv.DictReader((d / "summary.csv").open(encoding="utf-8")))
    assert [row["axis"] for row in summ] == ["x", "y", "z"] and summ[0]["N_unit"] == "rad/s/√Hz"
    for row in summ:
        assert float(row["N_lo90"]) < float(row["N"]) < float(row["N_hi90"])
        assert row["enough_data"] in ("enough", "marginal", "not enough")
    # every coefficient in tempco.csv, the page lists only those that pass
    tempco = list(csv.DictReader((d / "tempco.csv").open(encoding="utf-8")))
    assert len(tempco) == 3 and all(row["n_eff"] for row in tempco if row["slope"])
    listed = [row for row in tempco if row["listed"] == "True"]
    details = page[page.index("<h2>Details</h2>") :]
    assert f"{len(listed)} of 3 coefficients are listed" in details
    tempco_html = details[details.index("<h3>Bias temperature coefficients</h3>") :]
    assert tempco_html.count("<tr>") == (1 + len(listed) if listed else 0)


def test_report_rejects_bad_warmup(sim_run, tmp_path):
    path, _ = sim_run
    r = CliRunner().invoke(cli, ["report", str(path), "-o", str(tmp_path), "--warmup", "soon"])
    assert r.exit_code == 2 and "--warmup 'soon'" in r.output and "(or auto, or 0 for nothing)" in r.output


def test_report_two_runs_has_combined_table(sim_run, tmp_path):
    import shutil

    path, _ = sim_run
    second = tmp_path / "second.h5"
    shutil.copy(path, second)
    out = tmp_path / "rep"
    r = CliRunner().invoke(cli, ["report", str(path), str(second), "-o", str(out), "--warmup", "0", "--channel", "*/z"])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader((out / "noise.csv").open(encoding="utf-8")))
    assert [row["device"] for row in rows] == [f"{path.stem}:bmx055", "second:bmx055"]
    assert rows[0]["sigma_w"] == rows[1]["sigma_w"]  # the same data gives the same fit
    assert (out / path.stem / "index.html").exists() and (out / "second" / "index.html").exists()
