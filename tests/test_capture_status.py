"""capture's live status: a block that fits the terminal, redrawn in place under a pseudo-terminal of a
given size, plain lines elsewhere; the final JSON record up to date (issue 23).

Every redraw is driven by the test (StatusView.show with a status document): nothing depends on how
fast the machine is. The screen is what pyte, a VT100 emulator, makes of the bytes the pty carried.
"""

from __future__ import annotations

import copy
import errno
import fcntl
import io
import json
import os
import pty
import select
import struct
import subprocess
import sys
import termios

import pyte
import pytest
from click.testing import CliRunner

from imustation.cli import cli
from imustation.cli.statusview import StatusView, status_block, status_line, with_rates
from imustation.runfile import open_series

LAB = [("bmx055", 400), ("bmx055_accel", 400), ("mpu9150", 500), ("mpu6500", 1000), ("adis16448", 409.6),
       ("mti", 400), ("fog", 100)]  # fmt: skip


def lab_status(step: int = 0, *, failed: str = "", elapsed: float = 3725.0) -> dict:
    """A status document (imustation.status.capture_status's shape) of the paper's lab, ``step`` s on."""
    devices = {
        name: {
            "state": "failed" if name == failed else "ok",
            "samples": int(rate * (elapsed + step)),
            "rate_hz": rate * 0.999,
            "rate_recent_hz": rate - 0.1 * (step % 3),
            "rate_cfg_hz": rate,
            "gaps": step // 2,
            "lost": 104 * (step // 2),
            "faults": 0,
            "temp_c": 30.5 + 0.1 * step if name != "fog" else None,
        }
        for name, rate in LAB
    }
    return {
        "format": "imustation-status", "version": 1, "state": "recording", "reason": "",
        "elapsed_s": elapsed + step, "duration_s": 43200.0, "remaining_s": max(0.0, 43200.0 - elapsed - step),
        "wall_s": 60.0 + step, "speed": 1.0, "file": "night.h5", "part": None, "file_bytes": 242614272 + step,
        "on_disk": {}, "disk_free_bytes": 48 * 2**30, "devices": devices,
        "thermometers": {f"ambient{k}": {"state": "ok", "readings": 3725, "lost": 0, "faults": 0, "celsius": 23.19}
                         for k in (1, 2, 3)},
    }  # fmt: skip


class Terminal:
    """A pseudo-terminal of ``cols`` x ``lines``: the view writes to its slave side, pyte shows the screen."""

    def __init__(self, cols: int, lines: int):
        self.master, self.slave = pty.openpty()
        self.screen = pyte.Screen(cols, lines)
        self.vt = pyte.ByteStream(self.screen)
        self.resize(cols, lines)
        self.written = 0
        raw = os.fdopen(self.slave, "wb", buffering=0, closefd=False)
        self.stream = io.TextIOWrapper(_Counting(raw, self), encoding="utf-8", write_through=True)

    def resize(self, cols: int, lines: int) -> None:
        fcntl.ioctl(self.slave, termios.TIOCSWINSZ, struct.pack("HHHH", lines, cols, 0, 0))
        self.screen.resize(lines, cols)

    def pump(self) -> None:
        """Feed pyte everything written so far (the pty turns each \\n into \\r\\n)."""
        want, got = self.written, 0
        while got < want:
            ready, _, _ = select.select([self.master], [], [], 30)  # a safety net only: the bytes are there
            assert ready, "the pseudo-terminal gave back less than was written"
            data = os.read(self.master, 65536)
            got += len(data)
            self.vt.feed(data)
        self.written = 0

    def rows(self) -> list[str]:
        self.pump()
        return [line.rstrip() for line in self.screen.display]

    def close(self) -> None:
        self.stream.close()
        os.close(self.slave)
        os.close(self.master)


class _Counting(io.RawIOBase):
    def __init__(self, raw, term: Terminal):
        self.raw, self.term = raw, term

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:
        n = self.raw.write(b)
        self.term.written += n + bytes(b[:n]).count(b"\n")  # ONLCR: CR added before each LF
        return n

    def isatty(self) -> bool:
        return True

    def fileno(self) -> int:
        return self.raw.fileno()


@pytest.fixture
def term():
    terms = []

    def make(cols, lines):
        terms.append(Terminal(cols, lines))
        return terms[-1]

    yield make
    for t in terms:
        t.close()


def _block_on_screen(rows: list[str], block: list[str]) -> int:
    """Index of the screen row where ``block`` appears whole; the block must appear exactly once."""
    starts = [k for k in range(len(rows) - len(block) + 1) if rows[k : k + len(block)] == block]
    assert len(starts) == 1, "\n".join(rows)
    return starts[0]


@pytest.mark.parametrize("cols,lines", [(120, 30), (100, 20), (60, 20), (40, 8)])
def test_the_block_fits_the_terminal_and_is_redrawn_in_place(term, cols, lines):
    t = term(cols, lines)
    t.stream.write("$ imustation capture lab.toml\n")
    view = StatusView(t.stream)
    assert view.tty and view.size() == (cols, lines)
    history: dict = {}  # the view's rate window, kept alike (statusview.with_rates)
    for step in range(6):
        view.show(lab_status(step, failed="adis16448" if step >= 3 else ""))
        rows = t.rows()
        block = status_block(with_rates(lab_status(step, failed="adis16448" if step >= 3 else ""), history), cols,
                             lines)  # fmt: skip
        assert len(block) <= lines - 1 and all(len(line) < cols for line in block)
        at = _block_on_screen(rows, block)
        # nothing stale: the command line above, the block, then blank rows
        assert rows[:at] == ["$ imustation capture lab.toml"] and not any(rows[at + len(block) :])
    joined = "\n".join(rows)
    assert "ADIS16448" not in joined and "FAILED" in joined  # a device that fails is shown, even when rows are few
    assert "(-" not in joined and "left" in joined or cols < 60


def test_a_wide_table_keeps_its_most_needed_columns():
    wide = status_block(lab_status(4), 120, 30)
    narrow = status_block(lab_status(4), 40, 30)
    assert wide[1].split() == ["device", "state", "rate/cfg", "Hz", "samples", "gaps", "lost", "temp"]
    title = [k for k, line in enumerate(narrow) if line.startswith("device")]
    assert title == [3] and narrow[3].split() == ["device", "state", "rate/cfg", "Hz", "gaps"]
    assert narrow[:3] == ["recording 1h02m09s of 12h00m00s", "10h57m51s left  231.4 MiB written", "48.0 GiB free"]
    assert [line.split()[0] for line in wide[2:9]] == [name for name, _ in LAB]
    assert wide[3].split() == ["bmx055_accel", "ok", "399.6/400", str(int(400 * 3729)), "2", "208", "30.9°C"]


def test_fewer_lines_than_devices_show_the_troubled_ones_and_count_the_rest():
    block = status_block(lab_status(2, failed="mti"), 60, 7)
    assert len(block) == 6
    names = [line.split()[0] for line in block[2:4]]
    assert names == ["bmx055", "mti"] and "MTI FAILED" not in block[3] and "FAILED" in block[3]
    assert block[4].startswith("… 5 more devices, all ok; gaps 5, lost 520")
    assert block[5].startswith("thermometers: ambient1 23.19°C")
    tiny = status_block(lab_status(2, failed="mti"), 40, 4)
    assert tiny[1] == "7 devices, mti FAILED; gaps 7, lost 728"


def test_no_negative_times_or_counts():
    over = lab_status(0, elapsed=43300.0)  # the last interval ran past the planned duration
    over["state"] = "done"
    text = "\n".join(status_block(over, 120, 30)) + status_line(over)
    assert "(-" not in text and "left" not in text and "gaps 1 (-" not in text
    assert status_block(over, 120, 30)[0].startswith("done 12h01m40s of 12h00m00s")
    stopped = {**over, "state": "stopped", "reason": "disk full: 16 MiB left"}
    assert status_block(stopped, 120, 30)[0].startswith("stopped (disk full: 16 MiB left) 12h01m40s")


def test_a_resized_terminal_gets_a_fresh_block_and_notes_go_above_it(term):
    t = term(100, 24)
    view = StatusView(t.stream)
    view.show(lab_status(0))
    t.resize(60, 24)
    view.show(lab_status(1))
    rows = t.rows()
    last = status_block(lab_status(1), 60, 24)
    at = _block_on_screen(rows, last)
    assert not any(rows[at + len(last) :])
    view.note("monitor: started (pid 4242) at http://127.0.0.1:8765/")
    rows = t.rows()
    at2 = _block_on_screen(rows, last)
    assert rows[at2 - 1] == "monitor: started (pid 4242) at http://127.0.0.1:8765/"
    assert rows.count("monitor: started (pid 4242) at http://127.0.0.1:8765/") == 1
    view.close()
    t.stream.write("wrote night.h5\n")
    rows = t.rows()
    at3 = _block_on_screen(rows, last)
    assert rows[at3 + len(last)] == "wrote night.h5"


def test_plain_lines_when_not_a_terminal():
    out = io.StringIO()
    view = StatusView(out)
    for step in range(3):
        view.show(lab_status(step))
    view.close()
    lines = out.getvalue().splitlines()
    assert lines == [status_line(lab_status(k)) for k in range(3)]
    assert "\x1b" not in out.getvalue() and "\r" not in out.getvalue()
    assert lines[2].startswith("recording 1h02m07s of 12h00m00s, 10h57m53s left, 231.4 MiB written, 48.0 GiB free")
    assert "| bmx055 399.6/400 Hz 1490800 samples gaps 1 lost 104 30.7°C |" in lines[2]


def test_capture_under_a_pseudo_terminal_draws_the_final_block(tmp_path, demo_config):
    """The real command in a 72 x 12 pty; one status interval longer than the capture: only the final block."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 12, 72, 0, 0))
    out = tmp_path / "c.h5"
    cmd = [sys.executable, "-m", "imustation", "capture", demo_config.path, "--simulate", "--duration", "3s",
           "-o", str(out), "--status-interval", "3600", "--no-fsync"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdin=slave, stdout=slave, stderr=slave, close_fds=True)
    os.close(slave)
    screen = pyte.Screen(72, 12)
    vt = pyte.ByteStream(screen)
    while True:
        try:
            data = os.read(master, 65536)
        except OSError as exc:  # EIO: every writer closed the slave side
            assert exc.errno == errno.EIO
            break
        if not data:
            break
        vt.feed(data)
    os.close(master)
    assert proc.wait() == 0
    rows = [line.rstrip() for line in screen.display]
    text = "\n".join(rows)
    assert rows[0].startswith("done 3s of 3s"), text
    assert rows[1].split()[:4] == ["device", "state", "rate/cfg", "Hz"] and rows[2].split()[:2] == ["bmx055", "ok"]
    assert rows[3].startswith("wrote /") and "1200 samples from 1 device(s)" in text  # the summary below the block
    assert all(len(line) < 72 for line in rows[:3])


def test_the_final_json_record_is_up_to_date(tmp_path, demo_config):
    """--json-status and --status-file: the last record ("done") counts every sample and byte on disk."""
    out = tmp_path / "r.h5"
    status_file = tmp_path / "status.json"
    res = CliRunner().invoke(
        cli,
        ["capture", demo_config.path, "--simulate", "--duration", "25s", "--rotate", "10s", "-o", str(out),
         "--json-status", "--status-file", str(status_file), "--no-fsync"],
        catch_exceptions=False,
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    docs = [json.loads(line) for line in res.stdout.splitlines()]
    final = docs[-1]
    assert final["state"] == "done" and json.loads(status_file.read_text()) == final
    parts = [str(tmp_path / f"r.{k:03d}.h5") for k in (1, 2, 3)]
    assert final["file_bytes"] == sum(os.path.getsize(p) for p in parts)
    with open_series(str(out)) as run:
        assert final["on_disk"] == {"bmx055": run.devices["bmx055"].n} == {"bmx055": 25 * 400}
    assert final["devices"]["bmx055"]["samples"] == 25 * 400 and final["part"] == 3
    assert final["disk_free_bytes"] > 0


def test_the_final_record_of_a_single_file_counts_its_last_flush(tmp_path, demo_config):
    statuses = []
    from imustation.acquisition import capture

    # flush interval 1 s of wall time is longer than this simulation: only closing the file flushes
    capture(demo_config, tmp_path / "one.h5", 5.0, simulate=True, on_status=statuses.append, fsync=False)
    final = statuses[-1]
    assert [s["state"] for s in statuses].count("done") == 1 and final["state"] == "done"
    assert final["on_disk"] == {"bmx055": 2000} and final["file_bytes"] == os.path.getsize(tmp_path / "one.h5")
    earlier = copy.deepcopy(statuses[:-1])
    assert all(s["state"] == "recording" for s in earlier)


def test_a_stream_without_unicode_gets_ascii():
    raw = io.BytesIO()
    out = io.TextIOWrapper(raw, encoding="ascii")
    view = StatusView(out)
    view.show(lab_status(0))
    out.flush()
    text = raw.getvalue().decode("ascii")
    assert "30.5 C" in text and "23.19 C" in text
