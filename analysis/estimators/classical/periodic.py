"""Sinusoidal components (IEEE Std 952-1997 names sinusoidal noise beside ARW, bias instability, RRW):
found by a spectral peak test and removed before the noise is fitted, each named with the reason.

A sinusoid ``A sin(2 pi f0 t)`` in the rate is bounded in angle, so its Allan variance falls as
``tau^-2`` with ripples (``A^2 sin^4(pi f0 tau) / (pi f0 tau)^2``): the model family reads it as
white angle noise or a Gauss-Markov term at the fine scales and trades the white noise against it
(a 7 Hz sinusoid of three times the samples' white deviation: sigma_w +59 %, outside its interval).
No term of the family describes it, and it is not noise: it is measured and subtracted.

**Test** (:func:`find_sinusoids`): Welch's averaged periodogram (Hann window, segments of
:data:`SEGMENT_S` s, 50 % overlap) of the first :data:`MAX_SAMPLES` samples; each bin against the
running median of its neighbours (:data:`BASELINE_BINS`), which follows any smooth spectrum
(white, filtered, flicker, broad resonances). Under a smooth spectrum the ratio is a chi-square of
``2 K`` degrees of freedom over ``2 K`` (``K`` the segments); a bin is a peak where the ratio
exceeds the ``1 - ALPHA / bins`` point (Bonferroni over the bins) and :data:`MIN_RATIO`. Adjacent
peak bins form one component; one as narrow as the window's main lobe (:data:`LINE_BINS`) is a
sinusoid, a wider one a narrow-band resonance (reported, not removed: it is noise, and
:mod:`.model_choice` carries it as an angle term beyond its correlation time).

**Removal** (:func:`remove_sinusoids`): the frequency is refined from the phase drift of block-wise
complex demodulations, then the sinusoid's amplitude and phase are fitted by least squares in
blocks of :data:`BLOCK_S` s (at least :data:`BLOCK_CYCLES` cycles, so a slowly drifting amplitude
or phase is followed) and subtracted. Each block removes two degrees of freedom from a band of
width ~1/block around f0: the white noise loses ``2 / (block samples)`` of its variance
(0.025 % at 20 s and 400 Hz), nothing at 0 Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, signal
from scipy.stats import chi2

#: Welch segment length, s (frequency resolution ~1.5 / SEGMENT_S with the Hann window)
SEGMENT_S = 20.0
#: samples the test reads (a sinusoid present through the record shows in any part of it)
MAX_SAMPLES = 1 << 20
#: neighbours of the running median that estimates the smooth spectrum under a bin
BASELINE_BINS = 65
#: family-wise false-alarm probability of the peak test over all bins
ALPHA = 1e-3
#: a peak must also stand this far above the smooth spectrum (a weak line changes no estimate)
MIN_RATIO = 4.0
#: widest component (bins above the threshold) still read as a sinusoid (Hann main lobe: 4 bins)
LINE_BINS = 6
#: lowest frequency tested, in bins (the running median needs neighbours on both sides)
FIRST_BIN = 8
#: removal blocks: at least BLOCK_S seconds and BLOCK_CYCLES cycles
BLOCK_S = 20.0
BLOCK_CYCLES = 50


@dataclass(frozen=True)
class Component:
    """A spectral peak: ``kind`` ``"sinusoid"`` (removed) or ``"resonance"`` (reported only);
    ``frequency_hz`` its centre, ``band_hz`` (lo, hi) its band, ``amplitude`` the sinusoid's peak
    amplitude (unit of the channel; NaN for a resonance), ``ratio`` the peak PSD over the smooth
    spectrum under it, ``reason`` one sentence for the user."""

    kind: str
    frequency_hz: float
    band_hz: tuple[float, float]
    amplitude: float
    ratio: float
    reason: str

    def as_dict(self) -> dict:
        return {
            "kind": self.kind,
            "frequency_hz": self.frequency_hz,
            "band_hz": list(self.band_hz),
            "amplitude": self.amplitude,
            "psd_ratio": self.ratio,
            "removed": self.kind == "sinusoid",
            "reason": self.reason,
        }


def find_sinusoids(x: np.ndarray, fs_hz: float, scale: float = 1.0) -> list[Component]:
    """Spectral peaks of ``x`` (unit of the channel, or integer counts of ``scale`` units each,
    sampled at ``fs_hz`` Hz) above the smooth spectrum (module docstring), from its first
    :data:`MAX_SAMPLES` samples; sinusoids get their refined frequency and median amplitude."""
    part = np.asarray(x[:MAX_SAMPLES], dtype=float) * scale
    nseg = 1 << int(round(math.log2(max(SEGMENT_S * fs_hz, 64.0))))
    if len(part) < 8 * nseg:
        return []
    f, p = signal.welch(part - part.mean(), fs_hz, window="hann", nperseg=nseg, noverlap=nseg // 2)
    base = ndimage.median_filter(p, size=BASELINE_BINS, mode="nearest")
    k = len(part) // nseg  # independent segments (the overlap's gain is not counted: conservative)
    bins = len(f) - FIRST_BIN - 1
    # the running median of a chi-square is below its mean by ~(1 - 2/(9 * 2k)) ... negligible for k >= 8
    threshold = max(MIN_RATIO, chi2.isf(ALPHA / bins, 2 * k) / (2 * k))
    ratio = np.where(base > 0, p / np.maximum(base, 1e-300), 0.0)
    hot = ratio > threshold
    hot[:FIRST_BIN] = False
    hot[-1] = False
    out: list[Component] = []
    i = 0
    while i < len(f):
        if not hot[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(f) and hot[j + 1]:
            j += 1
        # the component's full extent: down to twice the smooth spectrum on both sides
        lo, hi = i, j
        while lo > FIRST_BIN and ratio[lo - 1] > 2.0:
            lo -= 1
        while hi + 1 < len(f) - 1 and ratio[hi + 1] > 2.0:
            hi += 1
        peak = lo + int(np.argmax(p[lo : hi + 1]))
        band = (float(f[lo]), float(f[hi]))
        if hi - lo + 1 <= LINE_BINS:
            f0 = _refine(part, fs_hz, float(f[peak]), float(f[1] - f[0]))
            amp = _amplitude(part, fs_hz, f0)
            out.append(Component("sinusoid", f0, band, amp, float(ratio[peak]),
                                 f"a sinusoid at {f0:.4g} Hz ({ratio[peak]:.3g} x the spectrum around it) "
                                 "is not noise: removed before the noise is fitted"))  # fmt: skip
        else:
            out.append(Component("resonance", float(f[peak]), band, math.nan, float(ratio[peak]),
                                 f"a narrow-band resonance at {f[peak]:.4g} Hz ({band[0]:.3g}..{band[1]:.3g} Hz, "
                                 f"{ratio[peak]:.3g} x the spectrum around it): carried as an angle term beyond "
                                 "its correlation time"))  # fmt: skip
        i = hi + 1
    return out


def _demod(x: np.ndarray, fs_hz: float, f0: float, block: int) -> tuple[np.ndarray, np.ndarray]:
    """Complex amplitude of ``f0`` in each block of ``block`` samples, and the blocks' centre times (s)."""
    nb = len(x) // block
    t = np.arange(nb * block) / fs_hz
    z = (np.asarray(x[: nb * block], dtype=float) * np.exp(-2j * math.pi * f0 * t)).reshape(nb, block).mean(axis=1)
    return z, (np.arange(nb) + 0.5) * block / fs_hz


