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
