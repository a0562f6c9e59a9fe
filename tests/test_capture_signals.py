"""A capture stopped by SIGINT/SIGTERM at any moment exits cleanly: a complete file, never a traceback,
never a swallowed stop (issue 33, "Signals").

Each case runs the real entry point (``imustation.__main__``) in a subprocess and
sends the signal to itself at one chosen point through a hook (no timing): before
the command line's modules are imported, while ``imustation.cli.capture`` itself
is imported, while the reader processes open their devices, during the recording,
and while the finished file is being closed. A one-hour capture that is not
stopped would run into the test's time limit.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from imustation.configs import config_path
from imustation.runfile import open_run

#: wall s a stopped capture may take, spawning its reader processes on a loaded machine included
LIMIT_S = 240

SCRIPT = """
import importlib.abc, os, signal, sys
from imustation import stopsignals

stage, sig = sys.argv[1], getattr(signal, sys.argv[2])
sys.argv = ["imustation", "capture", *sys.argv[3:]]
kill = lambda: os.kill(os.getpid(), sig)

if stage == "entry":  # the entry point has just set its handlers; nothing else is imported
    stopsignals.record()
    kill()
elif stage == "import":  # while the capture command's module is being imported

    class Trigger(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path, target=None):
            if name == "imustation.cli.capture":
                sys.meta_path.remove(self)
                kill()
            return None

    sys.meta_path.insert(0, Trigger())
elif stage == "opening":  # while the reader processes open their devices
    from imustation.acquisition import workers

    real = workers.WorkerPool.opened
    def opened(self):
        kill()
        return real(self)
    workers.WorkerPool.opened = opened
elif stage == "recording":  # at the writer's first turn
    from imustation.acquisition import recorder

    real = recorder.Recorder.tick
    def tick(self, t_ns):
        if not getattr(self, "_killed", False):
            self._killed = True
            kill()
        return real(self, t_ns)
    recorder.Recorder.tick = tick
elif stage == "finishing":  # as the complete file is closed
    from imustation.acquisition import recorder

    real = recorder.Recorder.finish
    def finish(self, attrs=None):
        kill()
        return real(self, attrs)
    recorder.Recorder.finish = finish

from imustation.__main__ import main
main()
"""

CASES = [
    ("entry", "SIGINT", "1h"),
    ("import", "SIGINT", "1h"),
    ("import", "SIGTERM", "1h"),
    ("opening", "SIGTERM", "1h"),
    ("recording", "SIGINT", "1h"),
    ("finishing", "SIGINT", "1s"),
]


@pytest.mark.parametrize(("stage", "sig", "duration"), CASES)
def test_a_stop_signal_at_any_moment_finishes_the_file(tmp_path, stage, sig, duration):
    out = tmp_path / "run.h5"
    args = [str(config_path("demo.toml")), "--simulate", "--real-time", "--duration", duration, "-o", str(out)]
    res = subprocess.run(
        [sys.executable, "-c", SCRIPT, stage, sig, *args, "--quiet"],
        capture_output=True,
        text=True,
        timeout=LIMIT_S,
        cwd=tmp_path,
    )
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr and "KeyboardInterrupt" not in res.stderr, res.stderr
    stopped = f"stopped by signal {sig}"
    with open_run(out) as run:
        assert run.complete
        notes = [e.detail for e in run.events() if e.kind == "note"]
        if stage == "finishing":  # the recording was over: the file is finished as it was
            assert stopped not in notes and run.devices["bmx055"].n > 0
        else:
            assert stopped in notes and stopped in res.stdout
            assert run.devices["bmx055"].n < 400 * 60
    assert not os.path.exists(f"{out}.lock")
