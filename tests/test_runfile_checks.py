"""Validation on read (imustation/runfile/checks.py): a run file whose attributes contradict the
schema or each other is refused with the reason, instead of being read as something else."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest
from fuzz_corpus import base_run

from imustation.errors import InputError, RunFileError
from imustation.runfile import open_run


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return base_run(tmp_path_factory.mktemp("checks"))


def _edited(base, tmp_path, edit):
    p = tmp_path / "edited.h5"
    shutil.copyfile(base, p)
    with h5py.File(p, "r+") as f:
        edit(f)
    return p


def _refused(path, *needles):
    with pytest.raises(RunFileError) as err:
        with open_run(path) as run:
            run.events()
    for needle in needles:
        assert needle in str(err.value), str(err.value)


def test_the_base_file_is_sound(base):
    with open_run(base) as run:
        lost = sum(e.lost for e in run.events() if e.kind == "gap")
        assert run.complete and lost > 0 and run.devices["gyro"].n + lost == 10000


def test_missing_scale_is_not_read_as_one(base, tmp_path):
    """Without 'scale' the reader used 1.0: sigma_w 15,000x off, exit 0."""
    edit = lambda f: f["devices/gyro/gyro"].attrs.__delitem__("scale")  # noqa: E731
    _refused(_edited(base, tmp_path, edit), "gyro/gyro", "'scale'")


@pytest.mark.parametrize("scale", [0.0, float("nan"), float("inf"), "x"])
def test_unusable_scale(base, tmp_path, scale):
    _refused(_edited(base, tmp_path, lambda f: f["devices/gyro/gyro"].attrs.__setitem__("scale", scale)), "scale")


@pytest.mark.parametrize("factor", [2.0, 0.5])
def test_rate_contradicting_the_timestamps(base, tmp_path, factor):
    def edit(f):
        f["devices/gyro"].attrs["rate_hz"] = 100.0 * factor

    _refused(_edited(base, tmp_path, edit), "rate_hz", "contradicts its timestamps", "100 Hz")


@pytest.mark.parametrize("rate", [0.0, -1.0, float("nan"), float("inf"), "fast", 1e9])
def test_unusable_thermometer_rate(base, tmp_path, rate):
    edit = lambda f: f["thermometers/ambient"].attrs.__setitem__("rate_hz", rate)  # noqa: E731
    _refused(_edited(base, tmp_path, edit), "thermometers/ambient", "'rate_hz'")


def test_thermometer_rate_contradicting_its_readings(base, tmp_path):
    edit = lambda f: f["thermometers/ambient"].attrs.__setitem__("rate_hz", 4.0)  # noqa: E731
    _refused(_edited(base, tmp_path, edit), "thermometers/ambient", "contradicts its timestamps", "1 Hz")


def test_a_thermometer_without_a_stored_rate_still_reads(base, tmp_path):
    """Files written before the rate was stored: read, the rate None (not guessed)."""
    with open_run(base) as run:
        assert run.thermometer_rate_hz("ambient") == 1.0
    edit = lambda f: f["thermometers/ambient"].attrs.__delitem__("rate_hz")  # noqa: E731
    with open_run(_edited(base, tmp_path, edit)) as run:
        assert run.thermometer_rate_hz("ambient") is None and len(run.temperatures("ambient")[0]) == 100


def test_no_timestamps_beside_samples(base, tmp_path):
    """A t of 0 rows beside the samples in a complete file (not a torn last block)."""
    _refused(_edited(base, tmp_path, lambda f: f["devices/gyro/t"].resize(0, axis=0)), "different lengths", "t 0")


def test_negative_loss(base, tmp_path):
    def edit(f):
        rows = f["events"][()]
        rows[-1]["lost"] = -5
        f["events"][-1] = rows[-1]

    _refused(_edited(base, tmp_path, edit), "negative loss")


def test_external_link(base, tmp_path):
    edit = lambda f: f["devices/gyro"].__setitem__("mag", h5py.ExternalLink("other.h5", "/x"))  # noqa: E731
    _refused(_edited(base, tmp_path, edit), "external link", "devices/gyro/mag")


def test_billions_of_unwritten_rows(base, tmp_path):
    def edit(f):
        for ds in f["devices/gyro"].values():
            ds.resize(2**33, axis=0)

    _refused(_edited(base, tmp_path, edit), "claims 8589934592 rows")


def test_unexpected_member(base, tmp_path):
    _refused(_edited(base, tmp_path, lambda f: f["devices/gyro"].create_group("sub")), "devices/gyro/sub", "group")


def test_float_channel_with_impossible_values_is_not_analysed(base, tmp_path):
    """What a corrupt bag used to import (4.3e19 rad/s) is refused by the loader, not analysed."""
    from imustation.analysis.pipeline.loaders import load_run

    def edit(f):
        g = f["devices/gyro"]
        attrs = dict(g["gyro"].attrs)
        n = g["gyro"].shape[0]
        del g["gyro"]
        data = np.full((n, 3), 0.01)
        data[123, 1] = 4.3e19
        ds = g.create_dataset("gyro", data=data, maxshape=(None, 3), chunks=(8192, 3))
        ds.attrs.update({**attrs, "scale": 1.0})

    (ch,) = [c for c in load_run(str(_edited(base, tmp_path, edit))) if c.id == "gyro/gyro/y"]
    with pytest.raises(InputError, match="sample 123"):
        ch.rate()
