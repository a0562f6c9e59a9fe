"""Waiting on capture subprocesses (shared by the crash-safety and monitor tests)."""

from __future__ import annotations

import os
import subprocess
import time


def wait_for_file(path, proc: subprocess.Popen, timeout: float = 60.0, poll: float = 0.05) -> None:
    """Wait until the capture ``proc`` has created ``path``; fail if it exits first or takes ``timeout`` s."""
    t_end = time.monotonic() + timeout
    while not os.path.exists(path):
        if proc.poll() is not None:
            raise AssertionError(f"capture exited early: {proc.stderr.read()}")
        if time.monotonic() > t_end:
            raise AssertionError("capture did not create its file")
        time.sleep(poll)


def wait_for_rows(path, proc: subprocess.Popen, devices, timeout: float = 60.0, poll: float = 0.1) -> None:
    """Wait until the capture ``proc``'s file holds flushed samples of every one of ``devices`` (read live,
    SWMR): an explicit trigger instead of a sleep that assumes how fast the machine is. Fails if the
    capture exits first or takes ``timeout`` s (a hang guard)."""
    from imustation.runfile import open_run

    t_end = time.monotonic() + timeout
    while True:
        if proc.poll() is not None:
            raise AssertionError(f"capture exited early: {proc.stderr.read() if proc.stderr else ''}")
        try:
            with open_run(path) as run:
                if all(run.rows(d) > 0 for d in devices):
                    return
        except Exception:  # noqa: BLE001 - a file still being created reads as not yet there
            pass
        if time.monotonic() > t_end:
            raise AssertionError(f"capture wrote no samples of {', '.join(devices)} in {timeout:g} s")
        time.sleep(poll)


def small_tmpfs(tmp_path, size: str):
    """Mount a tmpfs of ``size`` (mount's syntax, e.g. ``2m``) under ``tmp_path/small``; a
    generator for fixtures: yields the folder, unmounts after. Skips without root or mount."""
    import os
    import subprocess

    import pytest

    mnt = tmp_path / "small"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)], capture_output=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.decode().strip()}")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=False)
