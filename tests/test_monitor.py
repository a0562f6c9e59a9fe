"""``imustation monitor``: the page and its JSON endpoints beside a running simulated capture,
read-only and safe defaults, and a capture that survives its monitor being killed.

Captures run as paced subprocesses (PACE virtual s per wall s) so the monitor sees the file
grow; simulated captures are deterministic, so a capture whose monitor was SIGKILLed must
give exactly the file of the same capture run alone.
"""

from __future__ import annotations

import http.client
import math
import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.parse

import numpy as np
import pytest
from click.testing import CliRunner
from monitor_helpers import (
    CONFIG,
    get,
    get_json,
    read_url,
    start_capture,
    start_monitor,
    stop,
    wait_for_file,
    wait_json,
)

from imustation.acquisition import capture, load_config
from imustation.cli import cli
from imustation.monitor.live_allan import GyroBuffer
from imustation.monitor.server import STATIC_FILES, is_loopback
from imustation.monitor.watcher import decimate, warmup_summary
from imustation.runfile import open_run

SHORT = "30m"  # the kill tests' capture: 18 s wall at PACE


@pytest.fixture(scope="module")
def config_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("monitor") / "mon.toml"
    p.write_text(CONFIG)
    return p


@pytest.fixture(scope="module")
def live(tmp_path_factory, config_file):
    """A 40-minute paced capture (24 s wall) and a monitor watching it: (base URL, capture, path)."""
    out = tmp_path_factory.mktemp("live") / "live.h5"
    cap = start_capture(config_file, out, "40m")
    mon = None
    try:
        wait_for_file(out, cap)
        mon, url = start_monitor(out)
        yield url, cap, out
    finally:
        if mon is not None:
            stop(mon)
        stop(cap)


@pytest.fixture(scope="module")
def reference(tmp_path_factory, config_file):
    """The SHORT capture run alone, in-process: (t, gyro, events) of the gyro."""
    path = tmp_path_factory.mktemp("ref") / "ref.h5"
    capture(load_config(config_file), path, 1800.0, simulate=True)
    with open_run(path) as run:
        return run.read("gyro", "t"), run.read("gyro", "gyro"), [(e.t_ns, e.kind, e.lost) for e in run.events()]


def _same_as_reference(path, reference) -> None:
    t_ref, g_ref, ev_ref = reference
    with open_run(path) as run:
        assert run.complete, "the capture did not finish its file"
        np.testing.assert_array_equal(run.read("gyro", "t"), t_ref)
        np.testing.assert_array_equal(run.read("gyro", "gyro"), g_ref)
        events = [(e.t_ns, e.kind, e.lost) for e in run.events() if e.kind != "note"]
        assert events == [e for e in ev_ref if e[1] != "note"]


# -- the endpoints beside a running capture -----------------------------------------------


def test_status_follows_the_capture(live):
    url, cap, out = live
    first = wait_json(url + "api/status", lambda d: d["devices"]["gyro"]["samples"] > 0, what="first samples")
    assert first["format"] == "imustation-monitor-status"
    assert first["state"] == "recording" and first["simulated"] is True
    assert first["file"] == os.path.basename(out) and first["file_bytes"] > 0
    later = wait_json(
        url + "api/status",
        lambda d: d["devices"]["gyro"]["samples"] > first["devices"]["gyro"]["samples"] and d["elapsed_s"] > 120,
        what="growth past the fault at 60 s",
    )
    g = later["devices"]["gyro"]
    assert g["rate_cfg_hz"] == 400.0
    assert g["rate_recent_hz"] == pytest.approx(400.0, rel=0.02)  # station time, over the last 10 s
    assert g["state"] == "ok" and g["stalled_s"] < 10
    assert g["gaps"] >= 1 and g["lost"] > 0 and g["faults"] >= 1  # the cable pulled at 60 s
    assert g["events"] >= g["gaps"] + g["faults"]
    kinds = {e["kind"] for e in later["events"] if e["source"] == "gyro"}
    assert {"fault", "gap"} <= kinds
    assert 20.0 < g["temp_c"] < 45.0
    th = later["thermometers"]["ambient1"]
    assert th["readings"] > 60 and 10.0 < th["celsius"] < 40.0


