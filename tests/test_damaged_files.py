"""Damaged run files: every reader returns with one error line and exit status 2.

A truncated or byte-flipped run file used to make ``inspect``, ``analyze``,
``export`` and ``monitor`` sleep forever inside HDF5 (a SWMR reader re-reads a
block whose checksum fails with doubling sleeps, 100 times by default). The
commands run as subprocesses with a generous time limit: the tests check that
they return, never how fast.
"""

from __future__ import annotations

import re
import subprocess
import sys

import h5py
import pytest

from imustation.acquisition import capture, load_config
from imustation.configs import config_path

#: wall seconds a reader may take before the test calls it hung (far above a normal run)
LIMIT_S = 300

COMMANDS = {
    "inspect": ["inspect"],
    "analyze": ["analyze", "-m", "50"],
    "export": ["export", "--format", "kalibr", "-o", "{out}/noise.yaml"],
    "report": ["report", "-o", "{out}/report"],
    "monitor": ["monitor", "--port", "0"],
}


@pytest.fixture(scope="module")
def good_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("damaged") / "good.h5"
    capture(load_config(config_path("demo.toml")), path, 30.0, simulate=True)
    return path


def run_reader(command: str, path, out_dir) -> subprocess.CompletedProcess:
    args = [a.format(out=out_dir) for a in COMMANDS[command]]
    argv = [sys.executable, "-m", "imustation", args[0], str(path), *args[1:]]
    return subprocess.run(argv, capture_output=True, text=True, timeout=LIMIT_S)


def assert_one_error_line(res: subprocess.CompletedProcess) -> str:
    assert res.returncode == 2, (res.returncode, res.stdout[-2000:], res.stderr[-2000:])
    assert "Traceback" not in res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("imustation: error: ")]
    assert len(errors) == 1, res.stderr
    return errors[0]


def _damage(good_run, tmp_path, name: str, edit) -> str:
    data = bytearray(good_run.read_bytes())
    edit(data)
    p = tmp_path / name
    p.write_bytes(bytes(data))
    return p


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_first_100_bytes(good_run, tmp_path, command):
    """``head -c 100 run.h5 > t.h5``: the case that hung every reader."""
    p = _damage(good_run, tmp_path, "t.h5", lambda d: d.__delitem__(slice(100, None)))
    line = assert_one_error_line(run_reader(command, p, tmp_path))
    assert "t.h5" in line and "damaged run file" in line


@pytest.mark.parametrize("fraction", [0.1, 0.5, 0.98])
def test_truncated(good_run, tmp_path, fraction):
    n = int(good_run.stat().st_size * fraction)
    p = _damage(good_run, tmp_path, "cut.h5", lambda d: d.__delitem__(slice(n, None)))
    assert_one_error_line(run_reader("analyze", p, tmp_path))


def _metadata_offsets(path) -> list[tuple[str, int]]:
    """Offsets of the object headers and chunk indexes (checksummed metadata) in the file."""
    data = path.read_bytes()
    return [(sig, m.start()) for sig in ("OHDR", "EAHD") for m in re.finditer(sig.encode(), data)]


def _check_flips(good_run, tmp_path, offsets) -> None:
    for sig, off in offsets:
        p = _damage(good_run, tmp_path, f"{sig}{off}.h5", lambda d, o=off: d.__setitem__(o + 6, d[o + 6] ^ 0x10))
        res = run_reader("analyze", p, tmp_path)
        if sig == "EAHD" and res.returncode == 0:
            continue  # the index of a channel analyze does not read (temp, counter)
        assert_one_error_line(res)


def test_flipped_metadata(good_run, tmp_path):
    """A flipped bit in the root's object header, the first device dataset's, and the last chunk index."""
    offsets = _metadata_offsets(good_run)
    ohdr = [o for o in offsets if o[0] == "OHDR"]
    _check_flips(good_run, tmp_path, [ohdr[0], ohdr[len(ohdr) // 2], offsets[-1]])


@pytest.mark.slow
def test_flipped_metadata_everywhere(good_run, tmp_path):
    """A flipped bit in every object header and chunk index of the file."""
    offsets = _metadata_offsets(good_run)
    assert len(offsets) >= 8
    _check_flips(good_run, tmp_path, offsets)


def test_complete_file_cut_short_is_refused(good_run, tmp_path):
    """A finished file shorter than its end of allocation lost its tail (SWMR readers do not check)."""
    with h5py.File(good_run, "r") as f:
        assert "ended_utc" in f.attrs
    size = good_run.stat().st_size
    p = _damage(good_run, tmp_path, "tail.h5", lambda d: d.__delitem__(slice(size - 64, None)))
    line = assert_one_error_line(run_reader("inspect", p, tmp_path))
    assert "truncated" in line
