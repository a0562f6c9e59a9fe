"""Crash safety: SIGKILL at random moments, SIGTERM, a second capture on the same
output, reading while recording, a full disk.

Oracle for file contents: simulated captures are deterministic, so a file cut
off at any moment must hold exactly a prefix of the same capture run to the end.
"""

from __future__ import annotations

import errno
import json
import os
import random
import signal
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner
from procs import small_tmpfs, wait_for_file

from imustation.acquisition import capture, load_config
from imustation.cli import cli
from imustation.errors import DiskFullError
from imustation.runfile import RunWriter, open_run

CONFIG = """
[station]
name = "crash"
flush_interval_s = 0.1
seed = 9

[[device]]
name = "gyro"
driver = "bmx055"
bus = "i2c:1"
rate_hz = 400
bandwidth_hz = 47
"""
#: virtual seconds per wall second of the paced subprocess captures
PACE = 200.0
RATE = 400


@pytest.fixture(scope="module")
def config_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("crash") / "crash.toml"
    p.write_text(CONFIG)
    return p


@pytest.fixture(scope="module")
def reference(tmp_path_factory, config_file):
    """The same capture, uninterrupted: (t, gyro, temp) of 2000 virtual seconds."""
    path = tmp_path_factory.mktemp("ref") / "ref.h5"
    capture(load_config(config_file), path, 2000.0, simulate=True)
    with open_run(path) as run:
        return run.read("gyro", "t"), run.read("gyro", "gyro"), run.read("gyro", "temp")


