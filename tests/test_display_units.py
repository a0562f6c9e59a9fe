"""Every number carries its own channel's unit: the display-unit helper, analyze's text table, the report's
summary and flags for values that are not estimates (issue 23)."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import replace

import numpy as np
import pytest

from imustation.analysis.pipeline.channel import analyze_channel
from imustation.analysis.pipeline.loaders import Channel
from imustation.analysis.reports.analyzetable import results_table
from imustation.analysis.reports.summary import channel_estimates, summary_csv, summary_markdown, summary_rows
from imustation.analysis.reports.tables import (
    AT_BOUND,
    DOUBTFUL,
    NOT_IDENTIFIED,
    UPPER_BOUND,
    noise_rows,
    table_csv,
    table_latex,
    table_markdown,
)
from imustation.units import G0, display_units, sensor_kind

FS = 100.0


def test_display_units_per_sensor_kind():
    # the paper's Table IV units: deg/h/sqrt(Hz) for gyros, micro-g/sqrt(Hz) for accelerometers
    si, disp, k = display_units("gyro", "density")
    assert (si, disp) == ("rad/s/√Hz", "°/h/√Hz") and 1.6968e-4 * k == pytest.approx(35.0, abs=0.005)
    si, disp, k = display_units("accel", "density")
    assert (si, disp) == ("m/s²/√Hz", "µg/√Hz") and G0 * 1e-6 * k == pytest.approx(1.0)
    assert display_units("accel", "drift")[:2] == ("m/s³/√Hz", "µg/√s")
    assert display_units("gyro", "angle")[:2] == ("rad", "°")
    assert display_units(None, "density") == ("unit/√Hz", "unit/√Hz", 1.0)  # a plain array: no conversion
    assert display_units("accel", "time") == ("s", "s", 1.0)
    with pytest.raises(ValueError):
        display_units("baro", "density")
    assert sensor_kind("m/s^2") == "accel" and sensor_kind("", "dev/gyro/x") == "gyro" and sensor_kind("") is None


@pytest.fixture(scope="module")
def analysed():
    """An accelerometer and a gyro axis of 3 h-equivalent noise (fast: 100 Hz, 20k samples), and a short
    white-noise gyro whose tau_b ends at its search bound."""
    rng = np.random.default_rng(11)
    accel = Channel("imu/accel/x", FS, "m/s^2", 9.8 + rng.normal(0, 7e-4 * math.sqrt(FS), 20_000))
    gyro = Channel("imu/gyro/x", FS, "rad/s", rng.normal(0, 1.7e-4 * math.sqrt(FS), 20_000))
    short = Channel("fog/gyro/z", FS, "rad/s", np.random.default_rng(1).normal(0, 1e-3, 2000))
    return [analyze_channel(ch, model="wn+gm") for ch in (accel, gyro, short)]  # the paper's model: tau_b at its bound


def test_analyze_table_gives_each_kind_its_units(analysed):
    text = results_table(analysed)
    acc_block, gyro_block = text.split("\n\n")[:2]
    # the block titles name the units the columns are in, not SI (issue 34: "(m/s²)" over µg columns)
    assert acc_block.startswith("accelerometers (in µg units; --json in SI, m/s²)")
    assert "N [µg/√Hz]" in acc_block and "K [µg/√s]" in acc_block
    assert "°/h" not in acc_block and "deg/h" not in acc_block
    assert gyro_block.startswith("gyroscopes (in °/h units; --json in SI, rad/s)")
    assert "N [°/h/√Hz]" in gyro_block and "B [°/h]" in gyro_block
    # the accelerometer's N (the model's sigma_w) in micro-g/sqrt(Hz): 7e-4 m/s^2/sqrt(Hz) = 71.4 ug/sqrt(Hz)
    acc_row = next(ln for ln in acc_block.splitlines() if ln.startswith("imu/accel/x"))
    assert float(acc_row.split()[2]) == pytest.approx(7e-4 / G0 * 1e6, rel=0.05)
    assert "sigma_w (unit)/s*sqrt(s)" not in text
    # tau_b at its search bound is printed as such, with a legend line
    fog = next(ln for ln in gyro_block.splitlines() if ln.startswith("fog/gyro/z"))
    assert "at bound" in fog and "at bound: the fit stopped at its search bound" in text


def test_analyze_table_is_one_row_per_channel_and_a_short_attention_list(analysed):
    """199 lines of analyze text for one 3 h file (comparison fits, 45 'does not fit' lines, verdicts of
    250-400 characters): now one row per channel, a short list of what needs attention, details with -v."""
    text = results_table(analysed)
    rows = [ln for ln in text.splitlines() if ln.split()[:1] and ln.split()[0] in ("imu/accel/x", "imu/gyro/x",
                                                                                    "fog/gyro/z")]  # fmt: skip
    assert len(rows) == 3 and "ML_i" not in text and "model fit?" not in text
    head, _, todo = text.partition("needs attention (")
    assert todo and "fog/gyro/z: " in todo and "tau_b at the search bound" in todo
    assert max(len(ln) for ln in todo.splitlines()) < 250
    assert "details:" not in text
    verbose = results_table(analysed, verbose=True)
    assert verbose.startswith(text) and "details:" in verbose and "  mli: ML_i wn+gm" in verbose


def test_summary_and_flags(analysed):
    fog = analysed[2].noise_model
    assert "tau_b" in fog.at_bound
    rows = noise_rows(analysed)
    assert rows[2].flag("tau_b") == AT_BOUND
    md = table_markdown(rows)
    assert f"at bound ({fog.tau_b:.3g})" in md and f"| {fog.tau_b:.3g} |" not in md
    # the classical IEEE fit of pure white noise leaves B or K out (the record's last taus may suggest the
    # other): in its comparison table a term not fitted is a dash, empty in the CSV's <q>_allan
    q = next(q for q in ("B", "K") if getattr(analysed[1].ieee, q) == 0.0)
    assert rows[1].allan[q] == 0.0
    table = list(csv.DictReader(io.StringIO(table_csv(rows))))
    assert table[1][f"{q}_allan"] == "" and table[2]["tau_b_flag"] == AT_BOUND
    assert "classical IEEE-952 fit of the Allan curve (comparison only" in md
    assert "--" in table_latex(rows) and r"\textsuperscript{b}" in table_latex(rows)
    # the noise table's N, B, K are the summary's (the model's ieee952 block), not the classical fit's
    for row, res in zip(rows, analysed, strict=True):
        est = channel_estimates(res)
        for k in ("N", "B", "K"):
            assert row.values[k] == est[k].value or (math.isnan(row.values[k]) and math.isnan(est[k].value))
            assert (row.flag(k) or "") in (est[k].flag, DOUBTFUL)
    assert table[1][f"{q}_flag"] in ("", UPPER_BOUND) and table[1][q] != ""

    summary = summary_rows(analysed)
    s_md = summary_markdown(summary)
    assert "N [µg/√Hz]" in s_md and "N [°/h/√Hz]" in s_md and "σ_b [°/h/√h]" in s_md and "τ_b [s]" in s_md
    gyro_line = next(ln for ln in s_md.splitlines() if ln.startswith("| imu | x-gyro"))
    cells = [c.strip() for c in gyro_line.strip("|").split("|")]
    n_cell, q_cell = cells[3], cells[{"B": 4, "K": 5}[q]]
    n, lo, hi = (float(v) for v in n_cell.replace("[", "").replace("]", "").replace(",", "").split())
    assert lo < n < hi and n == pytest.approx(1.7e-4 * 3600 * 180 / math.pi, rel=0.05)  # deg/h/sqrt(Hz)
    # B and K in the summary are the model's (its ieee952 block: the verdict's and export's numbers), not the
    # classical Allan fit's: a term the model carries with its interval, else the Allan deviation's 90 % bound
    gyro_x = next(r for r in analysed if r.channel.id.endswith("gyro/x"))
    block = gyro_x.ieee952(gyro_x.noise_model)
    if block[f"{q}_detected"]:
        assert "[" in q_cell and not q_cell.startswith("<")
    else:
        assert q_cell.startswith("< ")
    # the fit verdict is the model-adequacy test's (docs/noise-model.md); the data verdict is given
    assert cells[-2].startswith(("fits", "does not fit")) and cells[-1] in ("enough", "marginal", "not enough")
    s_csv = list(csv.DictReader(io.StringIO(summary_csv(summary))))
    assert s_csv[2]["tau_b_flag"] == AT_BOUND and s_csv[0]["N_unit"] == "m/s²/√Hz"
    assert float(s_csv[1]["N_lo90"]) < float(s_csv[1]["N"]) < float(s_csv[1]["N_hi90"])


def test_not_identified_when_the_interval_spans_two_decades(analysed):
    fit = analysed[1].noise_model
    wide = replace(fit, ci90={**fit.ci90, "sigma_b": (fit.sigma_b / 30, fit.sigma_b * 30)}, at_bound=())
    row = noise_rows([replace(analysed[1], noise_model=wide)])[0]
    assert row.flag("sigma_b") == NOT_IDENTIFIED
    assert "not identified" in table_markdown([row])


def test_a_noise_density_with_a_wide_interval_is_doubtful_for_sigma_w_and_n(analysed):
    res = analysed[1]
    fit = res.noise_model
    assert noise_rows([res])[0].flags.get("sigma_w", "") == ""  # a tight sigma_w is a plain number
    # the interval finescale.white_bound gives when the slow terms reach the fine scales
    wide = replace(fit, ci90={**fit.ci90, "sigma_w": (0.75 * fit.sigma_w, 1.01 * fit.sigma_w)})
    row = noise_rows([replace(res, noise_model=wide)])[0]
    assert row.flag("sigma_w") == DOUBTFUL and row.flag("N") == DOUBTFUL
    assert f"doubtful ({fit.sigma_w:.3g})" in table_markdown([row])
    assert r"\textsuperscript{d}" in table_latex([row])
    line = next(csv.DictReader(io.StringIO(table_csv([row]))))
    assert line["sigma_w_flag"] == DOUBTFUL and float(line["sigma_w"]) == fit.sigma_w


def test_model_names_are_spelled_out_in_every_help():
    from click.testing import CliRunner

    from imustation.analysis.estimators.models.noise_models import TERM_ORDER
    from imustation.analysis.pipeline.choices import MODEL_TERMS
    from imustation.cli import cli

    assert set(MODEL_TERMS) == set(TERM_ORDER)  # a new term code needs its words in the help
    for cmd in ("analyze", "report", "export", "fleet"):
        out = " ".join(CliRunner().invoke(cli, [cmd, "--help"]).output.split())
        for words in ("wn white rate noise", "gm first-order Gauss-Markov bias", "rw rate random walk",
                      "wa white angle noise"):  # fmt: skip
            assert words in out, (cmd, words)


def test_plain_arrays_keep_their_own_unit():
    # a plain array does not say what it measured: no gyro or accelerometer display unit is made up
    ch = Channel("plain/0", FS, "", np.random.default_rng(6).normal(0, 1e-3, 20_000))
    text = results_table([analyze_channel(ch)])
    assert text.startswith("plain arrays, in their own unit") and "unit/√Hz" in text
    assert "°" not in text and "µg" not in text
