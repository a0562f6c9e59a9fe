"""Records that behave like real sensors, written directly with numpy/scipy for the estimator tests.

Independent of the estimators' own terms on purpose: the device filters are the chips'
structures (BMX055 gyro: 2nd-order Butterworth at 47 Hz on the 2 kHz internal rate, one
sample of five kept -> 400 Hz; MPU-9150 DLPF_CFG 3: 2-pole low-pass at 42 Hz on 1 kHz,
one of five -> 200 Hz; ADIS16448: Bartlett FIR of two 4-tap averages at 819.2 Hz, then
the mean of two -> 409.6 Hz), and the bias instability is a sum of Gauss-Markov terms
*two* per decade from 0.25 s to 1e7 s with non-negative least-squares weights fitted to
a flat Allan floor (the construction of the simulators of issue 21), not the estimators'
one-per-decade sum. Rate random walk: cumulative sum of white steps.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
from scipy.optimize import nnls
from scipy.signal import bilinear, lfilter

FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
#: output rates of the filtered devices, Hz
FS = {"bmx055": 400.0, "mpu9150": 200.0, "adis16448": 409.6, "none": 400.0}


def _gm_avar(tau: np.ndarray, var: float, T: float) -> np.ndarray:
    a = tau / T
    return var / a**2 * (2 * a - 3 + 4 * np.exp(-a) - np.exp(-2 * a))


@cache
def flicker_design() -> tuple[np.ndarray, np.ndarray]:
    """(correlation times s, stationary variances per B^2) of the two-per-decade Gauss-Markov sum."""
    times = 0.25 * 10 ** (np.arange(int(round(math.log10(1e7 / 0.25) * 2)) + 1) / 2)
    tau = np.logspace(0, 6, 300)
    A = np.column_stack([_gm_avar(tau, 1.0, t) for t in times]) / FLOOR**2
    w, _ = nnls(A, np.ones_like(tau))
    return times, w


def flicker(n: int, fs: float, B: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` samples at ``fs`` Hz of bias instability ``B`` (floor 0.664 B)."""
    times, w = flicker_design()
    out = np.zeros(n)
    for T, wj in zip(times, w, strict=True):
        if wj <= 0:
            continue
        var = wj * B * B
        phi = math.exp(-1.0 / (fs * T))
        e = rng.normal(0.0, math.sqrt(var * (1 - phi * phi)), n)
        x, _ = lfilter([1.0], [1.0, -phi], e, zi=[phi * rng.normal(0.0, math.sqrt(var))])
        out += x
    return out


def _butter2(bw: float, fs: float) -> tuple[np.ndarray, np.ndarray]:
    wc = 2 * fs * math.tan(math.pi * bw / fs)
    return bilinear([wc * wc], [1, math.sqrt(2) * wc, wc * wc], fs)


def filtered_white(n: int, device: str, sigma_w: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` output samples of white rate noise of density ``sigma_w`` through ``device``'s filter."""
    if device == "adis16448":
        fi, r = 819.2, 2
        x = rng.normal(0.0, sigma_w * math.sqrt(fi), n * r + 16)
        for taps in (4, 4, r):
            x = np.convolve(x, np.ones(taps) / taps, "valid")
        return x[-n * r :][r - 1 :: r][:n]
    if device == "none":
        return rng.normal(0.0, sigma_w * math.sqrt(FS["none"]), n)
    fi, r, bw = {"bmx055": (2000.0, 5, 47.0), "mpu9150": (1000.0, 5, 42.0)}[device]
    b, a = _butter2(bw, fi)
    x = rng.normal(0.0, sigma_w * math.sqrt(fi), n * r + 4000)
    return lfilter(b, a, x)[4000:][r - 1 :: r][:n]


def record(device: str, hours: float, sigma_w: float, B: float = 0.0, K: float = 0.0, seed: int = 0):
    """(rate samples, fs_hz) of ``device`` with white noise ``sigma_w`` (rad/s/sqrt(Hz)) through its
    filter, bias instability ``B`` (rad/s) and rate random walk ``K`` (rad/s^2/sqrt(Hz))."""
    rng = np.random.default_rng(seed)
    fs = FS[device]
    n = int(hours * 3600 * fs)
    x = filtered_white(n, device, sigma_w, rng)
    if B:
        x = x + flicker(n, fs, B, rng)
    if K:
        x = x + np.cumsum(rng.normal(0.0, K / math.sqrt(fs), n))
    return x, fs


def low_frequency_gain(device: str) -> float:
    """Output PSD at 0 Hz over the white input density of ``device``'s chain: decimation folds the
    filter's response at multiples of the output rate onto 0 Hz (MPU-9150 chain: 1.0022), so the
    output's white-noise density, what any estimator measures, is ``sigma_w sqrt(gain)``."""
    if device == "none":
        return 1.0
    if device == "adis16448":
        return 1.0  # the mean over each output interval has zeros at every multiple of the output rate
    fi, r, bw = {"bmx055": (2000.0, 5, 47.0), "mpu9150": (1000.0, 5, 42.0)}[device]
    b, a = _butter2(bw, fi)
    h = lfilter(b, a, np.r_[1.0, np.zeros(20000)])
    g = np.correlate(h, h, "full")[len(h) - 1 :][::r]
    return float(r * (g[0] + 2 * g[1:].sum()))
