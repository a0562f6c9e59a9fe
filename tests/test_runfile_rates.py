"""A run file's rate against its timestamps, and attribute values out of physical range (issue 33):
a file whose every loss is logged reads, a rate the stamps contradict is refused or corrected the
same way by every reader, impossible values are refused on read."""

from __future__ import annotations

import json
import shutil
import warnings

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from fuzz_corpus import base_run
from test_bad_input import assert_one_line_error

from imustation.analysis.pipeline.loaders import load_run
from imustation.channels import ChannelSpec
from imustation.cli import cli
from imustation.errors import RateCorrected, RunFileError
from imustation.runfile import DeviceSpec, RunWriter, open_run
from imustation.runfile.checks import RATE_FLOOR
from imustation.runfile.rate import stamp_rate

RATE = 409.6  # ADIS16448
PERIOD_NS = 1e9 / RATE


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _write(path, kept: np.ndarray, rate_hz: float, *, driver="adis16448", log_losses=True, seed=1) -> None:
    """A gyro record of the sample indices ``kept`` at ``rate_hz``, each hole logged as a gap event."""
    rng = np.random.default_rng(seed)
    t = np.rint(kept * 1e9 / rate_hz).astype(np.int64)
    counts = rng.normal(0, 40, (len(kept), 3)).astype(np.int16)
    spec = DeviceSpec(
        "imu", driver, "ADIS16448", "spi:0", "sim", rate_hz, {},
        (ChannelSpec("gyro", "<i2", "rad/s", 1e-4, axes=("x", "y", "z")),),
    )  # fmt: skip
    with RunWriter(path, station="t", config_text="", simulated=True, devices=[spec], ballast_bytes=0) as w:
        w.append("imu", t, {"gyro": counts})
        if log_losses:
            jumps = np.flatnonzero(np.diff(kept) > 1)
            for j in jumps:
                lost = int(kept[j + 1] - kept[j] - 1)
                w.event(int(t[j] + 1e9 / rate_hz), "imu", "gap", "not read for ...", lost=lost)


def _lossy(n: int, frac: float, seed: int = 2) -> np.ndarray:
    """Indices kept of ``n`` when ``frac`` of them are lost in holes every 16 to 32 samples (a host that
    misses a read now and then: most 16-sample windows hold a hole)."""
    rng = np.random.default_rng(seed)
    keep = np.ones(n, bool)
    at = 0
    while at < n:
        run_ = int(rng.integers(16, 33))
        hole = int(round(run_ * frac / (1 - frac) * rng.uniform(0.5, 1.5)))
        keep[at + run_ : at + run_ + hole] = False
        at += run_ + hole
    return np.flatnonzero(keep)


def test_a_file_with_40_percent_lost_in_small_logged_holes_reads(tmp_path):
    kept = _lossy(60_000, 0.40)
    assert 0.38 < 1 - len(kept) / (kept[-1] + 1) < 0.42
    p = tmp_path / "holes.h5"
    _write(p, kept, RATE)
    with open_run(p) as r:  # before: "rate_hz 409.6 contradicts its timestamps (299 Hz ...)"
        assert r.devices["imu"].rate_hz == RATE and not r.devices["imu"].rate_note
    res = run("inspect", p)
    assert res.exit_code == 0, res.output
    chans = load_run(str(p))
    assert chans[0].fs_hz == RATE and len(chans[0].segments) > 1000  # split at every hole
    assert "every one logged" in res.output and "contradicts" not in res.output
    # the reader no longer refuses it; the analysis judges segments of 16-32 samples on its own terms
    res = run("analyze", p, "--channel", "imu/gyro/x", "-m", "20")
    assert "contradicts" not in res.output and "Traceback" not in res.output


def test_the_stamp_rate_ignores_holes_but_not_a_wrong_rate():
    kept = _lossy(20_000, 0.40)
    t = np.rint(kept * PERIOD_NS).astype(np.int64)
    assert stamp_rate(t, RATE).rate_hz == pytest.approx(RATE, rel=1e-6)
    assert stamp_rate(t, RATE * 1.25).rate_hz == pytest.approx(RATE, rel=1e-6)  # still near enough to fit


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return base_run(tmp_path_factory.mktemp("rates"))


def _edited(base, tmp_path, edit, name="edited.h5"):
    p = tmp_path / name
    shutil.copyfile(base, p)
    with h5py.File(p, "r+") as f:
        edit(f)
    return p


def _set_rate(hz):
    def edit(f):
        f["devices/gyro"].attrs["rate_hz"] = hz

    return edit


