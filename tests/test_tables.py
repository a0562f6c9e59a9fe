"""Noise table: unit conversions (docs/reference/noise-formulas.md §3.1 worked values) and the three formats."""

from __future__ import annotations

import csv
import io
import math

import pytest

from imustation.analysis.reports.tables import NoiseRow, table_csv, table_latex, table_markdown, units_of

# EuRoC ADIS16448 (docs/reference/noise-formulas.md §3.1):
# 1.6968e-4 rad/s/sqrt(Hz) = 35.0 deg/h/sqrt(Hz) = 0.5833 deg/sqrt(h)
EUROC = {"sigma_w": 1.6968e-4, "sigma_b": 1.9393e-5, "tau_b": 300.0, "N": 1.6968e-4, "B": 1e-5, "K": 1.9393e-5}
EUROC["adev_1s"] = 1.7e-4


def _rows():
    gyro = NoiseRow("adis16448", "gyro", "x", 1000, 200.0, "wn+gm", dict(EUROC))
    acc = dict.fromkeys(EUROC, 2.0e-3) | {"tau_b": math.inf}
    accel = NoiseRow("adis16448", "accel", "z", 1000, 200.0, "wn+rw", acc)
    return [gyro, accel]


def test_gyro_display_units():
    gyro = _rows()[0]
    assert gyro.display("sigma_w") == pytest.approx(35.0, abs=0.005)
    assert gyro.display("sigma_w") / 60.0 == pytest.approx(0.5833, abs=5e-5)  # deg/sqrt(h) ARW
    # rad/s^2/sqrt(Hz) -> deg/h/sqrt(h): times 3600*180/pi (rad/s -> deg/h) times sqrt(3600 s/h)
    assert gyro.display("K") == pytest.approx(1.9393e-5 * 180 / math.pi * 3600 * 60, rel=1e-12)
    assert gyro.display("B") == pytest.approx(1e-5 * 180 / math.pi * 3600, rel=1e-12)
    assert units_of("gyro", "sigma_w")[:2] == ("rad/s/√Hz", "°/h/√Hz")


def test_accel_display_units():
    accel = _rows()[1]
    # 2.0e-3 m/s^2/sqrt(Hz) / 9.80665 m/s^2 per g = 203.9 ug/sqrt(Hz)
    assert accel.display("sigma_w") == pytest.approx(203.94, abs=0.01)
    assert units_of("accel", "sigma_w")[1] == "µg/√Hz" and units_of("accel", "B")[1] == "µg"


def test_csv_has_si_and_display_side_by_side():
    rows = list(csv.DictReader(io.StringIO(table_csv(_rows()))))
    assert len(rows) == 2
    g = rows[0]
    assert float(g["sigma_w"]) == 1.6968e-4 and g["sigma_w_unit"] == "rad/s/√Hz"
    assert float(g["sigma_w_display"]) == pytest.approx(35.0, abs=0.005) and g["sigma_w_display_unit"] == "°/h/√Hz"
    assert rows[1]["tau_b"] == "inf"


def test_markdown_and_latex():
    md = table_markdown(_rows())
    assert "| adis16448 | x-gyro | 0.00017 | 35 |" in md
    assert "σ_w [rad/s/√Hz] | σ_w [°/h/√Hz]" in md and "µg/√Hz" in md and "∞" in md
    tex = table_latex(_rows())
    assert tex.count(r"\begin{tabular}") == 2 and tex.count(r"\end{tabular}") == 2
    assert r"$1.70\times10^{-4}$" in tex and r"$3.50\times10^{1}$" in tex
    # every row has as many cells as the header
    for block in tex.split(r"\begin{tabular}")[1:]:
        body = [ln for ln in block.splitlines() if ln.endswith(r"\\")]
        assert len({ln.count("&") for ln in body}) == 1
