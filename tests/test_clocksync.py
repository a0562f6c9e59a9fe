"""The host clock: its synchronisation state in the run file and the status, a wall-clock step logged."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.acquisition import capture, load_config
from imustation.acquisition.clocksync import (
    STA_UNSYNC,
    TIME_ERROR,
    ClockWatch,
    HostClocks,
    KernelTime,
    StepWatch,
    kernel_adjtimex,
    read_sync,
)
from imustation.cli import cli
from imustation.cli.statusview import header
from imustation.runfile import open_run


@pytest.mark.parametrize(
    ("kt", "word", "est"),
    [
        (KernelTime(0, 0x2001, 1200, 15000), "synchronised", 1.2e-3),  # STA_PLL | STA_NANO
        (KernelTime(0, STA_UNSYNC, 16_000_000, 16_000_000), "unsynchronised", None),
        (KernelTime(TIME_ERROR, 0, 0, 0), "unsynchronised", None),
        (None, "unknown", None),
    ],
)
def test_sync_state_from_adjtimex(kt, word, est):
    state = read_sync(lambda: kt)
    assert state.word == word and state.attrs()["clock_sync"] == word
    assert state.est_error_s == est
    assert ("clock_est_error_s" in state.attrs()) == (est is not None)


def test_the_real_adjtimex_answers():
    kt = kernel_adjtimex()  # Linux: always answers read-only
    assert kt is not None and 0 <= kt.state <= 5


class SteppedWall:
    """A monotonic clock advancing 1 s per reading and a wall clock stepped by ``step_ns`` from reading ``at``."""

    def __init__(self, at: int, step_ns: int):
        self.readings, self.at, self.step_ns = 0, at, step_ns

    def monotonic_ns(self) -> int:
        self.readings += 1
        return self.readings * 1_000_000_000

    def realtime_ns(self) -> int:
        slew = self.readings * 400  # 0.4 ppm of NTP slewing: never a step
        return (
            1_700_000_000_000_000_000
            + self.readings * 1_000_000_000
            + slew
            + (self.step_ns if self.readings >= self.at else 0)
        )


def test_step_watch_finds_a_step_not_a_slew():
    wall = SteppedWall(at=5, step_ns=-2_000_000_000)
    watch = StepWatch(HostClocks(wall.realtime_ns, wall.monotonic_ns))
    notes = [watch.check(k * 1_000_000_000) for k in range(1, 10)]
    stepped = [n for n in notes if n]
    assert len(stepped) == 1 and "stepped by -2.000 s" in stepped[0] and watch.steps == 1
    assert watch.check(9_500_000_000) is None  # within the check interval: not read


CONFIG = """
[station]
name = "clock"
seed = 3
[[device]]
name = "gyro"
driver = "bmx055"
bus = "i2c:1"
"""


def test_capture_stores_the_state_and_logs_a_step_with_sample_times_unaffected(tmp_path):
    cfg_path = tmp_path / "c.toml"
    cfg_path.write_text(CONFIG)
    cfg = load_config(cfg_path)
    synced = KernelTime(0, 0x2001, 1200, 15000)
    statuses = []
    wall = SteppedWall(at=20, step_ns=5_000_000_000)
    watch = ClockWatch(lambda: synced, HostClocks(wall.realtime_ns, wall.monotonic_ns))
    capture(cfg, tmp_path / "a.h5", 60.0, simulate=True, clock_watch=watch, on_status=statuses.append, fsync=False)
    capture(cfg, tmp_path / "b.h5", 60.0, simulate=True, clock_watch=ClockWatch(lambda: synced), fsync=False)
    with open_run(tmp_path / "a.h5") as a, open_run(tmp_path / "b.h5") as b:
        assert a.attrs["clock_sync"] == "synchronised" and a.attrs["clock_est_error_s"] == pytest.approx(1.2e-3)
        assert a.attrs["clock_max_error_s"] == pytest.approx(15e-3)
        steps = [e for e in a.events() if "wall clock stepped" in e.detail]
        assert len(steps) == 1 and "+5.000 s" in steps[0].detail and steps[0].kind == "note"
        assert not [e for e in b.events() if "stepped" in e.detail]
        assert np.array_equal(a.read("gyro", "t"), b.read("gyro", "t"))  # monotonic times: unaffected
    res = CliRunner().invoke(cli, ["inspect", str(tmp_path / "a.h5")])
    assert "host clock at the start: synchronised, estimated error 1.2 ms, at most 15.0 ms" in res.output
    assert "host wall clock stepped by +5.000 s" in res.output
    final = statuses[-1]
    assert final["clock"] == {"sync": "synchronised", "est_error_s": 1.2e-3, "max_error_s": 15e-3, "steps": 1}
    assert "clock synced ±1.2 ms, STEPPED 1x" in header({**final, "speed": 1.0})  # a real capture's header
    assert not [f for f in header(final) if "clock" in f]  # a simulation's times are virtual: not shown
    assert "clock UNSYNCHRONISED" in header({**final, "speed": 1.0, "clock": {"sync": "unsynchronised", "steps": 0}})
    assert not [f for f in header({**final, "speed": 1.0, "clock": {**final["clock"], "steps": 0}}) if "clock" in f]
