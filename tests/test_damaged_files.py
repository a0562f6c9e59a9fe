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
from concurrent.futures import ThreadPoolExecutor

import h5py
import numpy as np
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
    paths = [
        _damage(good_run, tmp_path, f"{sig}{off}.h5", lambda d, o=off: d.__setitem__(o + 6, d[o + 6] ^ 0x10))
        for sig, off in offsets
    ]
    # two readers side by side: each damaged file is independent (the suite's machine has two CPUs)
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(lambda p: run_reader("analyze", p, tmp_path), paths))
    for (sig, _), res in zip(offsets, results, strict=True):
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


# -- chunk checksums (fletcher32) -----------------------------------------------------------


def _flip_in_chunk(path, dataset: str, index: int = 0, where: float = 0.5) -> int:
    """Flip one bit inside stored chunk ``index`` of ``dataset`` (found through HDF5's chunk index)."""
    with h5py.File(path, "r") as f:
        info = f[dataset].id.get_chunk_info(index)
    offset = info.byte_offset + int(info.size * where)
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x04
    path.write_bytes(bytes(data))
    return offset


def test_every_dataset_of_a_run_file_carries_chunk_checksums(good_run):
    seen = []
    with h5py.File(good_run, "r") as f:
        f.visititems(lambda name, obj: seen.append((name, obj.fletcher32)) if isinstance(obj, h5py.Dataset) else None)
    assert len(seen) >= 4 and all(f32 for _, f32 in seen), seen


@pytest.mark.parametrize("command", ["inspect", "analyze", "export"])
@pytest.mark.parametrize("where", [0.1, 0.5, 0.99])
def test_a_flipped_byte_inside_a_compressed_chunk_is_one_error_line(good_run, tmp_path, command, where):
    p = tmp_path / "flipped.h5"
    p.write_bytes(good_run.read_bytes())
    _flip_in_chunk(p, "devices/bmx055/t", 0, where)
    line = assert_one_error_line(run_reader(command, p, tmp_path))
    assert "flipped.h5" in line and "bmx055/t" in line and "fletcher32 checksum" in line, line


def _device():
    from imustation.runfile import ChannelSpec, DeviceSpec

    gyro = ChannelSpec("gyro", "<i2", "rad/s", 1e-3, 0.0, ("x",))
    return DeviceSpec("g", "test", "m", "bus", "id", 100.0, {}, (gyro,))


def _run_with_events(path, **h5_opts) -> None:
    """A small run file whose event table holds losses (written by the run-file writer)."""
    from imustation.runfile import RunWriter

    dev = _device()
    with RunWriter(path, station="s", config_text="", simulated=True, devices=[dev], fsync=False, ballast_bytes=0) as w:
        w.append("g", np.arange(20_000, dtype=np.int64) * 10_000_000, {"gyro": np.zeros((20_000, 1), np.int16)})
        for k in range(10):
            w.event(k * 10**9, "g", "note", f"note {k}")


def test_a_flipped_byte_in_the_event_table_is_found(tmp_path):
    """The event table is not compressed: without a checksum a flipped byte read as another
    text or another count of lost samples, without a word."""
    p = tmp_path / "events.h5"
    _run_with_events(p)
    with h5py.File(p, "r") as f:
        assert f["events"].fletcher32
    _flip_in_chunk(p, "events", 0, 0.3)
    line = assert_one_error_line(run_reader("inspect", p, tmp_path))
    assert "events.h5" in line and "events" in line and "fletcher32 checksum" in line, line


def test_files_written_without_checksums_still_read(tmp_path, monkeypatch):
    """Run files written before the checksums (format version 1 all the same) read as before;
    a damaged chunk in one is named as a chunk that does not decompress."""
    from imustation.runfile import open_run, writer

    monkeypatch.setitem(writer.H5_OPTS, "fletcher32", False)
    p = tmp_path / "old.h5"
    _run_with_events(p)
    with h5py.File(p, "r") as f:
        assert not f["devices/g/gyro"].fletcher32
    with open_run(p) as run:
        assert run.attrs["format_version"] == 1 and len(run.read("g", "t")) == 20_000
    _flip_in_chunk(p, "devices/g/t", 1)
    line = assert_one_error_line(run_reader("inspect", p, tmp_path))
    assert "old.h5" in line and "g/t" in line and "does not decompress" in line, line


def test_a_flipped_byte_in_a_data_channel_stops_the_analysis(good_run, tmp_path):
    p = tmp_path / "gyro.h5"
    p.write_bytes(good_run.read_bytes())
    _flip_in_chunk(p, "devices/bmx055/gyro", 1)
    line = assert_one_error_line(run_reader("analyze", p, tmp_path))
    assert "bmx055/gyro" in line and "fletcher32 checksum" in line, line


_LIVE_READER = """
import sys, zlib
from imustation.runfile import open_run
with open_run(sys.argv[1], live=True) as run:
    for line in sys.stdin:  # one line per flush of the writer
        run.refresh()
        g, t = run.read("g", "gyro"), run.read("g", "t")
        print(run.rows("g"), zlib.crc32(g.tobytes()), zlib.crc32(t.tobytes()), flush=True)
"""


def test_checksummed_chunks_with_swmr_appends_and_a_live_reader(tmp_path):
    """fletcher32 on resizable chunked datasets in SWMR mode: a live reader (another process)
    sees every flush (partial chunks rewritten, chunk boundaries crossed) with the values written."""
    import zlib

    from imustation.runfile import RunWriter, open_run

    dev = _device()
    rng = np.random.default_rng(3)
    gyro = rng.integers(-3000, 3000, (30_000, 1)).astype(np.int16)
    t = np.arange(30_000, dtype=np.int64) * 10_000_000
    p = tmp_path / "live.h5"
    w = RunWriter(p, station="s", config_text="", simulated=True, devices=[dev], fsync=False, ballast_bytes=0)
    reader = subprocess.Popen(
        [sys.executable, "-c", _LIVE_READER, str(p)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        for a, b in ((0, 5000), (5000, 9000), (9000, 21_000), (21_000, 30_000)):
            w.append("g", t[a:b], {"gyro": gyro[a:b]})
            w.flush()
            reader.stdin.write("next\n")
            reader.stdin.flush()
            seen = reader.stdout.readline().split()
            assert seen == [str(b), str(zlib.crc32(gyro[:b].tobytes())), str(zlib.crc32(t[:b].tobytes()))]
    finally:
        reader.stdin.close()
        assert reader.wait(timeout=LIMIT_S) == 0
    w.close()
    with open_run(p) as run:
        assert run.complete and run.h5["devices/g/gyro"].fletcher32
        assert np.array_equal(run.read("g", "gyro"), gyro)