def test_a_rate_the_stamps_contradict_is_corrected_the_same_everywhere(base, tmp_path):
    """A 100 Hz record stating rate_hz 125: before, analyze and export used 125 Hz (sigma_w -10.6 %)."""
    p = _edited(base, tmp_path, _set_rate(125.0))
    with pytest.warns(RateCorrected, match="rate_hz 125 contradicts its timestamps"):
        r = open_run(p)
    with r:
        dev = r.devices["gyro"]
        assert dev.rate_hz == pytest.approx(100.0, rel=1e-4) and dev.stated_rate_hz == 125.0
        assert "using 100 Hz" in dev.rate_note
    with pytest.warns(RateCorrected):
        assert {c.fs_hz for c in load_run(str(p))} == {dev.rate_hz}
    res = run("analyze", p, "--channel", "gyro/gyro/x", "-m", "20", "--json")
    assert res.exit_code == 0, res.output
    assert res.output.count("imustation: warning:") == 1 and "rate_hz 125 contradicts" in res.output
    doc = json.loads(res.output[res.output.index("{") :])
    assert doc["channels"][0]["fs_hz"] == pytest.approx(100.0, rel=1e-4)
    out = tmp_path / "kalibr.yaml"
    res = run("export", p, "--format", "kalibr", "--gyro-only", "-o", out)
    assert res.exit_code == 0, res.output
    rate = next(ln for ln in out.read_text().splitlines() if ln.startswith("update_rate:"))
    assert float(rate.split(":")[1]) == pytest.approx(100.0, rel=1e-4) and "rate_hz 125 contradicts" in res.output


@pytest.mark.parametrize("hz", [200.0, 50.0, 140.0])
def test_a_rate_the_stamps_contradict_grossly_is_refused(base, tmp_path, hz):
    p = _edited(base, tmp_path, _set_rate(hz))
    assert_one_line_error(run("analyze", p), "edited.h5", f"rate_hz {hz:g} contradicts its timestamps", "100 Hz")


def test_a_small_clock_offset_is_believed(base, tmp_path):
    p = _edited(base, tmp_path, _set_rate(100.05))  # 0.05 %: below RATE_FLOOR
    with open_run(p) as r:
        assert r.devices["gyro"].rate_hz == 100.05 and not r.devices["gyro"].rate_note


def _event_lost(value):
    def edit(f):
        ev = f["events"][()]
        i = int(np.flatnonzero(ev["kind"] == b"gap")[0])
        ev["lost"][i] = value
        f["events"][...] = ev

    return edit


def _attr(obj, key, value):
    def edit(f):
        f[obj].attrs[key] = value

    return edit


def _step_back(f):
    t = f["devices/gyro/t"]
    t[10] = t[8]


def _step_back_late(f):
    t = f["devices/gyro/t"]
    t[7000] = t[6990]


@pytest.mark.parametrize(
    "name, edit, needles",
    [
        ("lost=2**62", _event_lost(2**62), ("event", "loss of 4611686018427387904")),
        ("ended-before-started", _attr("/", "ended_utc", "2001-01-01T00:00:00.000+00:00"), ("ended_utc", "before")),
        ("t-steps-back", _step_back, ("gyro/t steps back at row 10",)),
        ("t-steps-back-later", _step_back_late, ("gyro/t steps back at row 7000",)),
        ("offset=1e300", _attr("devices/gyro/gyro", "offset", 1e300), ("'offset' is 1e+300",)),
        ("scale=1e300", _attr("devices/gyro/gyro", "scale", 1e300), ("'scale' is 1e+300",)),
        ("scale=-inf", _attr("devices/gyro/gyro", "scale", -np.inf), ("'scale' is -inf",)),
    ],
)
def test_values_out_of_physical_range_are_refused(base, tmp_path, name, edit, needles):
    p = _edited(base, tmp_path, edit)
    for cmd in (["analyze", p, "-m", "20"], ["export", p, "--format", "kalibr", "--gyro-only", "-o", tmp_path / "k"]):
        assert_one_line_error(run(*cmd), "edited.h5", *needles)
    if name != "t-steps-back-later":  # found on open; a later step back when the record is read
        with pytest.raises(RunFileError):
            with open_run(p) as r:
                r.events()