def test_temperatures_series_and_warmup(live):
    url, _, _ = live
    doc = wait_json(
        url + "api/temperatures?max_points=50",
        lambda d: d["series"]["ambient1"]["readings"] > 120 and d["series"]["gyro"]["readings"] > 120,
        what="temperature readings",
    )
    for name, kind in (("gyro", "device"), ("ambient1", "thermometer")):
        s = doc["series"][name]
        assert s["kind"] == kind
        assert 2 <= len(s["t_s"]) == len(s["celsius"]) <= 50  # decimated to max_points
        assert np.all(np.diff(s["t_s"]) > 0)
        assert set(doc["warmup"][name]) == {"warmup_end_s", "warming", "slope_c_per_h", "steady"}
        assert doc["warmup"][name]["slope_c_per_h"] is not None
    status, _, _ = get(url + "api/temperatures?max_points=abc")
    assert status == 400


def test_allan_grows_and_gets_the_model_overlay(live):
    url, _, _ = live
    doc = wait_json(url + "api/allan", lambda d: len(d["devices"]["gyro"]["tau"]) > 5, what="first Allan curve")
    g = doc["devices"]["gyro"]
    assert set(g["axes"]) == {"x", "y", "z"} and g["units"] == "rad/s"
    tau = np.array(g["tau"])
    assert tau[0] == pytest.approx(1 / 400) and np.all(np.diff(tau) > 0)
    for ax in g["axes"].values():
        adev = np.array(ax["adev"], dtype=float)
        assert len(adev) == len(tau) and np.all(adev > 0)
        assert 1e-4 < adev[0] < 1e-1  # white rate noise of a BMX055 at 400 Hz, rad/s
    n0 = g["samples"]
    doc = wait_json(
        url + "api/allan",
        lambda d: d["devices"]["gyro"]["model"] is not None and d["devices"]["gyro"]["samples"] > n0,
        timeout=120,
        what="model overlay after 5 min of data",
    )
    g = doc["devices"]["gyro"]
    assert g["duration_s"] >= 300.0 and g["segments"] >= 2  # split at the logged gap
    model = g["model"]
    assert model["model"] == "wn+gm"
    for axis, m in model["axes"].items():
        assert "error" not in m, (axis, m)
        assert len(m["adev"]) == len(g["tau"])
        assert 1e-6 < m["sigma_w"] < 1e-2  # rad/s/sqrt(Hz)
        # the model and the estimate agree at the shortest tau (white noise dominates)
        assert m["adev"][0] == pytest.approx(g["axes"][axis]["adev"][0], rel=0.2)


# -- read-only, local, no stray files ----------------------------------------------------


def test_page_and_static_files_ship_in_the_package(live):
    url, _, _ = live
    status, headers, body = get(url)
    page = body.decode()
    assert status == 200 and headers["Content-Type"].startswith("text/html")
    assert "default-src 'self'" in headers["Content-Security-Policy"]
    for name in ("uPlot.iife.min.js", "uPlot.min.css", "monitor.js", "monitor.css"):
        assert f"static/{name}" in page
    assert "http://" not in page and "https://" not in page and "//cdn" not in page
    for name, ctype in STATIC_FILES.items():
        status, headers, body = get(url + "static/" + name)
        assert status == 200 and headers["Content-Type"] == ctype and len(body) > 100, name
    assert b"MIT" in get(url + "static/uPlot.LICENSE")[2]
    js = get(url + "static/monitor.js")[2].decode()
    assert "fetch(" in js and "http://" not in js and "https://" not in js


