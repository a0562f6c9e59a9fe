"""Allan family of rate data: overlapping Allan, modified Allan, overlapping Hadamard, total deviation.

For rate samples ``y_k`` (rad/s, m/s^2, ...) at ``fs_hz`` the angle is
``x_k = tau0 * sum_{i<k} y_i`` (``x_0 = 0``, ``N = n + 1`` points) and, with
``tau = m tau0`` (NIST SP 1065, Riley 2008):

.. math::

    \\sigma^2_{OADEV}(\\tau) = \\frac{1}{2\\tau^2 (N-2m)} \\sum_{i=0}^{N-2m-1} (x_{i+2m} - 2x_{i+m} + x_i)^2
    \\quad\\text{(eq. 11)}

    \\mathrm{Mod}\\,\\sigma^2(\\tau) = \\frac{1}{2m^2\\tau^2 (N-3m+1)} \\sum_{j=0}^{N-3m}
        \\Big(\\sum_{i=j}^{j+m-1} x_{i+2m} - 2x_{i+m} + x_i\\Big)^2  \\quad\\text{(eq. 14)}

    \\sigma^2_{OHDEV}(\\tau) = \\frac{1}{6\\tau^2 (N-3m)} \\sum_{i=0}^{N-3m-1}
        (x_{i+3m} - 3x_{i+2m} + 3x_{i+m} - x_i)^2  \\quad\\text{(eq. 18)}

and the total variance (eq. 25) uses the series reflected about both ends.
The results equal allantools' ``oadev``, ``mdev``, ``ohdev``, ``totdev`` with
``data_type="freq"`` at the same taus (checked in the tests to 1e-9).

Integer counts are integrated exactly (see :mod:`imustation.analysis.estimators.classical._kernels`);
``segments`` (contiguous sample ranges, e.g. ``Channel.segments``) are pooled:
only difference terms lying wholly inside one segment are summed, and the
variance divides by the total number of such terms - never across a gap.

Confidence intervals: equivalent degrees of freedom from NIST SP 1065 Table 5
(OADEV) and the TOTVAR formula (SP 1065 sec. 5.2.11), for the power-law noise
type identified at each tau by the lag-1 autocorrelation method (Riley and
Greenhall 2004; SP 1065 sec. 5.6); chi-square bounds at 68.3 %.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from imustation.analysis.estimators.classical import _kernels
from imustation.errors import InputError

#: probability mass inside [adev_lo, adev_hi] (one sigma of a normal)
CONFIDENCE = 0.683
#: default memory allowed for the float64 angle array; beyond it integer
#: counts are processed from the counts themselves (running int64 sums)
MAX_ANGLE_BYTES = 512 * 2**20
#: float64 holds every integer below this exactly
_EXACT_INT = 2.0**53
#: noise identification needs at least this many tau-averages (Riley & Greenhall 2004)
_NOISE_ID_MIN_POINTS = 30
#: ... and uses at most this many (enough for a stable lag-1 autocorrelation)
_NOISE_ID_MAX_POINTS = 1000
KINDS = ("oadev", "mdev", "ohdev", "totdev")


@dataclass(frozen=True)
class AllanResult:
    """A deviation at cluster times ``tau`` (s); same units as the rate.

    ``adev_lo``/``adev_hi`` bound a 68.3 % chi-square interval from the
    equivalent degrees of freedom ``edf`` (NaN where no EDF formula is
    implemented); ``n`` is the number of difference terms averaged at each
    tau; ``alpha`` the identified power-law noise exponent of the rate
    (0 white rate noise, -1 flicker, -2 rate random walk, +1/+2 "phase"
    noises such as quantisation); ``kind`` the statistic (``oadev``, ...).
    """

    tau: np.ndarray
    adev: np.ndarray
    adev_lo: np.ndarray
    adev_hi: np.ndarray
    edf: np.ndarray
    n: np.ndarray
    alpha: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    kind: str = "oadev"


def log_taus(n: int, fs_hz: float, per_decade: int = 10, order: int = 2) -> np.ndarray:
    """Log-spaced cluster times (s) with distinct integer ``m`` up to ``(n-1)//order``."""
    m_max = max(1, (n - 1) // order)
    k = int(per_decade * np.log10(m_max)) + 1 if m_max > 1 else 1
    m = np.unique(np.round(np.logspace(0, np.log10(m_max), k)))
    return m.astype(np.int64) / fs_hz


# ---------------------------------------------------------------------------
# input handling


@dataclass
class _Series:
    """Rate data prepared for the kernels (x in counts*samples or unit*samples: tau0 applied later)."""

    n: int  # rate samples
    fs_hz: float
    scale: float  # units per count (1 for floats)
    x: np.ndarray | None  # float64 angle, N = n+1 points, in units of the input * samples
    y: np.ndarray | None  # integer counts (when x is not held)
    starts: np.ndarray
    stops: np.ndarray
    alpha_cache: np.ndarray | None = None  # noise exponents of the selected taus

    @property
    def longest(self) -> tuple[int, int]:
        k = int(np.argmax(self.stops - self.starts))
        return int(self.starts[k]), int(self.stops[k])


def _check_segments(segments: Sequence[tuple[int, int]] | None, n: int) -> tuple[np.ndarray, np.ndarray]:
    if segments is None:
        return np.array([0], dtype=np.int64), np.array([n], dtype=np.int64)
    seg = np.asarray(list(segments), dtype=np.int64).reshape(-1, 2)
    if len(seg) == 0:
        raise InputError("segments is empty: give at least one (start, stop) sample range")
    if np.any(seg[:, 0] < 0) or np.any(seg[:, 1] > n) or np.any(seg[:, 1] <= seg[:, 0]):
        raise InputError(f"segments {seg.tolist()} must be increasing ranges (start, stop) within 0..{n}")
    if np.any(seg[1:, 0] < seg[:-1, 1]):
        raise InputError(f"segments {seg.tolist()} overlap or are not sorted")
    return seg[:, 0].copy(), seg[:, 1].copy()


def _prepare(
    data: np.ndarray,
    fs_hz: float,
    scale: float,
    data_type: str,
    segments: Sequence[tuple[int, int]] | None,
    max_bytes: int | None,
    need_x: bool,
) -> _Series:
    data = np.asarray(data)
    if data.ndim != 1:
        raise InputError(f"data must be one-dimensional, got shape {data.shape}")
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise InputError(f"fs_hz = {fs_hz}: must be a positive sampling rate")
    if data.dtype.kind not in "iuf":
        raise InputError(f"data has dtype {data.dtype}, expected numbers")
    if data.dtype.kind == "f" and not np.all(np.isfinite(data)):
        raise InputError("data holds NaN or infinite values")
    if data_type not in ("rate", "angle"):
        raise InputError(f"data_type {data_type!r}: use 'rate' or 'angle'")
    n = len(data) - 1 if data_type == "angle" else len(data)
    if n < 3:
        raise InputError(f"{n} rate samples: an Allan deviation needs at least 3")
    starts, stops = _check_segments(segments, n)
    if data_type == "angle":
        # angle in (unit)*s: back to units*samples so that x has the same scale as a rate cumsum
        x = data.astype(np.float64) * (scale * fs_hz)
        return _Series(n, fs_hz, 1.0, x, None, starts, stops)
    integer = data.dtype.kind in "iu"
    limit = MAX_ANGLE_BYTES if max_bytes is None else max_bytes
    if integer:
        bound = float(n) * max(abs(int(data.max())), abs(int(data.min())))
        fits = (n + 1) * 8 <= limit or need_x
        if bound < _EXACT_INT and fits:
            x = np.empty(n + 1)
            _kernels.angle(data, 0, x)  # int64 partial sums, below 2**53 so exact in float64
            return _Series(n, fs_hz, float(scale), x, None, starts, stops)
        if need_x:
            raise InputError(f"counts too large for an exact float64 angle (n*max|y| = {bound:.3g} >= 2**53)")
        return _Series(n, fs_hz, float(scale), None, np.ascontiguousarray(data), starts, stops)
    x = np.empty(n + 1)
    # remove the mean first (as allantools does): smaller partial sums, smaller rounding
    _kernels.angle(data.astype(np.float64, copy=False), float(data.mean()), x)
    return _Series(n, fs_hz, float(scale), x, None, starts, stops)


def _select_m(taus: np.ndarray | Sequence[float] | None, s: _Series, order: int, min_terms: int) -> np.ndarray:
    """Integer averaging factors for ``taus``: rounded, unique, with at least ``min_terms`` terms."""
    longest = int(np.max(s.stops - s.starts))
    if taus is None:
        tau_s = log_taus(longest, s.fs_hz, order=order)
    else:
        tau_s = np.atleast_1d(np.asarray(taus, dtype=float))
        if not np.all(np.isfinite(tau_s)):
            raise InputError(f"taus {tau_s.tolist()} must be finite seconds")
    m = np.unique(np.round(tau_s * s.fs_hz).astype(np.int64))
    m = m[(m >= 1) & (longest + 1 - order * m >= min_terms)]
    if len(m) == 0:
        raise InputError(f"no requested tau fits the record (need {order}*tau shorter than the longest segment)")
    return m


# ---------------------------------------------------------------------------
# noise identification and EDF


def _lag1_noise_alpha(z: np.ndarray, dmax: int = 2) -> int:
    """Power-law exponent of a frequency-like series ``z`` (Riley & Greenhall 2004, lag-1 ACF).

    White rate (FM) noise gives 0, flicker -1, random walk -2; +2/+1 are white/flicker
    "phase" noise (e.g. quantisation of the angle).
    """
    t = np.arange(len(z), dtype=float)
    z = z - np.polyval(np.polyfit(t, z, 1), t)  # remove the linear drift (SP 1065 sec. 5.6)
    d = 0
    while True:
        zc = z - z.mean()
        den = float(np.dot(zc, zc))
        r1 = float(np.dot(zc[:-1], zc[1:])) / den if den > 0 else 0.0
        rho = r1 / (1.0 + r1)
        if rho < 0.25 or d >= dmax:
            return int(np.clip(np.round(-2.0 * (rho + d)), -2, 2))
        z = np.diff(z)
        d += 1


def _noise_alphas(s: _Series, m: np.ndarray) -> np.ndarray:
    """Noise exponent at each ``m``, from tau-averages of the longest segment.

    Uses at most ``_NOISE_ID_MAX_POINTS`` averages (from the segment start);
    where fewer than ``_NOISE_ID_MIN_POINTS`` exist the exponent of the next
    shorter tau is carried over (0, white, if there is none).
    """
    a, b = s.longest
    if s.x is not None:
        x = s.x
    else:  # counts: angle of the segment prefix that the largest needed window covers
        x = None
    alphas = np.zeros(len(m), dtype=int)
    last = 0
    for j, mj in enumerate(m):
        k = min((b - a) // int(mj), _NOISE_ID_MAX_POINTS)
        if k < _NOISE_ID_MIN_POINTS:
            alphas[j] = last
            continue
        stop = a + k * int(mj)
        if x is not None:
            xs = x[a : stop + 1 : int(mj)]
        else:
            part = s.y[a:stop].reshape(k, int(mj)).sum(axis=1, dtype=np.int64)
            xs = np.concatenate([[0], np.cumsum(part)]).astype(float)
        last = alphas[j] = _lag1_noise_alpha(np.diff(xs))
    return alphas


def edf_oadev(n_x: float, m: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """EDF of the overlapping AVAR, NIST SP 1065 Table 5 ("simple" formulas).

    ``n_x`` phase (angle) points, ``m`` averaging factors, ``alpha`` noise exponents.
    """
    N = float(n_x)
    m = np.asarray(m, dtype=float)
    out = np.empty(len(m))
    for j, (mj, a) in enumerate(zip(m, alpha, strict=True)):
        if a == 2:  # white PM
            e = (N + 1) * (N - 2 * mj) / (2 * (N - mj))
        elif a == 1:  # flicker PM
            e = np.exp(np.sqrt(np.log((N - 1) / (2 * mj)) * np.log((2 * mj + 1) * (N - 1) / 4)))
        elif a == 0:  # white FM
            e = (3 * (N - 1) / (2 * mj) - 2 * (N - 2) / N) * 4 * mj**2 / (4 * mj**2 + 5)
        elif a == -1:  # flicker FM
            e = 2 * (N - 2) ** 2 / (2.3 * N - 4.9) if mj == 1 else 5 * N**2 / (4 * mj * (N + 3 * mj))
        else:  # random walk FM
            e = (N - 2) / (mj * (N - 3) ** 2) * ((N - 1) ** 2 - 3 * mj * (N - 1) + 4 * mj**2)
        out[j] = e
    return out


#: TOTVAR EDF = b * T/tau - c (NIST SP 1065 sec. 5.2.11, Table 11), per noise exponent
_TOTVAR_BC = {0: (1.50, 0.0), -1: (1.17, 0.22), -2: (0.93, 0.36)}


def edf_totdev(n_x: float, m: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """EDF of the total variance; NaN for the "phase" noises (alpha > 0), which SP 1065 does not tabulate."""
    T_over_tau = (float(n_x) - 1.0) / np.asarray(m, dtype=float)
    out = np.full(len(T_over_tau), np.nan)
    for j, a in enumerate(alpha):
        if int(a) in _TOTVAR_BC:
            b, c = _TOTVAR_BC[int(a)]
            out[j] = b * T_over_tau[j] - c
    return out


def chi2_bounds(dev: np.ndarray, edf: np.ndarray, confidence: float = CONFIDENCE) -> tuple[np.ndarray, np.ndarray]:
    """Chi-square interval of a deviation with ``edf`` degrees of freedom (SP 1065 eq. 40)."""
    edf = np.asarray(edf, dtype=float)
    ok = np.isfinite(edf) & (edf > 0)
    e = np.where(ok, np.maximum(edf, 1e-3), 1.0)
    p = 1.0 - confidence
    lo = np.where(ok, dev * np.sqrt(e / chi2.ppf(1 - p / 2, e)), np.nan)
    hi = np.where(ok, dev * np.sqrt(e / chi2.ppf(p / 2, e)), np.nan)
    return lo, hi


def _pooled_edf(s: _Series, m: np.ndarray, alpha: np.ndarray, order: int, fn) -> np.ndarray:
    """Sum of per-segment EDFs (independent segments' estimates pooled)."""
    total = np.zeros(len(m))
    for a, b in zip(s.starts, s.stops, strict=True):
        n_x = b - a + 1
        ok = n_x - order * m >= 1
        if ok.any():
            e = np.zeros(len(m))
            e[ok] = fn(n_x, m[ok], alpha[ok])
            total += np.where(ok, e, 0.0)
    return np.maximum(total, 1.0)


def _result(s: _Series, m, var_sum, counts, norm, kind, edf) -> AllanResult:
    tau = m / s.fs_hz
    # var = sum * (scale*tau0)^2 / (norm * tau^2 * count) = sum * scale^2 / (norm * m^2 * count)
    var = var_sum * s.scale**2 / (norm * m.astype(float) ** 2 * counts)
    dev = np.sqrt(var)
    lo, hi = chi2_bounds(dev, edf)
    return AllanResult(tau, dev, lo, hi, edf, counts, s.alpha_cache, kind)


# ---------------------------------------------------------------------------
# public estimators


def oadev(
    rate: np.ndarray,
    fs_hz: float,
    taus: np.ndarray | Sequence[float] | None = None,
    *,
    scale: float = 1.0,
    data_type: str = "rate",
    segments: Sequence[tuple[int, int]] | None = None,
    max_bytes: int | None = None,
) -> AllanResult:
    """Overlapping Allan deviation (NIST SP 1065 eq. 11).

    Parameters
    ----------
    rate : (n,) rate samples (rad/s, m/s^2, ...) or integer counts with ``scale``;
        with ``data_type="angle"`` the (n+1,) angle ``x`` in (unit)*s instead.
    fs_hz : sampling rate, Hz.
    taus : cluster times, s; rounded to whole samples; default :func:`log_taus`.
    scale : units per count when ``rate`` holds integer counts.
    segments : contiguous ranges ``(start, stop)`` of rate samples (default: the
        whole record); terms never span two segments.
    max_bytes : memory allowed for the float64 angle (default ``MAX_ANGLE_BYTES``);
        larger integer records are summed from the counts (same result).

    Returns
    -------
    AllanResult with ``tau`` (s), ``adev`` (rate units) and its 68.3 % interval.
    """
    s = _prepare(rate, fs_hz, scale, data_type, segments, max_bytes, need_x=False)
    m = _select_m(taus, s, 2, 2)
    if s.x is not None:
        sums, counts = _kernels.diff_sums(s.x, m, s.starts, s.stops, 2)
    else:
        sums, counts = _kernels.diff_sums_counts(s.y, m, s.starts, s.stops)
    s.alpha_cache = _noise_alphas(s, m)
    edf = _pooled_edf(s, m, s.alpha_cache, 2, edf_oadev)
    return _result(s, m, sums, counts, 2.0, "oadev", edf)


def block_oavar(
    rate: np.ndarray,
    fs_hz: float,
    m: Sequence[int],
    blocks: int,
    *,
    scale: float = 1.0,
    segments: Sequence[tuple[int, int]] | None = None,
) -> np.ndarray:
    """Overlapping Allan variances at cluster sizes ``m`` (samples) in each of ``blocks`` equal
    consecutive blocks of the record, (blocks, len(m)); one preparation of the angle for all.

    ``rate`` (n,) rate samples or integer counts with ``scale``; terms never span a gap or a
    block edge; NaN where a block holds no term.
    """
    s = _prepare(rate, fs_hz, scale, "rate", segments, None, need_x=False)
    ms = np.asarray(m, dtype=np.int64)
    edges = np.linspace(0, s.n, blocks + 1).astype(np.int64)
    if s.x is not None:
        sums, counts = _kernels.block_sums(s.x, ms, s.starts, s.stops, edges)
    else:  # counts too large for a float angle: one pooled call per block
        sums = np.zeros((blocks, len(ms)))
        counts = np.zeros((blocks, len(ms)), dtype=np.int64)
        for j in range(blocks):
            starts, stops = np.maximum(s.starts, edges[j]), np.minimum(s.stops, edges[j + 1])
            keep = stops > starts
            if keep.any():
                sums[j], counts[j] = _kernels.diff_sums_counts(s.y, ms, starts[keep], stops[keep])
    with np.errstate(all="ignore"):
        return np.where(counts > 0, sums * s.scale**2 / (2.0 * ms.astype(float) ** 2 * counts), np.nan)


def ohdev(
    rate: np.ndarray,
    fs_hz: float,
    taus: np.ndarray | Sequence[float] | None = None,
    *,
    scale: float = 1.0,
    data_type: str = "rate",
    segments: Sequence[tuple[int, int]] | None = None,
) -> AllanResult:
    """Overlapping Hadamard deviation (NIST SP 1065 eq. 18); insensitive to a rate ramp.

    Parameters as :func:`oadev`. No EDF formula is implemented (intervals NaN).
    """
    s = _prepare(rate, fs_hz, scale, data_type, segments, None, need_x=True)
    m = _select_m(taus, s, 3, 2)
    sums, counts = _kernels.diff_sums(s.x, m, s.starts, s.stops, 3)
    s.alpha_cache = _noise_alphas(s, m)
    return _result(s, m, sums, counts, 6.0, "ohdev", np.full(len(m), np.nan))


def mdev(
    rate: np.ndarray,
    fs_hz: float,
    taus: np.ndarray | Sequence[float] | None = None,
    *,
    scale: float = 1.0,
    data_type: str = "rate",
    segments: Sequence[tuple[int, int]] | None = None,
) -> AllanResult:
    """Modified Allan deviation (NIST SP 1065 eq. 14); separates white from flicker angle noise.

    Parameters as :func:`oadev`. No EDF formula is implemented (intervals NaN).
    """
    s = _prepare(rate, fs_hz, scale, data_type, segments, None, need_x=True)
    m = _select_m(taus, s, 3, 2)
    sums = np.zeros(len(m))
    counts = np.zeros(len(m), dtype=np.int64)
    for a, b in zip(s.starts, s.stops, strict=True):
        x = s.x[a : b + 1]
        for j, mj in enumerate(m):
            k = len(x) - 3 * mj + 1  # number of inner sums
            if k < 1:
                continue
            d = x[2 * mj :] - 2.0 * x[mj:-mj] + x[: -2 * mj]
            c = np.empty(len(d) + 1)
            c[0] = 0.0
            np.cumsum(d, out=c[1:])
            inner = c[mj : mj + k] - c[:k]  # sum of m consecutive second differences
            sums[j] += np.dot(inner, inner)
            counts[j] += k
    keep = counts >= 2
    m, sums, counts = m[keep], sums[keep], counts[keep]
    s.alpha_cache = _noise_alphas(s, m)
    # Mod var = sum / (2 m^2 tau^2 count): one more m^2 than the OADEV normalisation
    res = _result(s, m, sums / m.astype(float) ** 2, counts, 2.0, "mdev", np.full(len(m), np.nan))
    return res


def totdev(
    rate: np.ndarray,
    fs_hz: float,
    taus: np.ndarray | Sequence[float] | None = None,
    *,
    scale: float = 1.0,
    data_type: str = "rate",
    segments: Sequence[tuple[int, int]] | None = None,
) -> AllanResult:
    """Total deviation (NIST SP 1065 eq. 25): the angle reflected about both ends extends the record.

    Parameters as :func:`oadev`; intervals from the TOTVAR EDF (SP 1065 sec. 5.2.11).
    """
    s = _prepare(rate, fs_hz, scale, data_type, segments, None, need_x=True)
    longest = int(np.max(s.stops - s.starts)) + 1
    m = _select_m(taus, s, 2, 1)
    m = m[m <= longest - 2]
    sums = np.zeros(len(m))
    counts = np.zeros(len(m), dtype=np.int64)
    for a, b in zip(s.starts, s.stops, strict=True):
        x = s.x[a : b + 1]
        N = len(x)
        if N < 3:
            continue
        # x*_{1-j} = 2x_1 - x_{1+j}, x*_{N+j} = 2x_N - x_{N-j}, j = 1..N-2 (SP 1065 eq. 25)
        ext = np.concatenate([(2.0 * x[0] - x[1:-1])[::-1], x, 2.0 * x[-1] - x[1:-1][::-1]])
        mid = N - 2
        for j, mj in enumerate(m):
            if mj > N - 2:
                continue
            i = np.arange(mid + 1, mid + N - 1)  # the interior points x_2..x_{N-1}
            d = ext[i - mj] - 2.0 * ext[i] + ext[i + mj]
            sums[j] += np.dot(d, d)
            counts[j] += N - 2
    s.alpha_cache = _noise_alphas(s, m)
    edf = _pooled_edf(s, m, s.alpha_cache, 1, edf_totdev)
    return _result(s, m, sums, counts, 2.0, "totdev", edf)


ESTIMATORS = {"oadev": oadev, "mdev": mdev, "ohdev": ohdev, "totdev": totdev}
