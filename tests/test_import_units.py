"""Text logs that cannot lie (issue 33): units from the header or the options, never guessed; the rate
from a fit over every stamp; stamps read exactly; start times to the stamps' own resolution."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from test_bad_input import assert_one_line_error

from imustation.acquisition.importers import check_stamps, import_recording, text_mapping
from imustation.acquisition.importers.textcells import to_ns
from imustation.acquisition.importers.units import column_unit, comment_units
from imustation.cli import cli
from imustation.runfile import open_run

T0_NS = 1_700_000_000_123_456_789


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _write(path, header: str, t_cells: list[str], columns: np.ndarray, comments: str = "") -> None:
    lines = [comments + header] if comments else [header]
    lines += [",".join([tc, *(f"{v:.17g}" for v in row)]) for tc, row in zip(t_cells, columns, strict=True)]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(
    "name, unit",
    [
        ("gyro_x_dps", "deg/s"),
        ("Gyro X [deg/s]", "deg/s"),
        ("wx (rad/s)", "rad/s"),
        ("gx_rads", "rad/s"),
        ("gyro_z_mdps", "mdeg/s"),
        ("omega_z [deg/h]", "deg/h"),
        ("acc_x_g", "g"),
        ("ax [m/s^2]", "m/s^2"),
        ("accel_y (m/s²)", "m/s^2"),
        ("az_mg", "mg"),
        ("acc_z_mps2", "m/s^2"),
        ("gx", None),
        ("acc_x", None),
        ("temp_c", None),
    ],
)
def test_units_in_column_names(name, unit):
    assert column_unit(name) == unit


def test_units_in_header_comments():
    assert comment_units(["# gyro: deg/s", "# accel [g]"]) == {
        "gyro": ("deg/s", "# gyro: deg/s"),
        "accel": ("g", "# accel [g]"),
    }
    assert comment_units(["# units: rad/s, m/s^2"]) == {
        "gyro": ("rad/s", "# units: rad/s, m/s^2"),
        "accel": ("m/s^2", "# units: rad/s, m/s^2"),
    }
    assert comment_units(["# recorded by logger 2.1 on 2024-05-01"]) == {}


def test_a_dps_log_is_read_in_degrees_and_says_so(tmp_path):
    rng = np.random.default_rng(1)
    n = 2000
    w_rad = rng.normal(0, 1e-4, (n, 3)) * math.sqrt(200)  # white noise of density 1e-4 rad/s/sqrt(Hz) at 200 Hz
    t = [f"{k * 0.005:.3f}" for k in range(n)]
    p = tmp_path / "dps.csv"
    _write(p, "timestamp,gyro_x_dps,gyro_y_dps,gyro_z_dps", t, np.degrees(w_rad))
    res = run("import", p, "-o", tmp_path / "o.h5")
    assert res.exit_code == 0, res.output
    assert "gyro x <- 'gyro_x_dps', y <- 'gyro_y_dps', z <- 'gyro_z_dps' [deg/s, from column names]" in res.output
    with open_run(tmp_path / "o.h5") as r:
        np.testing.assert_allclose(r.read("imu", "gyro"), w_rad, rtol=1e-12)  # rad/s, not deg/s taken as rad/s
        dev = r.devices["imu"]
        assert dev.settings["source_gyro_unit"] == "deg/s"
        assert dev.settings["source_gyro_unit_from"] == "column names"
        assert "[deg/s, from column names]" in dev.identity


def test_units_from_a_header_comment_and_the_options(tmp_path):
    n = 500
    t = [f"{k * 0.01:.2f}" for k in range(n)]
    data = np.column_stack([np.full((n, 3), 0.5), np.tile([0.0, 0.0, 1.0], (n, 1))])  # deg/s, g
    p = tmp_path / "c.csv"
    _write(p, "t,gx,gy,gz,ax,ay,az", t, data, comments="# gyro: deg/s\n# accel: g\n")
    mp = text_mapping(str(p))
    assert (mp.gyro_unit, mp.accel_unit) == ("deg/s", "g")
    assert "header comment '# gyro: deg/s'" in mp.summary()
    res = import_recording(str(p), str(tmp_path / "c.h5"))
    assert not [w for w in res.notes if "unit" in w]  # 1 g at rest, 0.5 deg/s: plausible
    with open_run(tmp_path / "c.h5") as r:
        np.testing.assert_allclose(r.read("imu", "accel")[:, 2], 9.80665)
        np.testing.assert_allclose(r.read("imu", "gyro")[:, 0], math.radians(0.5))
    # the option wins over the header and says what the header said
    mp = text_mapping(str(p), gyro_unit="rad/s")
    assert mp.gyro_unit == "rad/s" and "--gyro-unit" in mp.summary()


def test_a_log_without_units_is_refused_naming_the_option(tmp_path):
    n = 300
    t = [f"{k * 0.01:.2f}" for k in range(n)]
    p = tmp_path / "plain.csv"
    _write(p, "t,gx,gy,gz,ax,ay,az", t, np.zeros((n, 6)) + [0, 0, 0, 0, 0, 9.81])
    assert_one_line_error(run("import", p, "-o", tmp_path / "o.h5"), "plain.csv", "--gyro-unit", "'gx'")
    assert_one_line_error(run("analyze", p), "plain.csv", "--gyro-unit")
    assert_one_line_error(
        run("import", p, "-o", tmp_path / "o.h5", "--gyro-unit", "deg/s"), "plain.csv", "--accel-unit"
    )
    res = run("import", p, "-o", tmp_path / "o.h5", "--gyro-unit", "deg/s", "--accel-unit", "m/s^2")
    assert res.exit_code == 0, res.output
    assert_one_line_error(
        run("import", p, "-o", tmp_path / "x.h5", "--gyro-unit", "furlong/s"), "furlong/s", "rad/s, deg/s"
    )


def test_a_static_record_implausible_for_its_unit_is_flagged(tmp_path):
    n = 1000
    t = [f"{k * 0.01:.2f}" for k in range(n)]
    # accel in g, gyro in deg/s with a 20 deg/s bias, both stated (wrongly) as SI by the options
    data = np.column_stack([np.full((n, 3), 20.0), np.tile([0.0, 0.0, 1.0], (n, 1))])
    p = tmp_path / "g.csv"
    _write(p, "t,gx,gy,gz,ax,ay,az", t, data)
    res = run("import", p, "-o", tmp_path / "g.h5", "--gyro-unit", "rad/s", "--accel-unit", "m/s^2")
    assert res.exit_code == 0, res.output
    assert "mean acceleration 1 m/s^2" in res.output and "--accel-unit" in res.output
    assert "mean gyro rate 34.64 rad/s" in res.output and "--gyro-unit" in res.output
    with open_run(tmp_path / "g.h5") as r:
        notes = [e.detail for e in r.events() if e.kind == "note"]
    assert any("mean acceleration" in d for d in notes) and any("mean gyro rate" in d for d in notes)


def test_integer_ms_stamps_give_the_fitted_rate_and_a_warning(tmp_path):
    """A 400 Hz log with integer-ms stamps (steps 2, 3, 2, 3 ms): the median step said 500 Hz."""
    n = 8000
    rng = np.random.default_rng(5)
    t_ms = np.floor(np.arange(n) * 2.5).astype(np.int64) + 1_700_000_000_000
    p = tmp_path / "ms.csv"
    _write(p, "time_ms,gx_rads,gy_rads,gz_rads", [str(v) for v in t_ms], rng.normal(0, 1e-3, (n, 3)))
    res = run("import", p, "-o", tmp_path / "ms.h5")
    assert res.exit_code == 0, res.output
    assert "stamps quantised to 1 ms, 0.4 of the 2.5 ms period" in res.output
    with open_run(tmp_path / "ms.h5") as r:
        assert r.devices["imu"].rate_hz == pytest.approx(400.0, rel=1e-4)
        assert r.attrs["started_utc"] == "2023-11-14T22:13:20.000+00:00"
    # and streamed into analyze: the same rate
    from imustation.cli._field import streamed_channels

    text = {"time_col": None, "gyro_cols": None, "accel_cols": None, "gyro_unit": None, "accel_unit": None}
    ch = streamed_channels(str(p), [], quiet=True, topic=None, time_unit=None, text=text)[0]
    assert ch.fs_hz == pytest.approx(400.0, rel=1e-4)


def test_rate_fit_excludes_gaps_and_ignores_the_median():
    t = (np.floor(np.arange(20000) * 2.5) * 1e6).astype(np.int64)
    t = np.delete(t, np.r_[100:140, 5000:5003, 12000:12500])
    rep = check_stamps(t)
    assert rep.true_rate_hz == pytest.approx(400.0, rel=1e-5) and rep.gaps == 3
    assert rep.quantum_ns == 1_000_000 and rep.warnings()
    # integer ns stamps at 200 Hz with +-300 ns jitter: 200 Hz, not 200.003
    rng = np.random.default_rng(2)
    t = np.arange(6000, dtype=np.int64) * 5_000_000 + rng.integers(-300, 300, 6000)
    assert check_stamps(t).true_rate_hz == pytest.approx(200.0, rel=1e-7)
    assert not check_stamps(t).warnings()


def test_unix_ns_stamps_are_read_exactly_and_started_utc_keeps_them(tmp_path):
    n = 3000
    rng = np.random.default_rng(7)
    t = T0_NS + np.arange(n, dtype=np.int64) * 5_000_000 + rng.integers(-150, 150, n)
    p = tmp_path / "ns.csv"
    _write(p, "stamp_ns,gx,gy,gz", [str(v) for v in t], rng.normal(0, 1e-3, (n, 3)), comments="# gyro: rad/s\n")
    res = run("import", p, "-o", tmp_path / "ns.h5", "--quiet")
    assert res.exit_code == 0, res.output
    with open_run(tmp_path / "ns.h5") as r:
        np.testing.assert_array_equal(r.read("imu", "t"), t - t[0])  # not one stamp off (float64 lost up to 149 ns)
        assert r.attrs["started_utc"] == f"2023-11-14T22:13:20.{t[0] % 10**9:09d}+00:00"
    # decimal seconds keep their digits too
    assert to_ns("1700000000.123456789", 9) == 1_700_000_000_123_456_789
    assert to_ns("-0.5", 6) == -500_000 and to_ns("12", 3) == 12_000 and to_ns("1.7e9", 9) == 1_700_000_000 * 10**9


def test_nan_and_non_utf8_are_one_line_with_their_true_line(tmp_path):
    n = 6000
    t = [f"{k * 0.005:.3f}" for k in range(n)]
    rows = np.zeros((n, 3))
    rows[499, 1] = np.nan  # data line 500, file line 502 (a comment and the header before it)
    p = tmp_path / "nan.csv"
    _write(p, "t,gx,gy,gz", t, rows, comments="# gyro: rad/s\n")
    assert_one_line_error(run("import", p, "-o", tmp_path / "o.h5"), "nan.csv", "line 502", "NaN")
    p = tmp_path / "latin1.csv"
    _write(p, "t,gx,gy,gz", t, np.zeros((n, 3)), comments="# gyro: rad/s\n")
    raw = bytearray(p.read_bytes())
    at = raw.index(b"\n", len(raw) // 2) + 1  # the start of a line in the middle
    raw[at : at + 1] = b"\xe9"
    p.write_bytes(bytes(raw))
    line = raw[:at].count(b"\n") + 1
    assert_one_line_error(run("import", p, "-o", tmp_path / "o.h5"), "latin1.csv", f"line {line}", "0xe9", "UTF-8")
    assert_one_line_error(run("analyze", p), "latin1.csv", "UTF-8")


def test_an_integer_npy_keeps_its_unix_ns_stamps(tmp_path):
    n = 1000
    t = T0_NS + np.arange(n, dtype=np.int64) * 5_000_000 + np.random.default_rng(3).integers(-150, 150, n)
    arr = np.column_stack([t, np.zeros((n, 3), np.int64)])
    np.save(tmp_path / "ns.npy", arr)
    res = run("import", tmp_path / "ns.npy", "-o", tmp_path / "ns.h5", "--time-unit", "ns", "--quiet")
    assert res.exit_code == 0, res.output
    with open_run(tmp_path / "ns.h5") as r:
        np.testing.assert_array_equal(r.read("imu", "t"), t - t[0])


@pytest.mark.parametrize(
    "cell, exp, ns",
    [
        ("1700000000.123456789", 9, 1_700_000_000_123_456_789),
        ("-0.5", 6, -500_000),
        (" 2.5 ", 6, 2_500_000),
        ("-1.25", 9, -1_250_000_000),
        (".5", 9, 500_000_000),
        ("5.", 9, 5_000_000_000),
        ("+3.5", 3, 3500),
        ("1.23456789012", 9, 1_234_567_890),  # beyond 1 ns: rounded
        ("1.5", 0, 2),
        ("1.7e9", 9, 1_700_000_000 * 10**9),
    ],
)
def test_time_cells_are_read_to_the_ns(cell, exp, ns):
    assert to_ns(cell, exp) == ns


@pytest.mark.parametrize("cell", ["x", "1.2.3", "nan", "inf", "", "1e400", "1.x"])
def test_time_cells_that_are_not_times(cell):
    with pytest.raises(ValueError):
        to_ns(cell, 9)


def test_accel_unit_help_says_where_its_default_comes_from():
    """The help said "default: as --gyro-unit", yet --gyro-unit deg/s alone leaves a unit-less accel refused."""
    for cmd in ("import", "analyze"):
        text = " ".join(run(cmd, "--help").output.split())
        assert "as --gyro-unit" not in text
        assert "g or mg (default: from the column names or a header comment, as for the gyro" in text