def _write_two(path, n: int) -> None:
    """Device ``imu`` lost 40 % in holes every 16-32 samples, each logged; device ``ok`` beside it is whole."""
    kept = _lossy(n, 0.40)
    rng = np.random.default_rng(1)
    t = np.rint(kept * 1e9 / RATE).astype(np.int64)
    chans = (ChannelSpec("gyro", "<i2", "rad/s", 1e-4, axes=("x", "y", "z")),)
    specs = [DeviceSpec(name, "adis16448", "ADIS16448", bus, "sim", RATE, {}, chans)
             for name, bus in (("imu", "spi:0"), ("ok", "spi:1"))]  # fmt: skip
    with RunWriter(path, station="t", config_text="", simulated=True, devices=specs, ballast_bytes=0) as w:
        w.append("imu", t, {"gyro": rng.normal(0, 40, (len(kept), 3)).astype(np.int16)})
        w.append("ok", np.rint(np.arange(n) * PERIOD_NS).astype(np.int64),
                 {"gyro": rng.normal(0, 40, (n, 3)).astype(np.int16)})  # fmt: skip
        for j in np.flatnonzero(np.diff(kept) > 1):
            w.event(int(t[j] + PERIOD_NS), "imu", "gap", "not read", lost=int(kept[j + 1] - kept[j] - 1))


def test_a_device_in_pieces_too_short_for_any_estimate_is_skipped_and_the_others_analysed(tmp_path):
    """Before: the damaged device's channel failed ('too short for a fine scale beyond the device filter's
    memory') and was named only on stderr, not as a skipped channel in the output or the JSON."""
    p = tmp_path / "two.h5"
    _write_two(p, 20_000)
    res = run("analyze", p, "--channel", "ok/*", "-m", "20")  # another device of the same file
    assert res.exit_code == 0 and "ok/gyro/z" in res.output, res.output
    res = CliRunner().invoke(cli, ["analyze", str(p), "--channel", "*/gyro/x", "-m", "20"])
    assert res.exit_code == 0, res.output + res.stderr
    assert "ok/gyro/x" in res.stdout
    line = next(x for x in res.stdout.splitlines() if x.startswith("skipped imu/gyro/x"))
    assert "pieces between" in line and "logged holes, the longest 32 samples" in line
    res = CliRunner().invoke(cli, ["analyze", str(p), "--channel", "*/gyro/x", "-m", "20", "--json"])
    doc = json.loads(res.stdout)
    assert [c["id"] for c in doc["channels"]] == ["ok/gyro/x"]
    assert [(f["channel"], f["skipped"]) for f in doc["failures"]] == [("imu/gyro/x", "fragmented")]
    # the damaged device alone: every channel skipped, one line, exit 2 (docs/fleet.md)
    assert_one_line_error(run("analyze", p, "--channel", "imu/gyro/x", "-m", "20"), "skipped imu/gyro/x", "pieces")


HOST_HZ = 400.0


def _write_stamps(path, t: np.ndarray, rate_hz: float, losses=()) -> None:
    """A capture's gyro record of stamps ``t`` (ns) stating ``rate_hz``; ``losses``: (t ns, lost) gap events."""
    rng = np.random.default_rng(3)
    spec = DeviceSpec(
        "imu", "bmi088", "BMI088", "i2c:1", "sim", rate_hz, {},
        (ChannelSpec("gyro", "<i2", "rad/s", 1e-4, axes=("x", "y", "z")),),
    )  # fmt: skip
    with RunWriter(path, station="t", config_text="", simulated=False, devices=[spec], ballast_bytes=0) as w:
        w.append("imu", t, {"gyro": rng.normal(0, 40, (len(t), 3)).astype(np.int16)})
        for at, lost in losses:
            w.event(int(at), "imu", "gap", "not read", lost=int(lost))


