"""A recorded signal replayed through a chip simulator comes back sample for sample."""

import numpy as np
import pytest

from imustation.acquisition import capture
from imustation.acquisition.config import parse_config
from imustation.drivers.bmx055 import range_row
from imustation.errors import ImustationError
from imustation.runfile import open_run


def _cfg(sim):
    return parse_config({"device": [{"name": "g", "driver": "bmx055", "bus": "i2c:1", "sim": sim}]})


def test_npy_recording_replays_exactly(tmp_path):
    scale = range_row(125).scale
    counts = np.random.default_rng(1).integers(-2000, 2000, size=(4000, 3))
    np.save(tmp_path / "rec.npy", counts * scale)  # rad/s
    capture(_cfg({"replay": str(tmp_path / "rec.npy")}), tmp_path / "r.h5", 5.0, simulate=True)
    with open_run(tmp_path / "r.h5") as run:
        got = run.read("g", "gyro")
    # the first samples go to the start-up FIFO flush; the rest are the recording, in order
    n = len(got)
    assert n > 1900
    start = int(np.flatnonzero((counts == got[0]).all(axis=1))[0])
    assert np.array_equal(got, counts[start : start + n])


def test_run_file_channel_replays_into_a_new_capture(tmp_path):
    capture(_cfg({}), tmp_path / "a.h5", 10.0, simulate=True)
    capture(_cfg({"replay": f"{tmp_path / 'a.h5'}#g/gyro"}), tmp_path / "b.h5", 5.0, simulate=True)
    with open_run(tmp_path / "a.h5") as a, open_run(tmp_path / "b.h5") as b:
        ga, gb = a.read("g", "gyro"), b.read("g", "gyro")
    start = int(np.flatnonzero((ga == gb[0]).all(axis=1))[0])
    assert np.array_equal(gb, ga[start : start + len(gb)])


def test_used_up_recording_is_a_logged_fault(tmp_path):
    np.save(tmp_path / "short.npy", np.zeros((400, 3)))
    capture(_cfg({"replay": str(tmp_path / "short.npy")}), tmp_path / "s.h5", 5.0, simulate=True)
    with open_run(tmp_path / "s.h5") as run:
        faults = [e for e in run.events() if e.kind == "fault"]
        assert run.devices["g"].n <= 400
    assert faults and "used up after 400 samples" in faults[0].detail


@pytest.mark.parametrize(
    "sim,needle",
    [
        ({"replay": "nope.npy"}, "cannot read"),
        ({"replay": "x.npy", "replay_rate_hz": 100}, "100 Hz"),
    ],
)
def test_bad_replays(tmp_path, sim, needle):
    if "replay_rate_hz" in sim:
        np.save(tmp_path / "x.npy", np.zeros((10, 3)))
        sim = {**sim, "replay": str(tmp_path / "x.npy")}
    with pytest.raises(ImustationError, match=needle):
        capture(_cfg(sim), tmp_path / "bad.h5", 1.0, simulate=True)
