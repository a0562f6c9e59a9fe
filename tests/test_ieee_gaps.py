"""IEEE-952 coefficient fits on simulated terms; gap segmentation from run-file events; streaming reads."""

import numpy as np
import pytest
from scipy.signal import lfilter

from imustation.analysis import ieee_coefficients, oadev
from imustation.analysis.pipeline.loaders import load_run, locate_breaks, segments_from_breaks
from imustation.runfile import ChannelSpec, DeviceSpec, RunWriter, open_run


def white_rrw_gm(seed, fs, n, N, K, s, T):
    rng = np.random.default_rng(seed)
    white = rng.normal(0, N * np.sqrt(fs), n)  # S = N^2 two-sided
    rrw = np.cumsum(rng.normal(0, K / np.sqrt(fs), n))  # increments K^2 dt
    phi = np.exp(-1 / (fs * T))
    gm = lfilter([1], [1, -phi], rng.normal(0, s * np.sqrt(1 - phi**2), n))
    return white + rrw + gm


@pytest.mark.parametrize("seed", [0, 1])
def test_ieee_recovers_N_and_K_from_white_rrw_gm(seed):
    # docs/reference/noise-formulas.md §5 "Check use": N within 5 %, K within 20 % (55 h at 10 Hz)
    N, K, s, T, fs = 1e-4, 1e-6, 2e-5, 5.0, 10.0
    c = ieee_coefficients(oadev(white_rrw_gm(seed, fs, 2_000_000, N, K, s, T), fs))
    assert c.N == pytest.approx(N, rel=0.05)
    assert c.K == pytest.approx(K, rel=0.20)
    assert c.adev_1s == pytest.approx(N, rel=0.05)  # white dominates at 1 s: the Kalibr reading
    assert c.gm_T == pytest.approx(T, rel=0.5) and c.gm_sigma == pytest.approx(s, rel=0.3)
    assert np.isfinite(c.N_stderr) and np.isfinite(c.K_stderr)


def test_ieee_quantisation_and_ramp():
    # angle error iid of variance Q^2 gives AVAR = 3 Q^2 / tau^2; a ramp R t gives R^2 tau^2 / 2 (exact)
    fs, n, Q, R, N = 100.0, 400_000, 1e-4, 1e-7, 1e-5
    rng = np.random.default_rng(8)
    e = rng.normal(0, Q, n + 1)
    t = np.arange(n) / fs
    rate = np.diff(e) * fs + R * t + rng.normal(0, N * np.sqrt(fs), n)
    c = ieee_coefficients(oadev(rate, fs))
    assert c.Q == pytest.approx(Q, rel=0.05)
    assert c.R == pytest.approx(R, rel=0.05)
    assert c.N == pytest.approx(N, rel=0.2)


def _write_run(path, gaps):
    """A 1-device run with 16-bit counts; ``gaps`` = [(sample index, lost)] breaks in the timestamps."""
    fs, n = 100.0, 20_000
    period = int(1e9 / fs)
    spec = DeviceSpec(
        "imu", "sim", "model", "sim", "id", fs, {}, (ChannelSpec("gyro", "<i2", "rad/s", 1e-3, 0.0, ("x", "y", "z")),)
    )
    rng = np.random.default_rng(9)
    counts = rng.integers(-500, 500, (n, 3)).astype(np.int16)
    steps = np.full(n, period, dtype=np.int64)
    for j, lost in gaps:
        steps[j] += lost * period
    t = np.cumsum(steps)
    with RunWriter(path, station="t", config_text="", simulated=True, devices=[spec]) as w:
        w.append("imu", t, {"gyro": counts})
        for j, lost in gaps:
            # logged at the read that found the loss: its block ends a few samples after the break
            w.event(int(t[min(j + 7, n - 1)]), "imu", "gap", "samples lost", lost=lost)
        w.event(int(t[15_000]), "imu", "overrun", "FIFO overrun", lost=0)  # nothing missing: no break
    return counts


def test_segments_from_gap_events(tmp_path):
    path = tmp_path / "gaps.h5"
    counts = _write_run(path, [(5_000, 40), (12_345, 3)])
    with open_run(path) as run:
        breaks = locate_breaks(run.dataset("imu", "t"), run.events(), 100.0)
    assert breaks == [5_000, 12_345]
    assert segments_from_breaks(breaks, 20_000) == [(0, 5_000), (5_000, 12_345), (12_345, 20_000)]
    chans = load_run(str(path))
    assert [c.id for c in chans] == ["imu/gyro/x", "imu/gyro/y", "imu/gyro/z"]
    ch = chans[1]
    assert ch.segments == [(0, 5_000), (5_000, 12_345), (12_345, 20_000)] and ch.gaps == 3
    # lazy: streamed blocks and the loaded array are the stored counts
    np.testing.assert_array_equal(np.concatenate(list(ch.iter_raw(rows=4096))), counts[:, 1])
    np.testing.assert_array_equal(ch.data, counts[:, 1])
    assert ch.data.dtype == np.int16
    ch.release()
    assert ch.n == 20_000


def test_streaming_path_equals_in_memory_path(tmp_path):
    path = tmp_path / "gaps.h5"
    _write_run(path, [(7_000, 10)])
    ch = load_run(str(path))[0]
    mem = oadev(ch.data.astype(np.float64) * ch.scale, ch.fs_hz, segments=ch.segments)
    low = oadev(ch.data, ch.fs_hz, scale=ch.scale, segments=ch.segments, max_bytes=0)
    np.testing.assert_allclose(low.adev, mem.adev, rtol=1e-11)
    np.testing.assert_array_equal(low.n, mem.n)