def _refine(x: np.ndarray, fs_hz: float, f0: float, df: float) -> float:
    """``f0`` (Hz) refined from the phase drift of block-wise demodulations: blocks short enough that a
    frequency error of one bin ``df`` turns the phase by less than a quarter turn, then ten times longer."""
    f = f0
    for length in (0.25 / df, 2.5 / df):
        block = max(int(length * fs_hz), 8)
        if len(x) < 4 * block:
            break
        z, t = _demod(x, fs_hz, f, block)
        phase = np.unwrap(np.angle(z))
        w = np.abs(z)
        slope = np.polyfit(t, phase, 1, w=w)[0]
        f += slope / (2.0 * math.pi)
    return float(f)


def _amplitude(x: np.ndarray, fs_hz: float, f0: float) -> float:
    block = _block(fs_hz, f0, len(x))
    z, _ = _demod(x, fs_hz, f0, block)
    return float(2.0 * np.median(np.abs(z)))


def _block(fs_hz: float, f0: float, n: int) -> int:
    return int(min(n, max(BLOCK_S * fs_hz, BLOCK_CYCLES * fs_hz / f0)))


def remove_sinusoids(x: np.ndarray, fs_hz: float, found: list[Component], scale: float = 1.0) -> np.ndarray:
    """``x`` (unit of the channel, or counts of ``scale`` units) in the channel's unit, float, with each
    sinusoid of ``found`` fitted by least squares in blocks (module docstring) and subtracted; a new array."""
    y = np.asarray(x, dtype=float) * scale
    n = len(y)
    for c in found:
        if c.kind != "sinusoid":
            continue
        block = _block(fs_hz, c.frequency_hz, n)
        w = 2.0 * math.pi * c.frequency_hz
        for a in range(0, n, block):
            b = min(n, a + block)
            if b - a < block // 2 and a > 0:  # a short last piece joins the block before
                a = max(0, b - block)
            t = np.arange(a, b) / fs_hz
            basis = np.column_stack([np.cos(w * t), np.sin(w * t)])
            coef, *_ = np.linalg.lstsq(basis, y[a:b], rcond=None)
            y[a:b] -= basis @ coef
    return y
