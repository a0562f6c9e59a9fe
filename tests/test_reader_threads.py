"""Run files opened from several threads at once (an in-process dask cluster, the monitor).

The HDF5 library h5py ships is not thread-safe; h5py serialises its own calls
with one lock. The SWMR reader makes one HDF5 call of its own through ctypes
(imustation/runfile/swmr.py): made without that lock, it ran inside HDF5 beside
another thread's call and crashed the process (a segmentation fault in CI's
fleet tests).
"""

from __future__ import annotations

import subprocess
import sys
import threading

import pytest
from h5py._objects import phil

from imustation.acquisition import capture, load_config
from imustation.configs import config_path
from imustation.runfile import swmr


@pytest.fixture(scope="module")
def run_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("threads") / "run.h5"
    capture(load_config(config_path("demo.toml")), path, 5.0, simulate=True)
    return path


def test_the_ctypes_call_into_hdf5_holds_h5pys_lock(run_file, monkeypatch):
    """While the reader's own HDF5 call runs, no other thread can enter HDF5 through h5py."""
    real = swmr._set_read_attempts()
    other_thread_got_lock = []

    def try_lock():
        got = phil.acquire(blocking=False)
        if got:
            phil.release()  # by the thread that holds it
        other_thread_got_lock.append(got)

    def probe(*args):
        t = threading.Thread(target=try_lock)
        t.start()
        t.join()
        return real(*args)

    monkeypatch.setattr(swmr, "_set_read_attempts", lambda: probe)
    swmr.open_swmr_reader(run_file).close()
    assert other_thread_got_lock == [False]


STRESS = """
import sys, threading
from imustation.runfile import open_run
errors = []
def work():
    try:
        for _ in range(150):
            open_run(sys.argv[1]).h5.close()
    except Exception as exc:
        errors.append(exc)
threads = [threading.Thread(target=work) for _ in range(4)]
for t in threads:
    t.start()
for t in threads:
    t.join()
print("errors", errors)
"""


def test_four_threads_open_one_run_file_600_times(run_file):
    """Before the lock, this crashed the interpreter in 4 of 6 tries (exit -11)."""
    res = subprocess.run([sys.executable, "-c", STRESS, str(run_file)], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, (res.returncode, res.stderr[-3000:])
    assert res.stdout.strip() == "errors []"
