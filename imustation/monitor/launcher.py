"""Start ``imustation monitor`` as its own process beside a capture (``capture --monitor``).

The capture never depends on the monitor: the child is started once the run
file exists, with its own interpreter, no stdin, and its output on the
capture's stderr (stdout stays the capture's, e.g. ``--json-status``). If it
cannot be started or dies, the capture only prints one note and goes on. At the
end of the capture the child is asked to stop (SIGTERM).
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable


class MonitorProcess:
    """A monitor child process, started by :meth:`poll` once the run file exists.

    host, port : passed to ``imustation monitor``; extra : further options.
    note : called with a one-line message (start failed, child exited).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8765,
        extra: tuple[str, ...] = (),
        note: Callable[[str], None] | None = None,
    ):
        self.host = host
        self.port = int(port)
        self.extra = tuple(extra)
        self.note = note or (lambda msg: print(msg, file=sys.stderr))
        self.proc: subprocess.Popen | None = None
        self.failed = False
        self._reported_exit = False

    def command(self, path: str) -> list[str]:
        return [sys.executable, "-m", "imustation", "monitor", path, "--host", self.host, "--port", str(self.port)]

    def poll(self, path: str | os.PathLike | None) -> None:
        """Start the child when ``path`` exists (once); report once if it has exited. Never raises."""
        try:
            if self.proc is None and not self.failed and path is not None and os.path.exists(path):
                self.proc = subprocess.Popen(
                    [*self.command(os.fspath(path)), *self.extra],
                    stdin=subprocess.DEVNULL,
                    stdout=sys.stderr.fileno(),
                    stderr=sys.stderr.fileno(),
                    close_fds=True,
                )
                self.note(f"monitor starting (pid {self.proc.pid}) on {os.fspath(path)}; its address follows")
            elif self.proc is not None and not self._reported_exit and self.proc.poll() is not None:
                self._reported_exit = True
                self.note(f"monitor exited (status {self.proc.returncode}); the capture goes on")
        except (OSError, ValueError) as exc:
            self.failed = True
            self.note(f"monitor not started ({exc}); the capture goes on")

    def stop(self, timeout_s: float = 3.0) -> None:
        """Ask the child to stop (SIGTERM), kill it after ``timeout_s``. Never raises."""
        proc = self.proc
        if proc is None or proc.poll() is not None:
            return
        try:
            proc.terminate()
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout_s)
        except OSError:
            pass
