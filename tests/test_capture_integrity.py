"""Captures that readers, other captures and small disks cannot break or replace (issue 24)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner
from procs import small_tmpfs

from imustation.acquisition.recorder import OutputLock, run_of_part
from imustation.cli import cli
from imustation.runfile import ChannelSpec, DeviceSpec, RunWriter, open_run

#: wall seconds a helper process may take to start (far above normal)
START_LIMIT_S = 120

READERS = {
    "open_run": "from imustation.runfile import open_run\nf = open_run(sys.argv[1])\n",
    "h5py-swmr": "import h5py\nf = h5py.File(sys.argv[1], 'r', libver='latest', swmr=True)\n",
}


def _writer(path) -> RunWriter:
    dev = DeviceSpec(
        "g", "test", "m", "bus", "id", 100.0, {}, (ChannelSpec("gyro", "<i2", "rad/s", 1e-3, 0.0, ("x", "y", "z")),)
    )
    w = RunWriter(path, station="s", config_text="", simulated=True, devices=[dev], fsync=False, ballast_bytes=0)
    w.append("g", np.arange(1000, dtype=np.int64) * 10_000_000, {"gyro": np.zeros((1000, 3), np.int16)})
    w.flush()
    return w


@pytest.mark.parametrize("reader", sorted(READERS))
def test_a_reader_holding_the_file_does_not_break_the_end_of_a_capture(tmp_path, reader):
    """A SWMR reader holds HDF5's shared lock while the file is open: the writer's reopen to set
    ended_utc failed after 5 s with BlockingIOError (capture exit 1, file INCOMPLETE)."""
    path = tmp_path / "held.h5"
    w = _writer(path)
    code = "import sys\n" + READERS[reader] + "print('open', flush=True)\nsys.stdin.read()\n"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout.readline().strip() == "open"  # the reader has the file open (and stays)
        w.close()
    finally:
        proc.stdin.close()
        proc.wait(START_LIMIT_S)
    with open_run(path) as run:
        assert run.complete and run.devices["g"].n == 1000


def test_part_names_belong_to_their_run():
    assert run_of_part("/d/rot.001.h5") == "/d/rot.h5" and run_of_part("rot.0042.hdf5") == "rot.hdf5"
    assert run_of_part("rot.h5") is None and run_of_part("rot.1.h5") is None


def test_the_whole_name_set_of_a_rotated_capture_is_locked(tmp_path, demo_config):
    """Capture A writes rot.h5 --rotate: B may not write rot.001.h5 (even with --overwrite: it
    replaced A's open part) nor a later part (A died at its next rotation)."""
    out = tmp_path / "rot.h5"
    part1 = tmp_path / "rot.001.h5"
    part1.write_bytes(b"capture A's open part")
    a = OutputLock(str(out))  # what capture A holds while it records
    a.acquire()
    try:
        for name, extra in (("rot.001.h5", ["--overwrite"]), ("rot.002.h5", [])):
            res = CliRunner().invoke(
                cli,
                ["capture", demo_config.path, "--simulate", "--duration", "10s", "-o", str(tmp_path / name), *extra],
            )
            assert res.exit_code == 2, res.output
            lines = [ln for ln in res.output.splitlines() if ln.strip()]
            assert len(lines) == 1 and f"{name} is a part name of" in lines[0] and "another capture" in lines[0], lines
            assert not (tmp_path / (name + ".lock")).exists()
        assert part1.read_bytes() == b"capture A's open part"
        assert not (tmp_path / "rot.002.h5").exists()
    finally:
        a.release()
    # A's lock gone, the part name is free again
    b = OutputLock(str(tmp_path / "rot.002.h5"))
    b.acquire()
    b.release()


@pytest.fixture
def small_filesystem(tmp_path):
    """An 8 MiB tmpfs (needs root and a kernel that lets us mount; skipped otherwise)."""
    yield from small_tmpfs(tmp_path, "8m")


def test_a_disk_smaller_than_reserve_and_ballast_is_refused_at_the_start(small_filesystem, demo_config):
    """A 20 MiB disk used to give a capture that wrote 0 samples: the 16 MiB reserve and the
    4 MiB ballast took it all. Refused before any device or file is touched."""
    out = small_filesystem / "run.h5"
    res = CliRunner().invoke(cli, ["capture", demo_config.path, "--simulate", "--duration", "10s", "-o", str(out)])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "MiB free" in lines[0] and "reserve" in lines[0], lines
    assert list(small_filesystem.iterdir()) == []


KILLED_WRITER = """
import os, signal, sys
import numpy as np
from imustation.runfile import ChannelSpec, DeviceSpec, RunWriter
spec = (ChannelSpec("gyro", "<i2", "rad/s", 1e-3, 0.0, ("x", "y", "z")),)
dev = DeviceSpec("g", "test", "m", "bus", "id", 100.0, {}, spec)
w = RunWriter(sys.argv[1], station="s", config_text="", simulated=True, devices=[dev], ballast_bytes=0)
t = np.arange(3000, dtype=np.int64) * 10_000_000
w.append("g", t[:2000], {"gyro": (np.arange(6000) % 300).reshape(2000, 3).astype(np.int16)})
w.event(int(t[1999]), "g", "gap", "a gap", lost=3)
w.flush()
w.append("g", t[2000:], {"gyro": np.ones((1000, 3), np.int16)})  # read, never flushed
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_recover_makes_a_killed_capture_a_plain_complete_file(tmp_path):
    """After kill -9 the file opened only with a SWMR-aware reader ("already open for write,
    use h5clear"); `imustation recover` makes it a plain, complete file marked recovered."""
    import h5py

    path = tmp_path / "killed.h5"
    res = subprocess.run([sys.executable, "-c", KILLED_WRITER, str(path)], capture_output=True, timeout=START_LIMIT_S)
    assert res.returncode == -9, res.stderr
    with pytest.raises(OSError, match="already open for write"):
        h5py.File(path, "r")
    out = CliRunner().invoke(cli, ["inspect", str(path)])
    assert out.exit_code == 0 and f"imustation recover {path}" in out.output
    with open_run(path) as run:
        before = run.read("g", "gyro")
    assert len(before) == 2000

    out = CliRunner().invoke(cli, ["recover", str(path)])
    assert out.exit_code == 0, out.output
    assert "recovered" in out.output and "before-recover" in out.output
    with h5py.File(path, "r") as f:  # any HDF5 reader, no SWMR
        assert f["devices/g/gyro"].shape == (2000, 3)
    with open_run(path) as run:
        assert run.complete and "cut off by a crash" in run.attrs["recovered"]
        assert np.array_equal(run.read("g", "gyro"), before)
        events = run.events()
        assert [e.kind for e in events] == ["gap", "note"] and events[0].lost == 3
        assert "never written" in events[-1].detail
        assert run.attrs["ended_utc"] > run.attrs["started_utc"]
    assert (tmp_path / "killed.h5.before-recover").exists()
    out = CliRunner().invoke(cli, ["recover", str(path)])
    assert out.exit_code == 0 and "nothing to recover" in out.output
    out = CliRunner().invoke(cli, ["inspect", str(path)])
    assert "recovered" in out.output and "INCOMPLETE" not in out.output


SIGTERM_AT_START = """
import os, signal, sys
import imustation.acquisition as acq
from imustation.cli import main
real = acq.load_config

def load_config(path):  # SIGTERM while the capture starts up (here: as the config is read)
    os.kill(os.getpid(), signal.SIGTERM)
    return real(path)

acq.load_config = load_config
sys.argv = ["imustation", "capture", *sys.argv[1:]]
main()
"""


def test_sigterm_during_start_up_still_leaves_a_finished_file(tmp_path, demo_config):
    """SIGTERM in the first moments (imports, config, opening devices) killed the process with
    nothing left; now the capture creates its file and finishes it at once, with the stop noted."""
    out = tmp_path / "early.h5"
    argv = [demo_config.path, "--simulate", "--duration", "1h", "-o", str(out), "--quiet"]
    res = subprocess.run(
        [sys.executable, "-c", SIGTERM_AT_START, *argv], capture_output=True, text=True, timeout=START_LIMIT_S
    )
    assert res.returncode == 0, res.stderr
    assert "stopped by signal SIGTERM" in res.stdout + res.stderr
    with open_run(out) as run:
        assert run.complete
        assert any(e.kind == "note" and "stopped by signal SIGTERM" in e.detail for e in run.events())
        assert run.devices["bmx055"].n < 400 * 3600
    assert not os.path.exists(str(out) + ".lock")


BUS_CONFIG = """
[station]
name = "full"
seed = 4

[[device]]
name = "gyro"
driver = "bmx055"
bus = "i2c:1"
rate_hz = 400
bandwidth_hz = 47
"""

#: a capture that flushes every 4000 rows, stops before its third flush until told to go on,
#: and exits 3 on DiskFullError: the disk is filled at a moment the test chooses
PAUSED_CAPTURE = """
import sys
from imustation.acquisition import capture, load_config
from imustation.errors import DiskFullError
from imustation.runfile import RunWriter

RunWriter.flush_due = lambda self: self._pending_rows >= 4000
real_flush = RunWriter.flush
flushes = [0]

def flush(self, *, reserve=True):
    if reserve and self._pending_rows:
        flushes[0] += 1
        if flushes[0] == 3:
            print("ready", flush=True)
            sys.stdin.readline()
    return real_flush(self, reserve=reserve)

RunWriter.flush = flush
try:
    capture(load_config(sys.argv[1]), sys.argv[2], 2000.0, simulate=True, min_free_bytes=2**19, ballast_bytes=2**20)
except DiskFullError as exc:
    print(exc, flush=True)
    sys.exit(3)
"""


@pytest.fixture
def disk_for_three(tmp_path):
    yield from small_tmpfs(tmp_path, "16m")


def _fill(path, stop) -> int:
    """Another program: takes every byte the filesystem frees until ``stop`` is set."""
    written = 0
    with open(path, "wb", buffering=0) as f:
        while not stop.is_set():
            try:
                written += f.write(b"\0" * 4096)
            except OSError:
                stop.wait(0.001)
    return written


def test_a_disk_filled_by_another_program_finishes_every_capture(disk_for_three, tmp_path):
    """Three bus-level captures on one disk, which another program fills and keeps full: every
    file ends with ended_utc and stopped = disk full, the dropped samples logged. (Before, a
    capture freed its ballast file to finish and the other program took the room: 2 of 3
    files were left without ended_utc.)"""
    import threading

    cfg = tmp_path / "bus.toml"
    cfg.write_text(BUS_CONFIG)
    outs = [disk_for_three / f"bus{k}.h5" for k in range(3)]
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", PAUSED_CAPTURE, str(cfg), str(out)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        for out in outs
    ]
    stop = threading.Event()
    filler = threading.Thread(target=_fill, args=(disk_for_three / "filler", stop))
    try:
        for p in procs:
            assert p.stdout.readline().strip() == "ready", p.stderr.read()
        filler.start()
        while os.statvfs(disk_for_three).f_bavail > 0:  # the disk is full before anyone goes on
            stop.wait(0.01)
        for p in procs:
            p.stdin.write("go\n")
            p.stdin.flush()
        results = [p.communicate(timeout=START_LIMIT_S) for p in procs]
    finally:
        stop.set()
        if filler.is_alive():
            filler.join()
        for p in procs:
            if p.poll() is None:
                p.kill()
    for p, (stdout, stderr), out in zip(procs, results, outs, strict=True):
        assert p.returncode == 3 and "disk full" in stdout, (p.returncode, stdout, stderr[-2000:])
        assert "Traceback" not in stderr
        with open_run(out) as run:
            assert run.complete and run.attrs["stopped"] == "disk full", out
            n = run.rows("gyro")
            events = run.events()
            gaps = [e for e in events if e.kind == "gap"]
        assert n >= 8000  # two flushes before the disk filled
        assert events[-1].detail == "capture stopped: disk full"
        # the samples dropped at the stop are stated: written + lost = every sample produced
        assert gaps and all(e.detail == "disk full: samples not written" for e in gaps)
        assert n + sum(e.lost for e in gaps) == max(e.t_ns for e in gaps) // (10**9 // 400)
        assert not os.path.exists(str(out) + ".ballast") and not os.path.exists(str(out) + ".lock")
        assert os.stat(out).st_blocks * 512 < os.stat(out).st_size + 2**16  # the room kept is given back


def test_the_room_to_finish_a_file_is_allocated_to_it(tmp_path):
    """While a file is written the room to finish it is allocated past its end (its size, which
    HDF5 reads, unchanged); a clean close gives it back."""
    w = _writer(tmp_path / "room.h5")  # no ballast
    assert os.stat(w.path).st_blocks * 512 < os.stat(w.path).st_size + 2**16
    w.close()
    dev = w.devices["g"]
    w = RunWriter(tmp_path / "room2.h5", station="s", config_text="", simulated=True, devices=[dev], fsync=False)
    if not w._tail:
        w.abort()
        pytest.skip("this filesystem has no fallocate: the room is a ballast file")
    w.append("g", np.arange(1000, dtype=np.int64) * 10_000_000, {"gyro": np.zeros((1000, 3), np.int16)})
    w.flush()
    st = os.stat(w.path)
    assert st.st_blocks * 512 >= st.st_size + w.ballast_bytes
    assert not os.path.exists(w.path + ".ballast")
    w.close()
    st = os.stat(w.path)
    assert st.st_blocks * 512 < st.st_size + 2**16
    with open_run(w.path) as run:
        assert run.complete and run.rows("g") == 1000
