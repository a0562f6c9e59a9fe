"""Resonances (IEEE Std 952-1997's band-limited, exponentially correlated components): found by a
hump test on the spectrum and kept out of the white-noise estimate, each named with the reason.

A resonance (a structural mode the gyro sees, a second-order Gauss-Markov process, the broad hump
of the ADIS16405 z gyro between 10 and 30 Hz) adds a band of excess power to the white noise. At
the fine cluster times the white-noise estimate reads (a few samples) it lifts the Allan variance
in a shape no term of the family has; beyond its correlation time it is either white (its power at
0 Hz, which then *is* part of the long-term white noise) or, when its angle stays bounded (zero
power at 0 Hz), white angle noise. So the white noise is read where the resonance has averaged out:
the fine-scale statistic starts beyond :data:`START_FACTOR` correlation times
(:class:`~imustation.analysis.estimators.ml.finescale.FilterHint` ``start_s``) and carries the angle
term the remainder looks like. Before (issue 32): a 35 Hz, Q 20 resonance gave sigma_w -4 .. -6 %,
covered only by a widened interval.

**Test** (:func:`find_resonances`): Welch's averaged periodogram (Hann, segments of
:data:`SEGMENT_S` s, 50 % overlap) of the first :data:`MAX_SAMPLES` samples, averaged in bands of
:data:`BANDS_PER_OCTAVE` per octave from :data:`FIRST_HZ` to :data:`TOP` of the Nyquist frequency.
A band is the top of a hump when its power stands above the lowest band on **both** sides by
:data:`MIN_RATIO` and by :data:`Z` standard errors of the logs (each band's mean of ``b`` bins over
``k`` independent segments has a relative error ``1/sqrt(k b)``). No spectrum of the family has such
an interior maximum: white noise is flat, a low-pass filter, flicker, random walk and Gauss-Markov
terms fall with frequency, white angle noise and the folding of decimation rise toward the Nyquist
frequency (excluded above :data:`TOP` of it), a filter's folded band is a valley, not a hump. The
test runs after the sinusoids are removed (:mod:`.periodic`), so a line is not a resonance.

**Band and correlation time**: on the periodogram smoothed over :data:`SMOOTH_HZ`, the frequencies
where the excess over the valley level falls to half its peak (the full width at half maximum
``df``); the envelope of a resonance of that width decays as ``exp(-pi df t)``, so its correlation
time is ``T = 1 / (pi df)`` and its quality ``Q = f_r / df``. Its Allan variance then carries the
resonance's ripples up to a few ``T``: the white noise is read from ``START_FACTOR * T`` on (and from
at least :data:`START_PERIODS` periods of the band's lowest frequency).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, signal

#: Welch segment length, s (resolution ~1.5 / SEGMENT_S Hz with the Hann window)
SEGMENT_S = 8.0
#: samples the test reads
MAX_SAMPLES = 1 << 20
#: lowest frequency tested, Hz (below, the slow terms and sinusoids the peak test cannot resolve)
FIRST_HZ = 1.0
#: highest frequency tested, as a fraction of the Nyquist frequency (filter edges and folding above)
TOP = 0.8
#: bands per octave of the hump test
BANDS_PER_OCTAVE = 6
#: a hump stands this far above the lowest band on both sides (a filter's ripple stays below 1.26)
MIN_RATIO = 1.5
#: ... and this many standard errors of the log power (Bonferroni over ~50 bands at 1e-4 each)
Z = 5.0
#: smoothing of the periodogram for the band edges, Hz
SMOOTH_HZ = 0.5
#: the white noise is read from this many correlation times of the resonance on
START_FACTOR = 3.0
#: ... and from at least this many periods of the lowest frequency in its band
START_PERIODS = 2.0


@dataclass(frozen=True)
class Resonance:
    """A resonance found in a channel: ``frequency_hz`` its peak, ``band_hz`` (lo, hi) its full width at
    half maximum, ``q`` its quality, ``psd_ratio`` the peak power over the valley level beside it,
    ``correlation_s`` (s) its envelope's correlation time, ``start_s`` (s) the cluster time from which
    the white noise is read (0: not excluded), ``reason`` one sentence for the user."""

    frequency_hz: float
    band_hz: tuple[float, float]
    q: float
    psd_ratio: float
    correlation_s: float
    start_s: float
    reason: str

    def as_dict(self) -> dict:
        return {
            "kind": "resonance",
            "frequency_hz": self.frequency_hz,
            "band_hz": list(self.band_hz),
            "q": self.q,
            "psd_ratio": self.psd_ratio,
            "correlation_s": self.correlation_s,
            "action": "white noise read beyond it" if self.start_s > 0 else "reported",
            "white_from_s": self.start_s,
            "reason": self.reason,
        }


def welch_psd(x: np.ndarray, fs_hz: float, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, int]:
    """Frequencies (Hz), one-sided Welch PSD ((unit)^2/Hz) of the first :data:`MAX_SAMPLES` samples of
    ``x`` (unit of the channel, or counts of ``scale`` units) and the number of independent segments
    (0 when the record is shorter than eight segments)."""
    part = np.asarray(x[:MAX_SAMPLES], dtype=float) * scale
    nseg = 1 << int(round(math.log2(max(SEGMENT_S * fs_hz, 64.0))))
    if len(part) < 8 * nseg:
        return np.zeros(0), np.zeros(0), 0
    f, p = signal.welch(part - part.mean(), fs_hz, window="hann", nperseg=nseg, noverlap=nseg // 2)
    return f, p, len(part) // nseg


def find_resonances(x: np.ndarray, fs_hz: float, scale: float = 1.0) -> list[Resonance]:
    """The humps of the spectrum of ``x`` (module docstring; ``x`` in the channel's unit, or counts of
    ``scale`` units, sampled at ``fs_hz`` Hz), strongest first, each with the cluster time from which the
    white noise is read."""
    f, p, k = welch_psd(x, fs_hz, scale)
    top = TOP * fs_hz / 2.0
    if k == 0 or top <= 2.0 * FIRST_HZ:
        return []
    edges = FIRST_HZ * 2.0 ** (np.arange(0, math.log2(top / FIRST_HZ) * BANDS_PER_OCTAVE + 1) / BANDS_PER_OCTAVE)
    idx = np.searchsorted(f, edges)
    counts = np.diff(idx)
    ok = counts > 0
    sums = np.add.reduceat(p, idx[:-1])[: len(counts)] if len(idx) > 1 else np.zeros(0)
    level = np.where(ok, sums / np.maximum(counts, 1), np.nan)
    centre = np.sqrt(edges[:-1] * edges[1:])
    level, centre, counts = level[ok], centre[ok], counts[ok]
    if len(level) < 3 or not np.all(level > 0):
        return []
    logp = np.log(level)
    var = 1.0 / (k * counts)  # relative variance of each band's mean (Hann neighbours not independent: conservative)
    # the lowest band on each side of every band (itself excluded) and where it lies
    left = np.minimum.accumulate(np.r_[np.inf, logp[:-1]])
    right = np.minimum.accumulate(np.r_[logp[1:], np.inf][::-1])[::-1]
    base = np.maximum(left, right)
    vl = var[_argmin_before(logp)]
    vr = var[_argmin_after(logp)]
    vbase = np.where(left >= right, vl, vr)
    z = (logp - base) / np.sqrt(var + vbase)
    hump = np.isfinite(base) & (logp - base > math.log(MIN_RATIO)) & (z > Z)
    out: list[Resonance] = []
    taken = np.zeros(len(level), dtype=bool)
    for i in np.argsort(-np.where(hump, logp - base, -np.inf)):
        if not hump[i] or taken[i]:
            continue
        # the whole hump: the bands above the valley level on either side of the top
        lo = hi = i
        floor = base[i]
        while lo > 0 and logp[lo - 1] > floor + 0.5 * math.log(MIN_RATIO):
            lo -= 1
        while hi + 1 < len(logp) and logp[hi + 1] > floor + 0.5 * math.log(MIN_RATIO):
            hi += 1
        taken[lo : hi + 1] = True
        res = _describe(f, p, fs_hz, centre[lo] / 2 ** (0.5 / BANDS_PER_OCTAVE),
                        centre[hi] * 2 ** (0.5 / BANDS_PER_OCTAVE), math.exp(floor))  # fmt: skip
        if res is not None:
            out.append(res)
    return out


def _argmin_before(logp: np.ndarray) -> np.ndarray:
    """Index of the lowest band strictly before each band (0 for the first)."""
    idx = np.zeros(len(logp), dtype=int)
    best = 0
    for i in range(1, len(logp)):  # ~50 bands: not per sample
        if logp[i - 1] < logp[best]:
            best = i - 1
        idx[i] = best if i > 0 else 0
    return idx


def _argmin_after(logp: np.ndarray) -> np.ndarray:
    """Index of the lowest band strictly after each band (the last for the last)."""
    n = len(logp)
    idx = np.full(n, n - 1, dtype=int)
    best = n - 1
    for i in range(n - 2, -1, -1):
        if logp[i + 1] < logp[best]:
            best = i + 1
        idx[i] = best
    return idx


def _describe(f: np.ndarray, p: np.ndarray, fs_hz: float, f_lo: float, f_hi: float, floor: float) -> Resonance | None:
    """The resonance whose hump spans ``f_lo`` .. ``f_hi`` (Hz) above the valley ``floor`` ((unit)^2/Hz):
    peak, half-maximum band, Q, correlation time and where the white noise is read."""
    df = float(f[1] - f[0])
    width = max(1, int(round(SMOOTH_HZ / df)))
    smooth = ndimage.uniform_filter1d(p, width, mode="nearest")
    sel = np.nonzero((f >= f_lo) & (f <= f_hi))[0]
    if len(sel) < 2:
        return None
    j = int(sel[np.argmax(smooth[sel])])
    peak = float(smooth[j])
    if not peak > floor:
        return None
    half = floor + 0.5 * (peak - floor)
    a = j
    while a > 0 and smooth[a - 1] > half:
        a -= 1
    b = j
    while b + 1 < len(smooth) and smooth[b + 1] > half:
        b += 1
    lo, hi = float(f[a]) - 0.5 * df, float(f[b]) + 0.5 * df
    fwhm = max(hi - lo, df)
    f0 = float(f[j])
    corr = 1.0 / (math.pi * fwhm)
    start = max(START_FACTOR * corr, START_PERIODS / max(lo, df))
    ratio = peak / floor
    reason = (
        f"a resonance at {f0:.3g} Hz ({lo:.3g}..{hi:.3g} Hz, Q {f0 / fwhm:.2g}, {ratio:.3g} x the spectrum beside it) "
        f"is no term of the model: the white noise is read from {start:.3g} s on, where it has averaged out "
        f"({START_FACTOR:g} correlation times of {corr:.3g} s)"
    )
    return Resonance(f0, (lo, hi), f0 / fwhm, ratio, corr, start, reason)
