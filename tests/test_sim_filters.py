"""Output filters of the simulated chips (drivers/sim/filters.py) at both simulation levels."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
from scipy.signal import get_window, welch
from scipy.stats import chi2

from imustation.acquisition import capture
from imustation.acquisition.config import parse_config
from imustation.analysis.estimators.models.reference import TABLE_IV
from imustation.analysis.estimators.models.standard import StandardNoiseStream
from imustation.configs import config_path
from imustation.drivers.sim import device_sources, filters
from imustation.drivers.sim.sources import NoiseSource
from imustation.runfile import open_run
from imustation.units import DEG2RAD

with open(config_path("lab-realistic.toml"), "rb") as _fh:
    LAB = tomllib.load(_fh)
#: no slow terms: what is left is the filtered white noise (and the paper-level Gauss-Markov, none here)
WHITE_ONLY = {"bias_instability": 0.0, "rate_random_walk": 0.0, "bias_tempco": 0.0}
ACCEL_WHITE_ONLY = {"accel_" + k: v for k, v in WHITE_ONLY.items()}
#: Welch segment length of the PSD checks
NPERSEG = 256
#: chips whose datasheet delay no non-resonant low-pass of 1st/2nd order meets (docs/simulation.md), s
DELAY_LIMITS = {
    "InvenSense MPU-9150 (MPU-6050 core) gyro DLPF_CFG 5": 2.6e-3,
    "InvenSense MPU-9150 (MPU-6050 core) gyro DLPF_CFG 6": 13.3e-3,
    "InvenSense MPU-9150 (MPU-6050 core) accel DLPF 0": 0.5e-3,
    "InvenSense MPU-9150 (MPU-6050 core) accel DLPF 5": 2.2e-3,
    "InvenSense MPU-9150 (MPU-6050 core) accel DLPF 6": 12.9e-3,
    "InvenSense MPU-6500 gyro DLPF_CFG 7": 0.04e-3,
    "InvenSense MPU-6500 accel DLPF 0": 0.13e-3,
    "InvenSense MPU-6500 accel DLPF 7": 0.13e-3,
}


def _device(name: str, **settings) -> dict:
    dev = dict(next(d for d in LAB["device"] if d["name"] == name), **settings)
    accel = dev["driver"] in ("bmx055_accel", "mpu9150", "mpu6500")
    gyro = dev["driver"] != "bmx055_accel"
    dev["sim"] = {"profile": "datasheet", **(WHITE_ONLY if gyro else {}), **(ACCEL_WHITE_ONLY if accel else {})}
    return dev


def _one(dev: dict):
    return parse_config({"station": {"seed": 5}, "device": [dev]})


def test_every_setting_has_the_datasheet_bandwidth_and_delay():
    for f in filters.every_setting():
        bw = f.model_bandwidth_hz()
        if f.bandwidth_hz is not None and not f.structure.startswith("none"):
            assert bw == pytest.approx(f.bandwidth_hz, rel=1e-4), f.chip
        if f.delay_s is not None:
            err = abs(f.model_delay_s() - f.delay_s)
            assert err <= DELAY_LIMITS.get(f.chip, 1e-9), (f.chip, err)
        assert not f.interval_mean or f.white_equivalent


def test_adis16448_bartlett_filter_halves_the_power_where_linux_says():
    # SENS_AVG B = 4: two 16-tap stages; "approximately 16 Hz" (ADIS16448 datasheet), fs/50 (Linux's estimate)
    f = filters.adis16448(0, 16)
    assert f.model_bandwidth_hz() == pytest.approx(819.2 / 50, rel=0.01)
    assert f.model_delay_s() == pytest.approx(15 / 819.2)  # (N - 1) samples of two N-tap averages


def _welch_interval(x: np.ndarray, fs: float, nperseg: int = NPERSEG):
    """One-sided PSD (no overlap, so the segments are independent) and its 99.9 % chi-square band per bin."""
    f, p = welch(x - x.mean(), fs, window="hann", nperseg=nperseg, noverlap=0, detrend=False)
    k = len(x) // nperseg
    lo, hi = chi2.ppf([0.0005, 0.9995], 2 * k) / (2 * k)
    keep = (f > 0) & (f < fs / 2)  # DC and Nyquist bins are not chi-square with 2k degrees
    return f[keep], p[keep], lo, hi


def _expected_welch(gain, density: float, fs: float, f: np.ndarray, nperseg: int = NPERSEG) -> np.ndarray:
    """What Welch's estimate averages to for a process of two-sided PSD ``density**2 * gain(f)``:
    the PSD seen through the Hann window (leakage included), one-sided."""
    m = 1 << 16
    grid = np.arange(m) * fs / m
    r = np.fft.ifft(density**2 * gain(np.minimum(grid, fs - grid))).real * fs  # autocovariance at lags k / fs
    w = get_window("hann", nperseg)
    lags = np.arange(-(nperseg - 1), nperseg)
    terms = r[lags % m] * np.correlate(w, w, "full")
    return 2.0 * (np.cos(2 * np.pi * np.outer(f, lags) / fs) @ terms) / (fs * np.sum(w**2))


SETTINGS = [
    ("bmx055", {}),
    ("bmx055", {"rate_hz": 100, "bandwidth_hz": 12}),
    ("bmx055-accel", {}),
    ("bmx055-accel", {"rate_hz": 1000}),
    ("mpu9150", {}),
    ("mpu9150", {"rate_hz": 1000, "bandwidth_hz": 5}),
    ("mpu6500", {}),
    ("mpu6500", {"rate_hz": 500, "bandwidth_hz": 92}),
    ("adis", {}),
    ("adis", {"decimation": 0, "filter_taps": 8}),
    ("adis", {"decimation": 2, "filter_taps": 2}),
    ("mti", {}),
    ("fog", {}),
]


@pytest.mark.parametrize("name,settings", SETTINGS, ids=[f"{n}-{'-'.join(map(str, s.values()))}" for n, s in SETTINGS])
def test_the_simulated_psd_follows_the_configured_filter(name, settings):
    cfg = _one(_device(name, **settings))
    dev = cfg.devices[0]
    chip_filters = filters.for_device(dev.driver, dev.settings)
    for channel, source in device_sources(dev, 11).items():
        x = source.next(1 << 18)[:, 0]
        f, p, lo, hi = _welch_interval(x, source.fs_hz)
        density = source.models[0].sigma_w
        gain = chip_filters[channel].output_gain
        ratio = p / _expected_welch(gain, density, source.fs_hz, f)
        outside = np.sum((ratio < lo) | (ratio > hi))
        assert outside <= 2, (name, channel, outside, ratio.min(), ratio.max())
        if gain(f).min() < 0.5:
            # the test can fail: a flat (unfiltered) PSD is far outside the interval
            flat = p / (2 * density**2)
            assert np.sum((flat < lo) | (flat > hi)) > len(f) / 4


@pytest.mark.parametrize("name", [d["name"] for d in LAB["device"]])
def test_bus_and_model_level_record_the_same_samples(name, tmp_path):
    """Filters and the further terms included: the bus-level samples appear, in order, in the model-level stream."""
    dev = dict(next(d for d in LAB["device"] if d["name"] == name))
    dev["sim"] = {k: v for k, v in dev["sim"].items() if k != "faults"}
    cfg = _one(dev)
    capture(cfg, tmp_path / "bus.h5", 20.0, simulate=True)
    capture(cfg, tmp_path / "model.h5", 20.0, simulate=True, sim_level="model")
    own = {"adis": "accel", "mti": "accel"}  # these simulators draw their accelerometer noise themselves
    with open_run(tmp_path / "bus.h5") as a, open_run(tmp_path / "model.h5") as b:
        channels = [c for c in ("gyro", "accel") if c in a.devices[name].channels and own.get(name) != c]
        assert channels
        for channel in channels:
            bus, model = a.read(name, channel), b.read(name, channel)
            bus, model = bus.reshape(len(bus), -1), model.reshape(len(model), -1)
            hits = [i for i in range(len(model) - 32) if np.array_equal(model[i : i + 32], bus[:32])]
            assert len(hits) == 1, (name, channel)
            k = min(len(bus), len(model) - hits[0])
            assert k > 0.9 * 20 * a.devices[name].rate_hz
            np.testing.assert_array_equal(model[hits[0] : hits[0] + k], bus[:k])


def test_filter_key_switches_the_filter_off_and_on():
    dev = _device("bmx055")
    f = filters.for_device("bmx055", _one(dev).devices[0].settings)["gyro"]
    for sim, expect_filtered in (({}, True), ({"filter": False}, False)):
        cfg = _one({**dev, "sim": {**dev["sim"], **sim}})
        source = device_sources(cfg.devices[0], 3)["gyro"]
        x = source.next(1 << 18)[:, 0]
        fr, p, lo, hi = _welch_interval(x, source.fs_hz)
        gain = f.output_gain if expect_filtered else np.ones_like
        ratio = p / _expected_welch(gain, source.models[0].sigma_w, source.fs_hz, fr)
        assert np.sum((ratio < lo) | (ratio > hi)) <= 2, sim
    # and on for the paper's profile
    cfg = _one({**dev, "sim": {"filter": True}})
    source = device_sources(cfg.devices[0], 3)["gyro"]
    assert source.filtering and source.chip_filter == f


def test_the_paper_profile_is_the_papers_discrete_model_sample_for_sample():
    """Oracle: StandardNoiseStream (Algorithm 1) per axis on the generators the source always used."""
    seed, fs = 17, 400.0
    for sim in ({}, {"profile": "paper"}, {"profile": "paper", "sigma_w": 2e-4}):
        source = NoiseSource.for_device("bmx055", "xyz", fs, sim, seed)
        source.use_filter(filters.bmg160(0x03))  # told the chip's filter: the paper's profile leaves it off
        rng = np.random.default_rng(seed)
        b_on = np.random.default_rng([seed, 0x5EED]).normal(0.0, 0.5, 3) * DEG2RAD
        streams = []
        for i, axis in enumerate("xyz"):
            model = TABLE_IV["bmx055"][axis]
            if "sigma_w" in sim:
                model = type(model)(sim["sigma_w"], model.sigma_b, model.tau_b)
            model = type(model)(model.sigma_w, model.sigma_b, model.tau_b, b_on[i])
            streams.append(StandardNoiseStream(model, fs, np.random.default_rng(rng.integers(2**63))))
        expected = np.column_stack([s.next(NoiseSource.BLOCK) for s in streams])
        got = np.concatenate([source.next(1000) for _ in range(math.ceil(NoiseSource.BLOCK / 1000))])
        np.testing.assert_array_equal(got[: NoiseSource.BLOCK], expected)