def _raw_get(url: str, path: str, host: str | None = None) -> int:
    u = urllib.parse.urlsplit(url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
    try:
        conn.putrequest("GET", path, skip_host=host is not None)
        if host is not None:
            conn.putheader("Host", host)
        conn.endheaders()
        return conn.getresponse().status
    finally:
        conn.close()


def test_nothing_but_the_whitelist_is_served_and_nothing_changes(live):
    url, _, out = live
    for path in (
        "/static/../watcher.py",
        "/static/..%2fwatcher.py",
        "/static/%2e%2e/%2e%2e/errors.py",
        "/static/index.html/../../server.py",
        "/static/__init__.py",
        "/static/",
        "/" + str(out).lstrip("/"),
        "/" + os.path.basename(out),
        "/etc/passwd",
        "/api/file",
        "/api/status/../../x",
    ):
        assert _raw_get(url, path) in (400, 404), path
    size = os.path.getsize(out)
    for method in ("POST", "PUT", "DELETE", "PATCH"):
        for path in ("", "api/status", "api/allan", "static/monitor.js"):
            status, _, _ = get(url + path, method=method, headers={"Content-Length": "0"})
            assert status == 405, (method, path, status)
    assert os.path.getsize(out) >= size  # still growing, never rewritten by a request
    # DNS rebinding: a page of another site that resolves to 127.0.0.1 is refused
    assert _raw_get(url, "/api/status", host="evil.example:80") == 403
    assert _raw_get(url, "/api/status", host="localhost") == 200


def test_token_required_off_localhost(sim_run):
    path, _ = sim_run
    cmd = [sys.executable, "-m", "imustation", "monitor", str(path), "--host", "0.0.0.0", "--port", "0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url, _, lines = read_url(proc.stdout, proc)
        lines.append(proc.stdout.readline())
        assert "token" in "".join(lines) and "?token=" in url
        token = urllib.parse.parse_qs(urllib.parse.urlsplit(url).query)["token"][0]
        assert len(token) >= 24
        port = urllib.parse.urlsplit(url).port
        base = f"http://127.0.0.1:{port}/"
        for p in ("", "api/status", "api/allan", "api/temperatures", "static/monitor.js"):
            assert get(base + p)[0] == 403, p
            assert get(base + p + "?token=wrong")[0] == 403, p
        assert get(base + "api/status?token=" + token)[0] == 200
        assert get(base + "api/status", headers={"X-Imustation-Token": token})[0] == 200
        status, headers, _ = get(base + "?token=" + token)
        assert status == 200 and "imustation_token=" in headers.get("Set-Cookie", "")
        assert "httponly" in headers["Set-Cookie"].lower()
        assert get(base + "static/uPlot.iife.min.js", headers={"Cookie": f"imustation_token={token}"})[0] == 200
    finally:
        stop(proc)


def test_loopback_needs_no_token():
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert is_loopback("127.0.0.2") and not is_loopback("0.0.0.0") and not is_loopback("192.168.1.2")


def test_bad_input_is_one_line(tmp_path, sim_run):
    runner = CliRunner()
    res = runner.invoke(cli, ["monitor", str(tmp_path / "missing.h5")])
    assert res.exit_code == 2 and "no such file" in res.output and len(res.output.strip().splitlines()) == 1
    bad = tmp_path / "notes.h5"
    bad.write_text("not hdf5")
    res = runner.invoke(cli, ["monitor", str(bad)])
    assert res.exit_code == 2 and "notes.h5" in res.output
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        res = runner.invoke(cli, ["monitor", str(sim_run[0]), "--port", str(port)])
    assert res.exit_code == 2 and "in use" in res.output and len(res.output.strip().splitlines()) == 1
    res = runner.invoke(cli, ["monitor", str(sim_run[0]), "--port", "70000"])
    assert res.exit_code == 2


# -- the capture never depends on the monitor --------------------------------------------


def test_sigkill_of_the_monitor_leaves_the_capture_untouched(tmp_path, config_file, reference):
    out = tmp_path / "kill.h5"
    cap = start_capture(config_file, out, SHORT)
    mon = None
    try:
        wait_for_file(out, cap)
        mon, url = start_monitor(out)
        wait_json(url + "api/status", lambda d: d["devices"]["gyro"]["samples"] > 0, what="monitor reading")
        assert cap.poll() is None, "the capture must still be running when the monitor is killed"
        os.kill(mon.pid, signal.SIGKILL)
        mon.wait(10)
        _, err = cap.communicate(timeout=120)
        assert cap.returncode == 0, err
    finally:
        if mon is not None:
            stop(mon)
        stop(cap)
    _same_as_reference(out, reference)


def test_capture_with_monitor_goes_on_when_the_monitor_dies(tmp_path, config_file, reference):
    out = tmp_path / "withmon.h5"
    cap = start_capture(config_file, out, SHORT, "--monitor", "--monitor-port", "0")
    try:
        url, pid, _ = read_url(cap.stderr, cap)
        doc = get_json(url + "api/status")
        assert doc["file"] == "withmon.h5"
        assert pid != cap.pid
        assert cap.poll() is None
        os.kill(pid, signal.SIGKILL)
        _, err = cap.communicate(timeout=120)
        assert cap.returncode == 0, err
        assert "monitor exited" in err and "the capture goes on" in err
    finally:
        stop(cap)
    _same_as_reference(out, reference)


def test_capture_stops_its_monitor_at_the_end(tmp_path, config_file):
    out = tmp_path / "end.h5"
    cap = start_capture(config_file, out, "10m", "--monitor", "--monitor-port", "0")
    try:
        line = cap.stderr.readline()  # printed by the capture when it starts the monitor
        m = re.search(r"monitor starting \(pid (\d+)\)", line)
        assert m, line
        pid = int(m.group(1))
        _, err = cap.communicate(timeout=120)
        assert cap.returncode == 0, err
        t_end = time.monotonic() + 10
        while time.monotonic() < t_end:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
        else:
            raise AssertionError("the monitor outlived its capture")
    finally:
        stop(cap)
    with open_run(out) as run:
        assert run.complete


# -- pieces ------------------------------------------------------------------------------


def test_gyro_buffer_halves_into_exact_means():
    rng = np.random.default_rng(3)
    raw = rng.integers(-500, 500, size=(10_000, 3)).astype(np.int16)
    buf = GyroBuffer(400.0, 1e-3, raw.dtype, ("x", "y", "z"), max_rows=1000)
    while True:  # feed it as the watcher does: blocks of varying size, multiples of the decimation
        k = buf.wanted(len(raw))
        if k == 0:
            break
        step = min(k, int(rng.integers(1, 700)))
        step -= step % buf.decimation
        if step == 0:
            step = buf.decimation
        buf.append(raw[buf.consumed : buf.consumed + step])
    snap = buf.snapshot()
    d = snap.decimation
    assert d == 16 and snap.fs_hz == 400.0 / d and buf.n <= 1000
    assert snap.raw_rows == buf.n * d == len(raw) - len(raw) % d
    expected = raw[: snap.raw_rows].astype(float).reshape(-1, d, 3).mean(axis=1)
    np.testing.assert_allclose(snap.data, expected, rtol=0, atol=1e-9)


def test_gyro_buffer_keeps_integer_counts_until_full():
    raw = np.arange(300, dtype=np.int16).reshape(100, 3)
    buf = GyroBuffer(100.0, 1.0, raw.dtype, ("x", "y", "z"), max_rows=1000)
    buf.append(raw)
    snap = buf.snapshot()
    assert snap.decimation == 1 and snap.data.dtype == np.int16
    np.testing.assert_array_equal(snap.data, raw)
    buf.breaks = [40]
    assert buf.snapshot().segments == [(0, 40), (40, 100)]


def test_decimate_and_warmup_summary():
    t = np.arange(7200.0)
    c = 25.0 + 3.0 * np.exp(-t / 600.0)  # warms up, settles within the first hour
    td, cd = decimate(t, c, 100)
    assert len(td) <= 100 and td[0] == pytest.approx(t[:72].mean())
    w = warmup_summary(t, c)
    assert w["warming"] is False and 0 < w["warmup_end_s"] < 3600 and w["steady"] is True
    w = warmup_summary(t[:1800], c[:1800])
    assert w["warming"] is True and w["warmup_end_s"] is None and w["steady"] is False
    assert warmup_summary(t[:100], c[:100])["warming"] is None
    assert math.isclose(warmup_summary(t, np.full_like(t, 20.0))["slope_c_per_h"], 0.0, abs_tol=1e-9)


def test_the_allan_section_says_it_waits_for_data():
    """The Allan section was empty, with no word, until the first curve: the page says it waits, before the
    first answer and for a device whose data are still too short for one Allan point."""
    import importlib.resources

    static = importlib.resources.files("imustation.monitor") / "static"
    page = (static / "index.html").read_text(encoding="utf-8")
    assert '<div id="allan-note">waiting for data&hellip;</div>' in page
    js = (static / "monitor.js").read_text(encoding="utf-8")
    assert ': waiting for data (" + (d.samples || 0) + " samples so far)' in js