def _start(config_file, out, *extra):
    cmd = [sys.executable, "-m", "imustation", "capture", str(config_file), "--simulate", "-o", str(out)]
    cmd += ["--duration", "1h", "--sim-speed", str(PACE), "--json-status", "--status-interval", "0.2", *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _check_prefix(paths, reference, *, complete: bool) -> int:
    """The files open, every dataset reads, and together they hold a prefix of the reference run.

    ``paths``: one run file, or the parts of a rotated run in order (all but the
    last one complete).
    """
    t_ref, g_ref, temp_ref = reference
    paths = paths if isinstance(paths, list) else [paths]
    got = {"t": [], "gyro": [], "temp": []}
    for i, path in enumerate(paths):
        with open_run(path) as run:
            if i < len(paths) - 1:
                assert run.complete
            elif len(paths) == 1:  # (a kill between two parts leaves the last one complete)
                assert run.complete == complete
            dev = run.devices["gyro"]
            n = dev.n
            # a torn last block (crash inside a flush) leaves some datasets longer: readers use n
            assert n == min(dev.rows.values())
            assert max(dev.rows.values()) - n <= PACE * RATE * 0.1 * 4
            for name in dev.rows:  # every dataset reads in full
                assert len(run.dataset("gyro", name)[()]) == dev.rows[name]
            for name, parts in got.items():
                parts.append(run.read("gyro", name))
                assert len(parts[-1]) == n
            run.events()
    t, g, temp = (np.concatenate(got[k]) for k in ("t", "gyro", "temp"))
    n = len(t)
    assert n <= len(t_ref)
    assert np.array_equal(t, t_ref[:n]) and np.array_equal(g, g_ref[:n]) and np.array_equal(temp, temp_ref[:n])
    return n


def _last_status_on_disk(stdout: str) -> int:
    """Samples the last complete status line reported as flushed to disk."""
    lines = []
    for line in stdout.splitlines():
        try:
            lines.append(json.loads(line))
        except ValueError:
            pass  # the kill may cut the last line
    return lines[-1]["on_disk"]["gyro"] if lines else 0


def _wait_on_disk(proc, target: int) -> int:
    """Read the capture's status lines until one reports at least ``target`` samples on disk: the kill
    moment is a point in the recording, not a wall-clock delay (how far a delay gets depends on how
    fast the machine is). Returns the samples that line reported."""
    for line in proc.stdout:
        try:
            on_disk = json.loads(line)["on_disk"].get("gyro", 0)
        except (ValueError, KeyError):
            continue
        if on_disk >= target:
            return on_disk
    raise AssertionError(f"capture ended before {target} samples were on disk: {proc.stderr.read()}")


def _kill_at_random(config_file, tmp_path, reference, kills: int, seed: int, *extra) -> list[int]:
    rng = random.Random(seed)
    sizes = []
    for i in range(kills):
        out = tmp_path / f"kill{i}.h5"
        proc = _start(config_file, out, *extra)
        # a random point of the first 1.5 wall seconds' recording (0 .. 120,000 samples at PACE)
        target = rng.randint(1, int(1.5 * PACE * RATE))
        try:
            reached = _wait_on_disk(proc, target)
        finally:
            proc.send_signal(signal.SIGKILL)
        stdout, _ = proc.communicate(timeout=30)
        assert proc.returncode == -signal.SIGKILL
        paths = sorted(tmp_path.glob(f"kill{i}.*.h5")) if extra else [out]
        n = _check_prefix(paths, reference, complete=False)
        # everything a status reported as flushed survives the kill
        assert n >= max(reached, _last_status_on_disk(stdout)) >= target
        sizes.append(n)
    return sizes


def test_sigkill_at_random_moments_leaves_readable_prefixes(config_file, tmp_path, reference):
    sizes = _kill_at_random(config_file, tmp_path, reference, kills=3, seed=1)
    assert min(sizes) > 0


@pytest.mark.slow
def test_sigkill_soak(config_file, tmp_path, reference):
    sizes = _kill_at_random(config_file, tmp_path, reference, kills=25, seed=2)
    assert min(sizes) > 0


@pytest.mark.slow
def test_sigkill_with_rotation(config_file, tmp_path, reference):
    _kill_at_random(config_file, tmp_path, reference, 8, 3, "--rotate", "60s")


def test_sigterm_second_capture_and_live_reading(config_file, tmp_path, reference):
    out = tmp_path / "term.h5"
    proc = _start(config_file, out)
    try:
        wait_for_file(out, proc, timeout=30.0, poll=0.02)
        _wait_on_disk(proc, 1)  # recording, some of it on disk
        # a second capture of the same output is refused, even with --overwrite
        res = CliRunner().invoke(cli, ["capture", str(config_file), "--simulate", "-o", str(out), "--overwrite"])
        assert res.exit_code == 2 and "another capture" in res.output
        # the file reads while it is being written (SWMR)
        res = CliRunner().invoke(cli, ["inspect", str(out)])
        assert res.exit_code == 0 and "INCOMPLETE" in res.output, res.output
        n_live = _check_prefix(out, reference, complete=False)
        _wait_on_disk(proc, n_live + 1)  # it recorded on after the live read
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert "stopped by signal SIGTERM" in stderr
    final = json.loads(stdout.splitlines()[-1])
    assert final["state"] == "stopped"
    n = _check_prefix(out, reference, complete=True)
    assert n >= n_live and n == final["devices"]["gyro"]["samples"]
    with open_run(out) as run:
        assert run.events()[-1].detail == "stopped by signal SIGTERM"
    assert not os.path.exists(str(out) + ".lock")


def _check_dropped_are_logged(path, n: int) -> None:
    """Samples dropped at the disk-full stop are logged: written + lost = every
    sample up to the last one produced, exactly (sample k is at (k + 1) periods)."""
    with open_run(path) as run:
        gaps = [e for e in run.events() if e.kind == "gap"]
    assert all(e.detail == "disk full: samples not written" for e in gaps)
    if gaps:
        assert n + sum(e.lost for e in gaps) == max(e.t_ns for e in gaps) // (10**9 // RATE)


def test_reserve_refusal_finishes_the_file(config_file, tmp_path, reference, monkeypatch):
    """Free space falls under the reserve: the capture stops with a complete file."""
    calls = {"n": 0}

    def free_bytes(self):
        calls["n"] += 1
        return 10**12 if calls["n"] < 4 else 1000

    monkeypatch.setattr(RunWriter, "free_bytes", free_bytes)
    # every block is flushed as it comes: the flush count no longer depends on machine speed
    monkeypatch.setattr(RunWriter, "flush_due", lambda self: True)
    out = tmp_path / "full.h5"
    with pytest.raises(DiskFullError, match="disk full"):
        capture(load_config(config_file), out, 1000.0, simulate=True)
    n = _check_prefix(out, reference, complete=True)
    assert n > 0
    _check_dropped_are_logged(out, n)
    with open_run(out) as run:
        assert run.attrs["stopped"] == "disk full"
        assert run.events()[-1].detail == "capture stopped: disk full"


@pytest.mark.parametrize("room", ["past the end", "ballast file"])
def test_enospc_while_writing_is_rescued_by_the_ballast(config_file, tmp_path, reference, monkeypatch, room):
    """A write fails with ENOSPC all the same: the room kept to finish the file (allocated past
    its end, or a ballast file where the filesystem has no fallocate) lets HDF5 finish."""
    if room == "ballast file":
        monkeypatch.setattr("imustation.runfile.writer.reserve_tail", lambda fd, nbytes: False)
    real = RunWriter._write_pending
    calls = {"n": 0}

    def failing(self):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(self)

    monkeypatch.setattr(RunWriter, "_write_pending", failing)
    out = tmp_path / "enospc.h5"
    res = CliRunner().invoke(
        cli, ["capture", str(config_file), "--simulate", "-o", str(out), "--duration", "1000s", "--quiet"]
    )
    assert res.exit_code == 2 and "disk full" in res.output and res.output.count("\n") == 1
    # the ballast file made room: HDF5 finished the flush, the file was closed cleanly
    n = _check_prefix(out, reference, complete=True)
    assert n > 0
    _check_dropped_are_logged(out, n)
    assert not os.path.exists(str(out) + ".lock") and not os.path.exists(str(out) + ".ballast")


def test_bad_config_touches_nothing(tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[[device]]\nname = "g"\ndriver = "bmx055"\nbus = "i2c:1"\nrate_hz = 333\n')
    out = tmp_path / "never.h5"
    res = CliRunner().invoke(cli, ["capture", str(cfg), "--simulate", "-o", str(out)])
    assert res.exit_code == 2 and "rate_hz" in res.output and res.output.count("\n") == 1
    assert list(tmp_path.iterdir()) == [cfg]


@pytest.fixture
def small_filesystem(tmp_path):
    """A 2 MiB tmpfs (needs root and a kernel that lets us mount; skipped otherwise)."""
    yield from small_tmpfs(tmp_path, "2m")


@pytest.mark.parametrize("reserve", [0, 2**18])
def test_a_real_full_filesystem(small_filesystem, config_file, reference, reserve):
    """With a reserve the capture stops before the disk is full; without one the room the
    next flush needs is not there to allocate past the file's end, so it is refused before
    anything is written and the file is finished in the room kept for it.
    (Run in a subprocess: HDF5 crashes at exit if it could not close a file.)"""
    out = small_filesystem / "run.h5"
    script = (
        "import sys\n"
        "from imustation.acquisition import capture, load_config\n"
        "from imustation.errors import DiskFullError\n"
        "from imustation.runfile import RunWriter\n"
        # a flush every 20,000 rows (50 s of data): how much reaches the disk depends on the
        # data, not on how fast the machine simulates it (and per-block flushes would fill
        # the small disk with HDF5 metadata instead)
        "RunWriter.flush_due = lambda self: self._pending_rows >= 20_000\n"
        "try:\n"
        f"    cfg = load_config({str(config_file)!r})\n"
        f"    capture(cfg, {str(out)!r}, 2000.0, simulate=True, min_free_bytes={reserve}, ballast_bytes=2**18)\n"
        "except DiskFullError as exc:\n"
        "    print(exc)\n"
        "    sys.exit(3)\n"
    )
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert res.returncode == 3, res.stderr
    assert "disk full" in res.stdout
    n = _check_prefix(out, reference, complete=True)
    assert not os.path.exists(str(out) + ".ballast")
    _check_dropped_are_logged(out, n)
    assert n > 50_000  # several flushes made it to the disk
