"""Model choice speed: the 12 h realistic lab (31 channels) analysed with ``--model auto``.

Issue 22's budget: the whole lab with model choice and the fit checks in under 60 s on
two cores, and under 2 s per axis. The channels are written here with numpy, values of
the order of the datasheet profile of issue 21: white noise through each device's
output filter (BMX055 gyro 47 Hz and accelerometer 62.5 Hz Butterworth at 2 kHz,
InvenSense DLPF ~42 Hz at 1 kHz; ADIS16448 without FIR, MTi and DSP-3000 output
means: white), bias instability (Gauss-Markov terms two per decade from 0.25 s, on a
1/128 s grid) and rate random walk, stored as int16 counts. Each of two worker
processes times ``analyze_channel`` on stored channels (the filter settings in the
channel's metadata, as a run file gives them). The channels are made first and stored
(not timed), then analysed by the workers (timed, wall clock); the slowest axis is timed
once more alone (in the main process, warmed as the workers are; its cold first analysis is
printed too). Printed against the same-run reference of one ``np.sum`` over each
channel's counts. Errors are against the white-noise density of the output samples (the
filter's aliased gain at 0 Hz and the counts' rounding included); each sigma_w is printed with its stated 90 % interval
(relative to the truth, %).

    python benchmarks/bench_model_choice.py [--hours 12] [--workers 2] [--channels 31]
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

#: (device, driver, sensor, fs Hz, filter (internal Hz, ratio, bandwidth Hz) or None, sigma_w, B, K, settings)
_DEG = math.pi / 180.0
DEVICES = (
    ("bmx055", "bmx055", "gyro", 400.0, (2000.0, 5, 47.0), 0.014 * _DEG, 2e-5, 1.1e-6, {"bandwidth_hz": 47.0}),
    ("bmx055-accel", "bmx055_accel", "accel", 125.0, (2000.0, 16, 62.5), 1.5e-3, 3e-4, 1.6e-5, {"bandwidth_hz": 62.5}),
    ("mpu9150", "mpu9150", "gyro", 200.0, (1000.0, 5, 42.0), 0.005 * _DEG, 2e-4, 1.1e-5, {"bandwidth_hz": 42.0}),
    ("mpu9150", "mpu9150", "accel", 200.0, (1000.0, 5, 44.0), 3.9e-3, 4e-4, 2.2e-5, {"bandwidth_hz": 42.0}),
    ("mpu6500", "mpu6500", "gyro", 200.0, (1000.0, 5, 41.0), 0.01 * _DEG, 1e-4, 5e-6, {"bandwidth_hz": 41.0}),
    ("mpu6500", "mpu6500", "accel", 200.0, (1000.0, 5, 41.0), 2.9e-3, 3e-4, 1.6e-5, {"bandwidth_hz": 41.0}),
    ("adis", "adis16448", "gyro", 409.6, None, 0.66 / 60 * _DEG, 1.1e-4, 4e-6, {"filter_taps": 1, "decimation": 1}),
    ("adis", "adis16448", "accel", 409.6, None, 2.3e-3, 2e-4, 9e-6, {"filter_taps": 1, "decimation": 1}),
    ("mti", "mti", "gyro", 400.0, None, 0.01 * _DEG, 7.3e-5, 2.6e-6, {}),
    ("mti", "mti", "accel", 400.0, None, 8e-4, 1e-4, 3.6e-6, {}),
)
FOG = ("fog", "dsp3000", "gyro", 100.0, None, 0.0667 / 60 * _DEG, 7.3e-6, 8e-8, {})


def lab_channels(n_channels: int) -> list[tuple]:
    """The lab's channels (three axes per sensor, the fiber-optic gyro one), the first ``n_channels``."""
    out = [(*d, axis) for d in DEVICES for axis in "xyz"] + [(*FOG, "z")]
    return out[:n_channels]


