"""The integrated signal on a sampling pattern: what ML_i-type likelihoods see of a record.

The rate is integrated once (Nikolic et al. 2016, eq. 20; exactly in int64 for raw
counts) onto pattern points ``0 = k_0 < k_1 < ... < k_M = n`` -- log-spaced (the
paper's, m = 1000 by default) or uniform -- per contiguous segment of a record with
gaps. :class:`Increments` holds the result; :func:`pattern_avar` a rough Allan
variance of it for start points; :func:`check_rate` validates the rate arrays the
estimators accept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imustation.analysis.estimators.engine.kalman import Layout
from imustation.errors import InputError, RecordTooShort


def sampling_pattern(n: int, m: int = 1000, kind: str = "log") -> np.ndarray:
    """Pattern points as angle indices ``0 = k_0 < k_1 < ... < k_M = n``.

    ``log``: geometric spacing of the points from 1 to n, forced strictly
    increasing (the first steps are single samples), so ``M = min(m, n)``.
    ``uniform``: equal steps.
    """
    if n < 2:
        raise RecordTooShort(f"{n} samples: ML_i needs a longer record")
    m = int(min(m, n))
    if kind == "log":
        k = np.floor(np.geomspace(1.0, float(n), m)).astype(np.int64)
        i = np.arange(m, dtype=np.int64)
        # strictly increasing (steps >= 1); the last point stays n because n >= m
        k = np.maximum.accumulate(k - i) + i
    elif kind == "uniform":
        k = np.round(np.linspace(0, n, m + 1)[1:]).astype(np.int64)
    else:
        raise InputError(f"pattern {kind!r}: use 'log' or 'uniform'")
    k[-1] = n
    return np.concatenate([[0], k])


#: intervals at least this long are summed with np.sum (pairwise, vectorised);
#: shorter ones with one np.add.reduceat (a scalar loop, slow for long runs)
_LONG_INTERVAL = 8192


def interval_sums(rate: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Sums of ``rate`` between consecutive ``points`` (strictly increasing indices).

    Integer counts are summed exactly in int64, floats in float64.
    """
    acc = np.int64 if rate.dtype.kind in "iu" else np.float64
    lens = np.diff(points)
    out = np.empty(len(lens), dtype=acc)
    short = np.flatnonzero(lens < _LONG_INTERVAL)
    if len(short):
        last = int(short[-1]) + 1  # reduceat up to the last short interval, long ones are redone below
        out[:last] = np.add.reduceat(rate[: points[last]], points[:last], dtype=acc)
    for i in np.flatnonzero(lens >= _LONG_INTERVAL):
        out[i] = np.sum(rate[points[i] : points[i + 1]], dtype=acc)
    return out


