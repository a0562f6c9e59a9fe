"""Power spectral density of rate data: Welch's method and log-frequency averaging.

Units: if the rate is in rad/s and ``fs_hz`` in Hz, the PSD is in (rad/s)^2/Hz.

One-sided vs two-sided (the factor-2 pitfall, docs/reference/noise-formulas.md §5): the
**one-sided** PSD ``G(f)``, ``0 <= f <= fs/2``, integrates over positive
frequencies to the variance (``scipy.signal.welch`` default); the
**two-sided** PSD ``S(f) = G(f)/2`` for ``f > 0`` (``S(-f) = S(f)``) integrates
over ``-fs/2..fs/2`` to the variance. IEEE Std 952 writes its noise terms with
the two-sided ``S``: white rate noise of ARW coefficient ``N`` has ``S = N^2``,
``G = 2 N^2`` (so ``N = sqrt(G/2)``, Zhao et al. eq. 24).

Log-frequency averaging ("frequency averaging", IEEE Std 1293; Zhao et al. 2011
sec. 3): the Welch bins are averaged in log-spaced frequency bands so that a
long record's high-frequency scatter does not hide the slopes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.signal import welch

from imustation.errors import InputError

#: default Welch window length: the largest power of two giving at least this many windows
MIN_WINDOWS = 8
#: ... and never longer than this (memory of the FFT buffers)
MAX_NPERSEG = 1 << 20
SIDES = ("one", "two")


@dataclass(frozen=True)
class PSDResult:
    """PSD ``psd`` ((unit)^2/Hz) at frequencies ``f`` (Hz).

    ``sides`` is ``"one"`` (G(f), f in [0, fs/2]) or ``"two"`` (S(f) = G/2 at
    f >= 0, mirror at -f); ``nperseg`` the Welch window length (samples),
    ``windows`` how many windows were averaged, ``bins`` how many Welch bins
    each point averages (1 without log averaging).
    """

    f: np.ndarray
    psd: np.ndarray
    sides: str
    nperseg: int
    windows: int
    bins: np.ndarray


def default_nperseg(n: int) -> int:
    """Largest power of two <= n / MIN_WINDOWS (at least 16 samples, at most MAX_NPERSEG)."""
    k = max(4, int(np.floor(np.log2(max(n // MIN_WINDOWS, 16)))))
    return int(min(1 << k, MAX_NPERSEG, n))


def welch_psd(
    rate: np.ndarray,
    fs_hz: float,
    *,
    scale: float = 1.0,
    nperseg: int | None = None,
    sides: str = "one",
    window: str = "hann",
    segments: Sequence[tuple[int, int]] | None = None,
    block_windows: int = 64,
) -> PSDResult:
    """Welch PSD (50 % overlap, mean removed per window) of rate samples.

    Parameters
    ----------
    rate : (n,) rate samples in (unit), or integer counts with ``scale`` (unit per count).
    fs_hz : sampling rate, Hz.
    nperseg : window length in samples; default :func:`default_nperseg` of the longest segment.
    sides : ``"one"`` for G(f) or ``"two"`` for S(f) = G(f)/2 (see module docstring).
    window : any ``scipy.signal.get_window`` name.
    segments : contiguous ``(start, stop)`` sample ranges; windows never straddle
        a gap; the periodograms of all segments are averaged with equal weight per window.
    block_windows : windows converted to float per step (memory: about
        ``block_windows * nperseg / 2`` float64), so long integer records are
        never converted whole.

    Returns
    -------
    PSDResult in (unit)^2/Hz.
    """
    rate = np.asarray(rate)
    if rate.ndim != 1 or rate.dtype.kind not in "iuf":
        raise InputError(f"rate must be a one-dimensional numeric array, got {rate.dtype} {rate.shape}")
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise InputError(f"fs_hz = {fs_hz}: must be a positive sampling rate")
    if sides not in SIDES:
        raise InputError(f"sides {sides!r}: use 'one' or 'two'")
    n = len(rate)
    segs = [(0, n)] if segments is None else [(int(a), int(b)) for a, b in segments]
    longest = max(b - a for a, b in segs)
    nps = default_nperseg(longest) if nperseg is None else int(nperseg)
    if nps < 2 or nps > longest:
        raise InputError(f"nperseg {nps}: must be between 2 and the longest segment ({longest} samples)")
    step = nps // 2
    total = None
    windows = 0
    for a, b in segs:
        k_all = (b - a - nps) // step + 1 if b - a >= nps else 0
        for k0 in range(0, k_all, block_windows):
            k = min(block_windows, k_all - k0)
            lo = a + k0 * step
            hi = lo + (k - 1) * step + nps
            chunk = rate[lo:hi].astype(np.float64) * scale
            # scipy's Welch over exactly these k windows; its mean times k is their sum
            f, p = welch(chunk, fs=fs_hz, window=window, nperseg=nps, noverlap=nps - step, detrend="constant")
            total = p * k if total is None else total + p * k
            windows += k
    if windows == 0:
        raise InputError(f"no segment holds a full window of {nps} samples")
    G = total / windows
    if sides == "two":
        S = G / 2.0
        # scipy does not double DC (nor Nyquist for even nperseg): those bins are already two-sided
        S[0] = G[0]
        if nps % 2 == 0:
            S[-1] = G[-1]
        G = S
    return PSDResult(f, G, sides, nps, windows, np.ones(len(f), dtype=np.int64))


def log_average(res: PSDResult, per_decade: int = 20) -> PSDResult:
    """Average the PSD in log-spaced frequency bands (IEEE Std 1293 frequency averaging).

    The DC bin is dropped; each band's point sits at the mean frequency of its
    bins and holds their mean PSD; empty bands are skipped. ``bins`` counts the
    Welch bins in each point (the PSD scatter shrinks as 1/sqrt(bins)).
    """
    f, p = res.f[1:], res.psd[1:]
    if len(f) == 0:
        raise InputError("PSD has no positive frequencies to average")
    n_bands = max(1, int(np.ceil(per_decade * np.log10(f[-1] / f[0]))))
    edges = np.logspace(np.log10(f[0]), np.log10(f[-1]), n_bands + 1)
    idx = np.clip(np.searchsorted(edges, f, side="right") - 1, 0, n_bands - 1)  # end bins into the end bands
    counts = np.bincount(idx, minlength=n_bands)
    keep = counts > 0
    fm = np.bincount(idx, weights=f, minlength=n_bands)[keep] / counts[keep]
    pm = np.bincount(idx, weights=p, minlength=n_bands)[keep] / counts[keep]
    return PSDResult(fm, pm, res.sides, res.nperseg, res.windows, counts[keep].astype(np.int64))
