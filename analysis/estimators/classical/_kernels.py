"""Compiled (numba) inner loops of the Allan family: sums of squared differences.

Why compiled: an exact overlapping Allan variance needs one pass over all N
angle points per tau, and numpy spends 4-5 full passes (temporaries) per tau.
A fused loop reads each point once per tau and vectorises (see
``benchmarks/bench_oadev.py`` for the measured ratio against allantools).

Every kernel works on a list of contiguous segments ``[start, stop)`` of rate
samples and returns the plain sum of squares and the number of terms, so the
callers pool segments without ever differencing across a gap.

Exactness: for integer counts the angle ``x`` (cumulative sum) is held in
float64 only when every ``|x| < 2**53``; integers below that bound and their
sums/differences are exact in float64, so each difference term is the exact
integer and only the final sum of squares is rounded. Above the bound (or to
save memory) the ``*_counts`` kernels keep ``x`` as running int64 sums.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(fastmath=True, cache=True)
def _sq_d2(x, m, start, count):
    # sum_{i} (x[i+2m] - 2 x[i+m] + x[i])^2, i = start .. start+count-1 (SP 1065 eq. 11)
    a = x[start + 2 * m : start + 2 * m + count]
    b = x[start + m : start + m + count]
    c = x[start : start + count]
    acc = 0.0
    for i in range(count):
        d = a[i] - 2.0 * b[i] + c[i]
        acc += d * d
    return acc


@nb.njit(fastmath=True, cache=True)
def _sq_d3(x, m, start, count):
    # sum_{i} (x[i+3m] - 3 x[i+2m] + 3 x[i+m] - x[i])^2 (SP 1065 eq. 18)
    a = x[start + 3 * m : start + 3 * m + count]
    b = x[start + 2 * m : start + 2 * m + count]
    c = x[start + m : start + m + count]
    e = x[start : start + count]
    acc = 0.0
    for i in range(count):
        d = a[i] - 3.0 * b[i] + 3.0 * c[i] - e[i]
        acc += d * d
    return acc


#: taus with ``order*m`` up to this many points share one pass over cache-sized
#: blocks of x (all their terms for a block are summed while it sits in L2)
SMALL_SPAN = 16384
_BLOCK = 16384


@nb.njit(parallel=True, cache=True)
def _small_sums(x, ms, start, count_all, order):
    # terms i = start .. start+count_all[j]-1 for each (small) m_j, in blocks of _BLOCK
    nb_blocks = (np.max(count_all) + _BLOCK - 1) // _BLOCK
    part = np.zeros((nb_blocks, len(ms)))
    for k in nb.prange(nb_blocks):
        a = start + k * _BLOCK
        for j in range(len(ms)):
            stop = min(a + _BLOCK, start + count_all[j])
            if stop > a:
                if order == 2:
                    part[k, j] = _sq_d2(x, ms[j], a, stop - a)
                else:
                    part[k, j] = _sq_d3(x, ms[j], a, stop - a)
    return part.sum(axis=0)


@nb.njit(parallel=True, cache=True)
def _large_sums(x, ms, starts, stops, order):
    out = np.zeros(len(ms))
    cnt = np.zeros(len(ms), dtype=np.int64)
    for j in nb.prange(len(ms)):
        m = ms[j]
        acc = 0.0
        n = 0
        for k in range(len(starts)):
            count = stops[k] - starts[k] + 1 - order * m
            if count > 0:
                if order == 2:
                    acc += _sq_d2(x, m, starts[k], count)
                else:
                    acc += _sq_d3(x, m, starts[k], count)
                n += count
        out[j] = acc
        cnt[j] = n
    return out, cnt


def diff_sums(x, ms, starts, stops, order):
    """Pooled sums of squared ``order``-th differences (2: Allan, 3: Hadamard) of angle ``x``.

    ``x`` has one more point than the rate samples; segment ``[s, e)`` of rate
    samples spans angle points ``s .. e`` and contributes ``e - s + 1 - order*m``
    terms. Returns (sums, counts) per ``m``.
    """
    ms = np.asarray(ms, dtype=np.int64)
    small = order * ms <= SMALL_SPAN
    out, cnt = np.zeros(len(ms)), np.zeros(len(ms), dtype=np.int64)
    if (~small).any():
        out[~small], cnt[~small] = _large_sums(x, ms[~small], starts, stops, order)
    if small.any():
        ms_s = ms[small]
        for a, b in zip(starts, stops, strict=True):
            counts = np.maximum(b - a + 1 - order * ms_s, 0)
            if counts.max() > 0:
                out[small] += _small_sums(x, ms_s, a, counts, order)
                cnt[small] += counts
    return out, cnt


@nb.njit(cache=True)
def _sq_d2_counts(y, m, start, count):
    # running int64 angles x0 = x[i], x1 = x[i+m], x2 = x[i+2m] relative to x[start]
    x0 = np.int64(0)
    x1 = np.int64(0)
    for k in range(m):
        x1 += y[start + k]
    x2 = x1
    for k in range(m, 2 * m):
        x2 += y[start + k]
    acc = 0.0
    for i in range(count):
        fd = float(x2 - 2 * x1 + x0)
        acc += fd * fd
        if i + 1 < count:
            x0 += y[start + i]
            x1 += y[start + i + m]
            x2 += y[start + i + 2 * m]
    return acc


@nb.njit(parallel=True, cache=True)
def diff_sums_counts(y, ms, starts, stops):
    """As :func:`diff_sums` (order 2) but from integer rate counts ``y``, exact int64, O(1) extra memory."""
    out = np.zeros(len(ms))
    cnt = np.zeros(len(ms), dtype=np.int64)
    for j in nb.prange(len(ms)):
        m = ms[j]
        acc = 0.0
        n = 0
        for k in range(len(starts)):
            count = stops[k] - starts[k] + 1 - 2 * m
            if count > 0:
                acc += _sq_d2_counts(y, m, starts[k], count)
                n += count
        out[j] = acc
        cnt[j] = n
    return out, cnt


@nb.njit(cache=True)
def angle(y, offset, out):
    """``out[0] = 0``, ``out[k+1] = sum_{i<=k} (y[i] - offset)``: exact in int64 for integer ``y``."""
    acc = y[0] - y[0]  # int64 for integer input, float64 for floats
    out[0] = 0.0
    for i in range(len(y)):
        acc += y[i] - offset
        out[i + 1] = acc


@nb.njit(cache=True)
def block_sums(x, ms, starts, stops, edges):
    """Sums and counts of squared second differences of angle ``x`` per block of rate samples.

    Blocks ``[edges[b], edges[b+1])``; a term ``x[i+2m] - 2 x[i+m] + x[i]`` belongs to the block
    holding ``i`` and is counted only when it lies wholly inside that block and one segment.
    Returns (sums, counts) of shape (blocks, len(ms)).
    """
    nb_ = len(edges) - 1
    sums = np.zeros((nb_, len(ms)))
    counts = np.zeros((nb_, len(ms)), dtype=np.int64)
    for j in range(len(ms)):
        m = ms[j]
        for k in range(len(starts)):
            for b in range(nb_):
                lo = max(starts[k], edges[b])
                hi = min(stops[k], edges[b + 1])
                count = hi - lo + 1 - 2 * m
                if count <= 0:
                    continue
                acc = 0.0
                for i in range(lo, lo + count):
                    d = x[i + 2 * m] - 2.0 * x[i + m] + x[i]
                    acc += d * d
                sums[b, j] += acc
                counts[b, j] += count
    return sums, counts
