"""Shared pieces of the monitor tests: a paced simulated capture and a monitor subprocess."""

from __future__ import annotations

import json
import re
import select
import subprocess
import sys
import time
import urllib.error
import urllib.request

from procs import wait_for_file  # noqa: F401 - the monitor tests import it from here

CONFIG = """
[station]
name = "mon"
flush_interval_s = 0.2
seed = 5

[[device]]
name = "gyro"
driver = "bmx055"
bus = "i2c:1"
rate_hz = 400
bandwidth_hz = 47

[device.sim]
faults = [{kind = "disconnect", at_s = 60, duration_s = 3}]

[[thermometer]]
name = "ambient1"
driver = "mcp9804"
bus = "i2c:2"
address = 0x18
rate_hz = 1
"""
#: virtual seconds per wall second of the paced captures
PACE = 100.0
URL_RE = re.compile(r"imustation monitor: watching .* at (http://\S+) \(pid (\d+)\)")


def start_capture(config, out, duration: str, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "imustation", "capture", str(config), "--simulate", "-o", str(out)]
    cmd += ["--duration", duration, "--sim-speed", str(PACE), "--quiet", *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def read_url(stream, proc, timeout: float = 60.0) -> tuple[str, int, list[str]]:
    """Read lines from ``stream`` until the monitor's URL line: (url, pid, lines read)."""
    lines: list[str] = []
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        ready, _, _ = select.select([stream], [], [], 0.2)
        if ready:
            line = stream.readline()
            if line:
                lines.append(line)
                m = URL_RE.search(line)
                if m:
                    return m.group(1), int(m.group(2)), lines
                continue
        if proc.poll() is not None:
            break
    raise AssertionError(f"no monitor URL; output so far: {lines!r}")


def start_monitor(path, *extra: str) -> tuple[subprocess.Popen, str]:
    cmd = [sys.executable, "-m", "imustation", "monitor", str(path), "--port", "0", "--poll", "0.5"]
    cmd += ["--allan-every", "1", "--model-after", "5m", *extra]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    url, _, _ = read_url(proc.stdout, proc)
    return proc, url


def get(url: str, *, headers: dict | None = None, method: str = "GET") -> tuple[int, dict, bytes]:
    req = urllib.request.Request(url, headers=headers or {}, method=method)
    try:
        with urllib.request.urlopen(req, timeout=20) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers), exc.read()


def get_json(url: str) -> dict:
    status, _, body = get(url)
    assert status == 200, (url, status, body[:200])
    return json.loads(body)


def wait_json(url: str, ok, timeout: float = 90.0, what: str = "") -> dict:
    """GET ``url`` until ``ok(doc)`` holds; the last document."""
    t_end = time.monotonic() + timeout
    doc: dict = {}
    while time.monotonic() < t_end:
        doc = get_json(url)
        try:
            if ok(doc):
                return doc
        except (KeyError, IndexError, TypeError):
            pass
        time.sleep(0.3)
    raise AssertionError(f"{what or url}: condition not reached; last document {json.dumps(doc)[:600]}")


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