def _flicker_and_walk(n: int, fs: float, B: float, K: float, rng: np.random.Generator) -> np.ndarray:
    """Bias instability B (two Gauss-Markov terms per decade from 0.25 s, as issue 21's simulators,
    weight 2 B^2 ln(sqrt 10)/(pi T) each) and rate random walk K on a 1/128 s grid, interpolated to
    the samples."""
    from scipy.signal import lfilter

    h = 1.0 / 128.0
    m = int(n / fs / h) + 2
    grid = np.zeros(m)
    for T in 0.25 * 10.0 ** (np.arange(16) / 2.0):
        q = 2.0 * B * B * math.log(math.sqrt(10.0)) / (math.pi * T)  # sigma_b^2
        var = q * T / 2.0
        phi = math.exp(-h / T)
        e = rng.normal(0.0, math.sqrt(var * (1 - phi * phi)), m)
        grid += lfilter([1.0], [1.0, -phi], e, zi=[phi * rng.normal(0.0, math.sqrt(var))])[0]
    grid += np.cumsum(rng.normal(0.0, K * math.sqrt(h), m))
    return np.interp(np.arange(n) / fs, np.arange(m) * h, grid)


def make_channel(spec: tuple, hours: float, seed: int):
    """A :class:`Channel` of int16 counts for one lab axis."""
    from scipy.signal import bilinear, lfilter

    from imustation.analysis.pipeline.loaders import Channel

    device, driver, sensor, fs, filt, sigma_w, B, K, settings, axis = spec
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 * fs)
    if filt is None:
        x = rng.normal(0.0, sigma_w * math.sqrt(fs), n)
    else:
        fi, r, bw = filt
        wc = 2 * fi * math.tan(math.pi * bw / fi)
        b, a = bilinear([wc * wc], [1, math.sqrt(2) * wc, wc * wc], fi)
        x = lfilter(b, a, rng.normal(0.0, sigma_w * math.sqrt(fi), n * r + 4000))[4000:][r - 1 :: r][:n]
    x += _flicker_and_walk(n, fs, B, K, rng)
    scale = sigma_w * math.sqrt(fs) / 8.0  # the white noise spans ~8 counts
    counts = np.clip(np.rint(x / scale), -32768, 32767).astype(np.int16)
    meta = {"device": device, "driver": driver, "settings": settings}
    return Channel(f"{device}/{sensor}/{axis}", fs, "rad/s" if sensor == "gyro" else "m/s^2", counts, scale,
                   source="bench", meta=meta)  # fmt: skip


def output_density(spec: tuple) -> float:
    """The white-noise density of the channel's output samples: ``sigma_w sqrt(G)``, ``G`` the filter's
    aliased gain at 0 Hz after decimation (what every estimator measures; 1.128 for the 62.5 Hz
    filter of the 125 Hz accelerometer, which folds much of its band onto 0 Hz)."""
    from scipy.signal import bilinear, lfilter

    filt, sigma_w = spec[4], spec[5]
    if filt is None:
        return sigma_w
    fi, r, bw = filt
    wc = 2 * fi * math.tan(math.pi * bw / fi)
    b, a = bilinear([wc * wc], [1, math.sqrt(2) * wc, wc * wc], fi)
    h = lfilter(b, a, np.r_[1.0, np.zeros(20000)])
    g = np.correlate(h, h, "full")[len(h) - 1 :][::r]
    return sigma_w * math.sqrt(r * (g[0] + 2 * g[1:].sum()))


def make_one(args: tuple) -> str:
    """Make one channel's int16 counts and store them (not timed); returns the file."""
    spec, hours, seed, folder = args
    ch = make_channel(spec, hours, seed)
    path = os.path.join(folder, f"{seed}.npy")
    np.save(path, ch.data)
    return path


