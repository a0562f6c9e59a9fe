"""Bad input: one clear line naming the file and the problem, exit code 2, no traceback."""

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from imustation.cli import cli
from imustation.errors import InputError


def run(*args):
    res = CliRunner().invoke(cli, list(args))
    return res


def assert_one_line_error(res, *needles):
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1, res.output
    for needle in needles:
        assert needle in lines[0], lines[0]


def test_missing_config(tmp_path):
    assert_one_line_error(run("capture", str(tmp_path / "nope.toml"), "--simulate"), "nope.toml", "no such file")


def test_malformed_config(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[station\nname = 1")
    assert_one_line_error(run("capture", str(p), "--simulate"), "bad.toml", "invalid TOML")


@pytest.mark.parametrize(
    "body,needles",
    [
        ('[[device]]\nname="g"\ndriver="nosuch"\nbus="i2c:1"\n', ["device[0].driver", "'nosuch'", "known: ", "bmx055"]),
        ('[[device]]\nname="g"\ndriver="bmx055"\nbus="i2c:1"\nrate_hz=123\n', ["rate_hz = 123", "allows"]),
        ('[[device]]\nname="g"\ndriver="bmx055"\nbus="usb3:1"\n', ["device[0].bus", "unknown scheme"]),
        (
            '[station]\nflush_interval_s=0\n[[device]]\nname="g"\ndriver="bmx055"\nbus="i2c:1"\n',
            ["station.flush_interval_s"],
        ),
        ('[station]\nname="x"\n', ["at least one [[device]]"]),
        (
            '[[device]]\nname="g"\ndriver="bmx055"\nbus="i2c:1"\n[[device]]\nname="g"\ndriver="bmx055"\nbus="i2c:1"\n',
            ["used twice"],
        ),
    ],
)
def test_config_errors(tmp_path, body, needles):
    p = tmp_path / "c.toml"
    p.write_text(body)
    assert_one_line_error(run("capture", str(p), "--simulate"), "c.toml", *needles)


def test_bad_duration(demo_config):
    assert_one_line_error(run("capture", demo_config.path, "--simulate", "--duration", "soon"), "duration 'soon'")


def test_demo_output_needs_an_h5_name(tmp_path):
    # refused before the simulation, not after it when the analysis cannot open the file
    res = run("demo", "-o", str(tmp_path / "night"), "--duration", "10s")
    assert_one_line_error(res, "-o", "needs an .h5 name")
    assert not (tmp_path / "night").exists()


def test_not_hdf5(tmp_path):
    p = tmp_path / "x.h5"
    p.write_text("hello")
    assert_one_line_error(run("inspect", str(p)), "x.h5", "not a readable HDF5 file")
    assert_one_line_error(run("analyze", str(p)), "x.h5", "not a readable HDF5 file")


def test_not_an_imustation_file(tmp_path):
    p = tmp_path / "other.h5"
    with h5py.File(p, "w") as f:
        f["x"] = [1, 2, 3]
    assert_one_line_error(run("inspect", str(p)), "other.h5", "not an imustation run file")


def test_missing_run_file(tmp_path):
    assert_one_line_error(run("analyze", str(tmp_path / "none.h5")), "none.h5", "no such file")


def test_npy_without_rate(tmp_path):
    p = tmp_path / "gyro.npy"
    np.save(p, np.zeros(100))
    assert_one_line_error(run("analyze", str(p)), "gyro.npy", "--rate")


def test_empty_and_nan_arrays(tmp_path):
    empty, nan = tmp_path / "empty.npy", tmp_path / "nan.npy"
    np.save(empty, np.zeros(0))
    np.save(nan, np.array([1.0, np.nan, 2.0]))
    assert_one_line_error(run("analyze", str(empty), "--rate", "100"), "empty.npy", "empty")
    assert_one_line_error(run("analyze", str(nan), "--rate", "100"), "nan.npy", "1 NaN")


def test_bad_rate_value(tmp_path):
    p = tmp_path / "g.npy"
    np.save(p, np.zeros(100))
    assert_one_line_error(run("analyze", str(p), "--rate", "-5"), "--rate")


def test_no_matching_channel(tmp_path, sim_run):
    path, _ = sim_run
    assert_one_line_error(run("analyze", str(path), "--channel", "nope/*"), "no channels matching nope/*")


@pytest.mark.parametrize(
    "text,seconds",
    [
        ("90min", 5400.0),
        ("500ms", 0.5),
        ("1h30m", 5400.0),
        ("5m30s", 330.0),
        ("1d2h", 93600.0),
        ("2 h", 7200.0),
        (" 1 h 30 m ", 5400.0),
        ("45 s", 45.0),
    ],
)
def test_parse_duration_takes_every_unit_it_defines(text, seconds):
    from imustation.units import parse_duration

    assert parse_duration(text) == pytest.approx(seconds)


@pytest.mark.parametrize("text", ["12", "1h30", "2.5"])
def test_a_bare_number_is_not_a_duration(text):
    """'--duration 12' recorded 12 s for someone meaning 12 h: every number needs its unit."""
    from imustation.units import parse_duration

    with pytest.raises(InputError, match=r"--duration .*needs a unit \(ms, s, m or min, h, d\)"):
        parse_duration(text, "--duration")


def test_capture_duration_words_and_units(tmp_path, demo_config):
    out = tmp_path / "r.h5"
    res = run("capture", demo_config.path, "--simulate", "--quiet", "-o", str(out), "--duration", "12")
    assert_one_line_error(res, "--duration '12'", "needs a unit", "12h")
    assert not out.exists()
    # unquoted '--duration 2 s' is two shell words: joined, not 'unexpected extra argument'
    res = run("capture", demo_config.path, "--simulate", "--quiet", "-o", str(out), "--duration", "2", "s")
    assert res.exit_code == 0, res.output
    assert ", 2s in" in res.output and out.exists()


@pytest.mark.parametrize("duration,shown", [("10ms", "0.01s"), ("0.5s", "0.5s")])
def test_capture_shorter_than_a_flush_is_refused_before_recording(tmp_path, demo_config, duration, shown):
    """--duration 10ms wrote a 0-sample file that every analysis command then rejected."""
    out = tmp_path / "r.h5"
    res = run("capture", demo_config.path, "--simulate", "-o", str(out), "--duration", duration)
    assert_one_line_error(res, f"--duration {shown}", "shorter than one flush interval", "at least 1s")
    assert list(tmp_path.iterdir()) == []


def test_shortest_capture_is_set_by_the_slowest_device(tmp_path):
    from imustation.acquisition import load_config
    from imustation.acquisition.capture import check_capture_duration, shortest_capture_s

    p = tmp_path / "slow.toml"
    p.write_text(
        '[station]\nflush_interval_s = 0.5\n[[device]]\nname = "g"\ndriver = "bmx055"\nbus = "i2c:1"\n'
        "address = 0x68\nrate_hz = 400\n"
        '[[thermometer]]\nname = "slow"\ndriver = "mcp9804"\nbus = "i2c:2"\naddress = 0x18\nrate_hz = 0.25\n',
    )
    cfg = load_config(p)
    assert shortest_capture_s(cfg)[0] == 4.0
    with pytest.raises(InputError, match="one sample period of slow"):
        check_capture_duration(cfg, 2.0)


@pytest.mark.parametrize(
    "rotate,duration,needles",
    [
        ("1s", "1000000d", ["--rotate 1s", "parts", "at most 10000"]),
        ("0.01s", "1m", ["--rotate 0.01s", "at least 1 s"]),
    ],
)
def test_rotation_is_bounded_before_anything_is_written(tmp_path, demo_config, rotate, duration, needles):
    """Part names used to be built for every part up front (out of memory for 8.6e10 parts), and
    --rotate 0.01s made tens of thousands of files; both are refused before any file exists."""
    out = tmp_path / "rot.h5"
    res = run("capture", demo_config.path, "--simulate", "-o", str(out), "--rotate", rotate, "--duration", duration)
    assert_one_line_error(res, *needles)
    assert list(tmp_path.iterdir()) == []


def test_a_real_capture_whose_bus_is_missing_points_to_devices(tmp_path):
    """A real capture on a machine without the bus gave only 'cannot open /dev/i2c-99'; 'devices' knows
    the cause and the remedy (module, permission, udev, port), so the error names it (newcomer run)."""
    cfg = tmp_path / "one.toml"
    cfg.write_text(
        '[station]\nname = "t"\n[[device]]\nname = "bmx055"\ndriver = "bmx055"\nbus = "i2c:99"\n'
        "address = 0x68\nrate_hz = 400\n"
    )
    out = tmp_path / "x.h5"
    r = CliRunner().invoke(cli, ["capture", str(cfg), "--duration", "10s", "-o", str(out)])
    assert r.exit_code == 2, r.output
    assert "cannot open /dev/i2c-99" in r.output and f"imustation devices {cfg}" in r.output
    assert not out.exists()
