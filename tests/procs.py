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