def run_one(args: tuple) -> dict:
    """Time the analysis of one stored channel (and the np.sum reference over its counts)."""
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    from imustation.analysis.estimators.selection.model_choice import flicker_cut
    from imustation.analysis.pipeline.channel import analyze_channel
    from imustation.analysis.pipeline.loaders import Channel

    spec, path = args
    device, driver, sensor, fs, filt, sigma_w, B, K, settings, axis = spec
    counts = np.load(path)
    scale = sigma_w * math.sqrt(fs) / 8.0
    meta = {"device": device, "driver": driver, "settings": settings}
    units = "rad/s" if sensor == "gyro" else "m/s^2"
    ch = Channel(f"{device}/{sensor}/{axis}", fs, units, counts, scale, source=path, meta=meta)
    t0 = time.perf_counter()
    np.sum(counts, dtype=np.int64)
    t_ref = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = analyze_channel(ch)
    t_an = time.perf_counter() - t0
    choice = res.choice
    # the int16 counts' rounding is white rate noise of LSB^2/12 per sample at the output rate:
    # part of the output's white noise every estimator measures (+0.065 % at 8 counts per sigma)
    truth = math.hypot(output_density(spec), scale / math.sqrt(12.0 * fs))
    return {
        "id": ch.id,
        "pid": os.getpid(),
        "n": ch.n,
        "t": t_an,
        "t_ref": t_ref,
        "model": res.noise_model.model + (f"@{cut:.2g}s" if (cut := flicker_cut(res.noise_model)) else ""),
        "fits": choice.fits if choice else None,
        "candidates": len(choice.candidates) if choice else 0,
        "sigma_w_err": res.noise_model.sigma_w / truth - 1.0,
        "ci_err": [v / truth - 1.0 for v in res.noise_model.ci90.get("sigma_w", (math.nan, math.nan))],
        "ieee_N_err": res.ieee.N / truth - 1.0,
        "paper_err": choice.paper.sigma_w / truth - 1.0 if choice else math.nan,
        "flag": "slow terms reach" in res.noise_model.message,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--channels", type=int, default=31)
    args = ap.parse_args()
    os.environ["NUMBA_NUM_THREADS"] = "1"
    specs = lab_channels(args.channels)
    with tempfile.TemporaryDirectory() as folder, ProcessPoolExecutor(args.workers) as pool:
        t0 = time.perf_counter()
        paths = list(pool.map(make_one, [(s, args.hours, 1000 + i, folder) for i, s in enumerate(specs)]))
        t_make = time.perf_counter() - t0
        pool.submit(run_one, (specs[-1], paths[-1])).result()  # workers warm (imports, compiled kernels)
        pool.submit(run_one, (specs[-1], paths[-1])).result()
        t0 = time.perf_counter()
        rows = list(pool.map(run_one, list(zip(specs, paths, strict=True))))
        wall = time.perf_counter() - t0
        slowest = max(range(len(rows)), key=lambda i: rows[i]["t"])
        # the slowest axis with the machine to itself, in this process warmed as the workers were
        # (imports, compiled kernels loaded from numba's cache: ~0.4 s on the first analysis)
        cold = run_one((specs[slowest], paths[slowest]))["t"]
        alone = run_one((specs[slowest], paths[slowest]))["t"]
    total_samples = sum(r["n"] for r in rows)
    print(f"{len(rows)} channels, {args.hours:g} h, {total_samples / 1e6:.0f} M samples, {args.workers} workers")
    for r in rows:
        print(
            f"  {r['id']:22s} {r['n'] / 1e6:5.1f} M  {r['t']:5.2f} s (x{r['t'] / r['t_ref']:5.0f} np.sum)  "
            f"{r['model']:22s} {'fits' if r['fits'] else 'NO FIT'} ({r['candidates']} fitted)  "
            f"sigma_w {100 * r['sigma_w_err']:+.2f} % [{100 * r['ci_err'][0]:+.1f}, {100 * r['ci_err'][1]:+.1f}]"
            f"{' (flagged)' if r['flag'] else ''}  IEEE N "
            f"{100 * r['ieee_N_err']:+.2f} %  paper's wn+gm {100 * r['paper_err']:+.2f} %"
        )
    times = sorted(r["t"] for r in rows)
    ref = sum(r["t_ref"] for r in rows)
    print(f"analysis of the lab, wall time, {args.workers} workers: {wall:.1f} s; budget 60 s, ratio {wall / 60:.2f}")
    print(
        f"per axis (two analyses sharing the cores): median {times[len(times) // 2]:.2f} s, "
        f"90th percentile {times[int(0.9 * len(times))]:.2f} s, slowest {times[-1]:.2f} s ({rows[slowest]['id']})"
    )
    print(f"slowest axis alone: {alone:.2f} s; budget 2 s, ratio {alone / 2:.2f}")
    print(f"(the same axis as the first analysis of a fresh process: {cold:.2f} s)")
    print(f"all analyses / all np.sum references (same run): x{sum(r['t'] for r in rows) / ref:.0f}")
    fit = sum(bool(r["fits"]) for r in rows)
    held = sum(lo <= 0.0 <= hi for lo, hi in (r["ci_err"] for r in rows))
    print(f"chosen model fits: {fit} of {len(rows)}; sigma_w's 90 % interval holds the truth: {held} of {len(rows)}")
    print(f"(making the data, not timed above: {t_make:.0f} s)")


if __name__ == "__main__":
    main()
