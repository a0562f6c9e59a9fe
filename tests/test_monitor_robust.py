"""The monitor on damaged files and hostile requests: it says what is wrong, keeps serving,
stops on SIGTERM, and never writes its token into a log."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import threading
import urllib.parse

from monitor_helpers import get, read_url, start_monitor, stop, wait_json

from imustation.monitor.server import redact
from imustation.monitor.watcher import Monitor

#: wall seconds a stopped monitor may take to exit before the test calls it stuck (far above normal)
EXIT_LIMIT_S = 120


def test_a_file_damaged_while_watched_is_reported_and_sigterm_still_stops(tmp_path, sim_run):
    """The run file becomes unreadable under a running monitor (here: replaced by its first
    100 bytes). The poller used to sleep inside HDF5 forever, holding the GIL, so the page
    froze and SIGTERM was never handled."""
    path = tmp_path / "watched.h5"
    shutil.copyfile(sim_run[0], path)
    proc, url = start_monitor(path, "--poll", "0.2")
    try:
        wait_json(url + "api/status", lambda d: d["devices"]["bmx055"]["samples"] > 0, what="first poll")
        damaged = tmp_path / "damaged.h5"
        damaged.write_bytes(sim_run[0].read_bytes()[:100])
        damaged.replace(path)
        doc = wait_json(url + "api/status", lambda d: "damaged run file" in d.get("monitor_error", ""), what="error")
        assert "watched.h5" in doc["monitor_error"]
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(EXIT_LIMIT_S) == 0
    finally:
        stop(proc)


def test_the_poller_survives_any_error_and_the_page_says_it(sim_run):
    """An unexpected exception (a bug, or a file the checks let through) used to kill the
    polling thread: the page stayed 'starting' with no error. Driven by explicit triggers."""
    mon = Monitor(sim_run[0], poll_s=0.01, allan_every_s=1e9)
    calls: list[str] = []
    failed, recovered = threading.Event(), threading.Event()
    real_poll = mon.poll

    def poll():
        calls.append("poll")
        if len(calls) == 1:
            try:
                raise TypeError("unexpected")
            finally:
                failed.set()
        real_poll()
        recovered.set()

    mon.poll = poll
    th = threading.Thread(target=mon._poll_loop, daemon=True)
    seen: dict = {}
    original_report = mon._report

    def report(exc):
        original_report(exc)
        seen.update(mon.status())

    mon._report = report
    th.start()
    try:
        assert failed.wait(EXIT_LIMIT_S) and recovered.wait(EXIT_LIMIT_S)
    finally:
        mon._stop.set()
        th.join(EXIT_LIMIT_S)
    assert seen["state"] == "error" and seen["monitor_error"] == "TypeError: unexpected"
    status = mon.status()
    assert status["state"] == "complete" and "monitor_error" not in status and not th.is_alive()


def test_redact():
    assert redact("/api/status?token=abc-_12&x=1") == "/api/status?token=REDACTED&x=1"
    assert redact("/x?a=1&token=zz") == "/x?a=1&token=REDACTED"
    assert redact("/x?mytoken=zz") == "/x?mytoken=zz"


def test_the_token_never_reaches_the_log(sim_run):
    """Tornado logs every 4xx request with its URL on stderr: the token it carries is redacted."""
    cmd = [sys.executable, "-m", "imustation", "monitor", str(sim_run[0]), "--host", "0.0.0.0", "--port", "0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url, _, _ = read_url(proc.stdout, proc)
        token = urllib.parse.parse_qs(urllib.parse.urlsplit(url).query)["token"][0]
        base = f"http://127.0.0.1:{urllib.parse.urlsplit(url).port}/"
        assert get(base + "nope?token=" + token)[0] == 404
        assert get(base + "api/temperatures?max_points=x&token=" + token)[0] == 400
        assert get(base + "api/status?token=" + token + "x")[0] == 403
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=EXIT_LIMIT_S)
    finally:
        stop(proc)
    assert token not in err
    assert err.count("token=REDACTED") >= 3, err  # the lines are there, without the token
