"""Text logs with the common column names, one- and two-axis logs, a temperature column; ``inspect`` of an
imported file shows the end of the data, not the time of the conversion (issue 23)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.acquisition.importers import text_mapping
from imustation.cli import cli
from imustation.runfile import open_run

FS = 100.0
T0_S = 1_700_000_000.0  # Unix time of the first stamp: 2023-11-14T22:13:20 UTC


def _log(path, header: str, columns: list[np.ndarray], n: int = 3000, units: str = "# gyro: rad/s\n# accel: m/s^2\n"):
    t = T0_S + np.arange(n) / FS
    fmt = ["%.3f"] + ["%.17g"] * len(columns)  # stamps to the ms, as a logger writes them
    np.savetxt(path, np.column_stack([t, *columns]), delimiter=",", header=units + header, comments="", fmt=fmt)
    return t


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.mark.parametrize(
    "header, gyro, accel",
    [
        ("time,gx,gy,gz", ("x", "y", "z"), None),
        ("t,wx,wy,wz,ax,ay,az", ("x", "y", "z"), ("x", "y", "z")),
        ("stamp,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z", ("x", "y", "z"), ("x", "y", "z")),
        ("Time [s],Gyro X [rad/s],Gyro Y [rad/s]", ("x", "y"), None),  # a two-axis log, units in the names
        ("t,gz", ("z",), None),  # a single-axis fibre-optic gyro (DSP-3000)
        ("t,omega_z,accel_z", ("z",), ("z",)),
    ],
)
def test_common_column_names(tmp_path, header, gyro, accel):
    names = header.split(",")
    rng = np.random.default_rng(1)
    p = tmp_path / "log.csv"
    _log(p, header, [rng.normal(0, 1e-3, 3000) for _ in names[1:]])
    mp = text_mapping(str(p))
    assert mp.gyro_axes == gyro and len(mp.gyro_cols) == len(gyro)
    assert (mp.accel_axes if mp.accel_cols else None) == accel
    for axis, col in zip(mp.gyro_axes, mp.gyro_cols, strict=True):
        assert f"{axis} <- {names[col]!r}" in mp.summary()  # says which column was taken for which axis


def test_single_axis_log_imports_and_analyses(tmp_path):
    rng = np.random.default_rng(2)
    rate = rng.normal(0, 1e-3, 3000)
    p = tmp_path / "fog.csv"
    _log(p, "t,gz", [rate])
    out = tmp_path / "fog.h5"
    res = run("import", p, "-o", out)
    assert res.exit_code == 0, res.output
    assert "gyro z <- 'gz'" in res.output
    with open_run(out) as r:
        dev = r.devices["imu"]
        assert dev.channels["gyro"].axes == ("z",) and "accel" not in dev.channels
        np.testing.assert_array_equal(r.read("imu", "gyro")[:, 0], rate)
    res = run("analyze", p, "-m", "100")
    assert res.exit_code == 0, res.output
    assert "imu/gyro/z" in res.output and "imu/gyro/x" not in res.output


def test_temperature_column_becomes_a_thermometer_and_other_columns_are_named(tmp_path):
    rng = np.random.default_rng(3)
    temp = 25.0 + np.linspace(0, 1, 3000)
    p = tmp_path / "log.csv"
    _log(p, "time,gx,gy,gz,mag_x,temperature", [*rng.normal(0, 1e-3, (3, 3000)), rng.normal(size=3000), temp])
    res = run("import", p, "-o", tmp_path / "log.h5")
    assert res.exit_code == 0, res.output
    assert "temperature 'temperature' [°C]" in res.output and "ignored 'mag_x'" in res.output
    with open_run(tmp_path / "log.h5") as r:
        t, c = r.temperatures("imu_temperature")
        np.testing.assert_allclose(c, temp)


def test_log_without_gyro_names_the_accepted_names(tmp_path):
    p = tmp_path / "log.csv"
    _log(p, "time,foo,bar", [np.zeros(3000), np.zeros(3000)])
    res = run("import", p, "-o", tmp_path / "o.h5")
    assert res.exit_code == 2 and "no gyro columns found" in res.output and "gx/gy/gz" in res.output
    res = run("import", p, "-o", tmp_path / "o.h5", "--gyro-columns", "foo,bar,time,foo")
    assert res.exit_code == 2 and "one to three" in res.output


def test_inspect_of_an_import_shows_the_end_of_the_data(tmp_path):
    p = tmp_path / "log.csv"
    _log(p, "time,gx,gy,gz", list(np.random.default_rng(4).normal(0, 1e-3, (3, 3000))))
    out = tmp_path / "log.h5"
    assert run("import", p, "-o", out, "--quiet").exit_code == 0
    with open_run(out) as r:
        assert r.attrs["started_utc"] == "2023-11-14T22:13:20.000+00:00"
        assert r.attrs["ended_utc"] == "2023-11-14T22:13:49.990+00:00"  # the last stamp, 2999 periods later
        assert r.attrs["imported_utc"] > "2024"  # the conversion: now
    res = run("inspect", out)
    assert res.exit_code == 0, res.output
    assert "ended 2023-11-14T22:13:49.990+00:00" in res.output and "imported from" in res.output
    # a file imported before ended_utc meant the end of the data: derived from the last sample, and said so
    import h5py

    with h5py.File(out, "r+") as f:
        del f.attrs["imported_utc"]
        f.attrs["ended_utc"] = "2026-01-01T00:00:00.000+00:00"
    res = run("inspect", out)
    assert "ended 2023-11-14T22:13:49.990+00:00 (end of the data; the file says 2026-01-01" in res.output