def integrate_pattern(rate: np.ndarray, fs_hz: float, points: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Angle increments between consecutive ``points`` (eq. 20), in rate-units x s.

    Integer counts are summed exactly in int64 before scaling.
    """
    return interval_sums(rate, points).astype(np.float64) * (scale / fs_hz)


@dataclass(frozen=True)
class Increments:
    """The integrated record on its sampling pattern: what every ML_i fit works on.

    ``y`` angle increments (unit x s) over intervals ``dt`` (s); ``new_segment``
    marks intervals that open a segment, ``gap`` the unobserved time before them (s).
    """

    y: np.ndarray
    dt: np.ndarray
    new_segment: np.ndarray
    gap: np.ndarray
    n: int
    fs_hz: float
    pattern: str
    m: int

    @property
    def duration(self) -> float:
        return float(self.dt.sum() + self.gap.sum())

    def layout(self) -> Layout:
        return Layout.from_increments(self.y, self.dt, self.new_segment, self.gap)


def check_segments(segments: list[tuple[int, int]] | None, n: int) -> list[tuple[int, int]]:
    """Validated, sorted contiguous sample ranges ``[start, end)``; ``None`` -> the whole record."""
    if segments is None:
        return [(0, n)]
    out = sorted((int(a), int(b)) for a, b in segments)
    if not out:
        raise InputError("segments: empty list; give at least one (start, end) range")
    prev = 0
    for a, b in out:
        if not (0 <= a < b <= n) or a < prev:
            raise InputError(f"segment ({a}, {b}): ranges must satisfy 0 <= start < end <= {n} and not overlap")
        prev = b
    return out


def integrate(
    rate: np.ndarray,
    fs_hz: float,
    *,
    m: int = 1000,
    pattern: str = "log",
    scale: float = 1.0,
    segments: list[tuple[int, int]] | None = None,
) -> Increments:
    """One integration pass (eq. 20) onto the sampling pattern of every segment.

    ``rate`` (n,) in rad/s (or m/s^2), or integer counts times ``scale``;
    ``fs_hz`` Hz. With segments, the m pattern intervals are shared out in
    proportion to log(length) (``log``) or length (``uniform``), at least 2 each.
    """
    n = len(rate)
    segs = check_segments(segments, n)
    lens = np.array([b - a for a, b in segs], dtype=float)
    if len(segs) == 1:
        ms = [m]
    else:
        w = np.log(lens + 1.0) if pattern == "log" else lens
        ms = [int(max(2, round(m * wi / w.sum()))) for wi in w]
    ys: list[np.ndarray] = []
    new_seg: list[np.ndarray] = []
    gaps: list[np.ndarray] = []
    dts: list[np.ndarray] = []
    prev_end = segs[0][0]
    for (a, b), mj in zip(segs, ms, strict=True):
        pts = sampling_pattern(b - a, mj, pattern) + a
        k = len(pts) - 1
        ys.append(interval_sums(rate, pts).astype(np.float64) * (scale / fs_hz))
        flags = np.zeros(k, dtype=bool)
        flags[0] = True
        new_seg.append(flags)
        g = np.zeros(k)
        g[0] = (a - prev_end) / fs_hz
        gaps.append(g)
        dts.append(np.diff(pts) / fs_hz)
        prev_end = b
    return Increments(
        np.concatenate(ys),
        np.concatenate(dts),
        np.concatenate(new_seg),
        np.concatenate(gaps),
        n,
        float(fs_hz),
        pattern,
        int(m),
    )


def pattern_avar(inc: Increments, per_decade: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rough Allan variance from the pattern increments alone (for start points).

    Blocks of 2^k consecutive increments (within a segment) whose neighbour has
    nearly the same length (ratio <= 1.25) give one Allan sample each,
    ``(mean rate difference)^2 / 2`` at tau = their mean length; samples are
    averaged in log-tau bins. Returns ``tau`` (s), ``avar``, sample ``count``.
    """
    taus, vals = [], []
    seg_id = np.cumsum(inc.new_segment) - 1
    for s in range(int(seg_id[-1]) + 1):
        idx = np.flatnonzero(seg_id == s)
        y, dt = inc.y[idx], inc.dt[idx]
        k = 1
        while 2 * k <= len(y):
            nb = len(y) // k
            ys = y[: nb * k].reshape(nb, k).sum(axis=1)
            ds = dt[: nb * k].reshape(nb, k).sum(axis=1)
            ratio = ds[1:] / ds[:-1]
            ok = (ratio < 1.25) & (ratio > 0.8)
            d = ys[1:] / ds[1:] - ys[:-1] / ds[:-1]
            taus.append(0.5 * (ds[1:] + ds[:-1])[ok])
            vals.append(0.5 * d[ok] ** 2)
            k *= 2
    tau = np.concatenate(taus)
    val = np.concatenate(vals)
    if len(tau) == 0:
        raise RecordTooShort("record too short for an Allan-variance start point")
    edges = np.floor(np.log10(tau) * per_decade).astype(int)
    bins, inv, count = np.unique(edges, return_inverse=True, return_counts=True)
    avar = np.bincount(inv, weights=val) / count
    tau_b = np.exp(np.bincount(inv, weights=np.log(tau)) / count)
    return tau_b, avar, count


def check_rate(rate: np.ndarray, fs_hz: float) -> np.ndarray:
    """``rate`` as an array after checking it is one-dimensional and finite and ``fs_hz`` (Hz) positive."""
    rate = np.asarray(rate)
    if rate.ndim != 1:
        raise InputError(f"rate must be one-dimensional, got shape {rate.shape}")
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise InputError(f"fs_hz = {fs_hz}: must be a positive sampling rate")
    if rate.dtype.kind == "f" and not np.all(np.isfinite(rate)):
        raise InputError("rate holds NaN or infinite values")
    return rate