def _host_stamps(n: int, true_hz: float, transient_ms: float, settle: int, seed: int = 4) -> np.ndarray:
    """Host-clock-like stamps: the newest sample of a read of 4 dated at the read (0-1 ms late), the others
    a period apart before it, and a start-up transient: the first reads dated up to ``transient_ms`` early
    and catching up over ``settle`` samples (what the timeline's steps giving way make of a late start)."""
    rng = np.random.default_rng(seed)
    i = np.arange(n)
    late = np.repeat(rng.uniform(0, 1e6, n // 4 + 1), 4)[:n]
    lag = -transient_ms * 1e6 * np.exp(-i / settle)
    return np.rint(i * 1e9 / true_hz + late + lag).astype(np.int64)


@pytest.mark.parametrize("n, transient_ms, settle", [(162, 4.0, 400), (24_000, 20.0, 600)])
def test_a_start_up_transient_of_a_host_clock_record_is_not_a_rate(tmp_path, n, transient_ms, settle):
    """Before: the fit over the first 4097 samples followed the transient and 'corrected' a 400 Hz capture
    (test logs: '402.538 Hz fitted over the first 162 samples, 0.63 % off'); the whole span says 400 Hz."""
    t = _host_stamps(n, HOST_HZ, transient_ms, settle)
    first = stamp_rate(t[:4097], HOST_HZ)
    assert abs(first.rate_hz / HOST_HZ - 1) > RATE_FLOOR  # what the old check saw (it corrected this)
    assert abs(first.rate_hz / HOST_HZ - 1) > 5 * first.sigma_hz / first.rate_hz
    p = tmp_path / "host.h5"
    _write_stamps(p, t, HOST_HZ)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RateCorrected)
        with open_run(p) as r:
            assert r.devices["imu"].rate_hz == HOST_HZ and not r.devices["imu"].rate_note


def test_a_chip_off_its_rate_over_a_long_host_clock_record_is_corrected_from_the_whole_span(tmp_path):
    """A chip 0.5 % fast, read on a jittery host, with a hole its event logs: the span (rows + logged loss)
    confirms what the fit over the runs says, beyond the jitter over the span; the fit's rate is used."""
    true = HOST_HZ * 1.005
    t = _host_stamps(48_000, true, 20.0, 600)
    cut = 30_000
    t = np.concatenate([t[:cut], t[cut + 500 :]])  # 500 samples lost, logged
    p = tmp_path / "fast.h5"
    _write_stamps(p, t, HOST_HZ, [(t[cut - 1] + 1e9 / true, 500)])
    with pytest.warns(RateCorrected, match=r"rate_hz 400 contradicts its timestamps over its whole span \(401\.9"):
        r = open_run(p)
    with r:
        assert r.devices["imu"].rate_hz == pytest.approx(true, rel=1e-4)
    # a hole of 50 left unlogged: the span's count is short by 0.1 %, the span still fast; the fit is the rate
    t = np.concatenate([t[:cut], t[cut + 50 :]])
    q = tmp_path / "fast-unlogged.h5"
    _write_stamps(q, t, HOST_HZ, [(t[cut - 1] + 1e9 / true, 500)])
    with pytest.warns(RateCorrected):
        r = open_run(q)
    with r:
        assert r.devices["imu"].rate_hz == pytest.approx(true, rel=1e-4)


def test_the_probe_spans_a_long_record():
    from imustation.runfile.rate import WINDOW_ROWS, WINDOWS, probe_windows

    assert probe_windows(1000) == [(0, 1000)]
    n = 17_280_000  # 12 h at 400 Hz
    w = probe_windows(n)
    assert len(w) == WINDOWS and w[0][0] == 0 and w[-1][1] == n and all(b - a == WINDOW_ROWS for a, b in w)


def test_a_capture_counts_an_outage_with_the_rate_the_reader_will_confirm():
    """Before: an outage after 200 samples was counted with the transient's 402.57 Hz, so the file logged
    0.65 % too many lost samples and the reader then 'confirmed' that rate over the whole span."""
    from imustation.runfile.rate import capture_rate

    assert capture_rate(_host_stamps(200, HOST_HZ, 4.0, 400), HOST_HZ) == HOST_HZ
    fast = _host_stamps(4097, HOST_HZ * 1.005, 1.0, 50)
    assert capture_rate(fast, HOST_HZ) == pytest.approx(HOST_HZ * 1.005, rel=1e-4)


def test_stamps_straddling_the_outage_being_counted_do_not_confirm_a_transient():
    """A reader killed 0.2 s into a capture and started again 2.9 s later (tests/test_reader_processes.py's
    restart, under load): the probe held 81 samples before the outage and 81 after, each run stretched by
    its start-up transient (0.17 %; here 0.4 %). Their span taken whole, with no loss logged, 'confirmed' 399.3 Hz, so
    the outage was counted 2 samples short and the file then read at 399.3 Hz; now the span is judged over
    the longest run (0.2 s: it cannot confirm 0.17 %) and the outage is counted at 400 Hz."""
    from imustation.runfile.rate import capture_rate

    before = _host_stamps(81, HOST_HZ, 1.0, 40)
    after = _host_stamps(81, HOST_HZ, 1.0, 40, seed=5) + before[-1] + 1155 * round(1e9 / HOST_HZ)
    both = np.concatenate([before, after])
    fit = stamp_rate(both, HOST_HZ)
    assert abs(fit.rate_hz / HOST_HZ - 1) > RATE_FLOOR  # the transients alone would be 'corrected'
    assert capture_rate(both, HOST_HZ) == HOST_HZ
    # a chip truly 0.5 % fast is still found across an outage, from a run long enough to show it
    fast = _host_stamps(3000, HOST_HZ * 1.005, 1.0, 50)
    after = fast[:1000] + fast[-1] + 1155 * round(1e9 / HOST_HZ)
    assert capture_rate(np.concatenate([fast, after]), HOST_HZ) == pytest.approx(HOST_HZ * 1.005, rel=1e-3)
