"""sigma_w's interval takes in the fine scales' own reading, and the demo's paper rows compare with what the
stored record truly has (issue 32: the two small sigma_w misses on the project's own simulators)."""

import math

import numpy as np

from imustation.analysis.pipeline.channel import analyze_channel
from imustation.analysis.pipeline.loaders import Channel
from imustation.cli.demo import stored_truth
from imustation.drivers.sim.filters import for_device
from imustation.drivers.sim.sources import NoiseSource


def test_adis16448_datasheet_sigma_w_interval_holds_the_truth():
    # the zoo's project record (benchmarks/bench_zoo.py, seed 2003, z): wn+fl+lp read sigma_w -0.79 % with
    # an interval ending at -0.28 %; the fine scales alone read -0.37 +- 0.50 % (the slow terms' model, not
    # the record's flicker plus random walk, moved the model's point)
    settings = {"decimation": 1, "filter_taps": 4}
    cf = for_device("adis16448", settings)["gyro"]
    sim = {"profile": "datasheet", "warmup_c": 0.0, "bias_tempco": 0.0}
    src = NoiseSource.for_device("adis16448", "xyz", cf.fs_out_hz, sim, 2003)
    src.use_filter(cf)
    x = src.next(int(3600 * cf.fs_out_hz))[:, 2]
    truth = src.models[2].sigma_w * math.sqrt(float(cf.output_gain(np.array([0.0]))[0]))
    meta = {"device": "adis16448", "driver": "adis16448", "settings": settings}
    ch = Channel("sim/adis16448/gyro/z", cf.fs_out_hz, "rad/s", x - x.mean(), 1.0, source="test", meta=meta)
    res = analyze_channel(ch)
    lo, hi = res.noise_model.ci90["sigma_w"]
    assert lo <= truth <= hi, (lo / truth - 1, hi / truth - 1)
    assert "fine scales alone read sigma_w" in res.choice.chosen.message
    assert hi / lo - 1 < 0.025  # still an estimate: the union of two intervals of about +-0.5 %


def test_demo_truth_counts_the_rounding():
    # BMX055 at 125 deg/s full scale, 400 Hz: the counts add (LSB^2 / 12) / fs to sigma_w^2
    lsb = 125 / 32768 * math.pi / 180
    got = stored_truth("sigma_w", 1e-4, lsb, 400.0)
    assert math.isclose(got**2, 1e-8 + lsb**2 / 12 / 400.0, rel_tol=1e-12)
    assert stored_truth("sigma_w", 1e-4, 1.0, 400.0) == 1e-4  # float data: nothing rounded
    assert stored_truth("tau_b", 537.0, lsb, 400.0) == 537.0
