"""The fine-scale statistics of ML_i-F: Allan variances of every sample where the noise is white.

:func:`fine_scale` gives the overlapping Allan variance ``D`` at one cluster size
(the sample scale, or with ``samples="auto"`` the first size at which ``tau AVAR``
equals ``4 tau AVAR(4 tau)``), the statistic of the paper's standard model in
:mod:`.composite`.

:func:`fine_statistics` is the device-filter-aware version the model family uses.
A low-pass filter with unit DC gain (and white angle noise) changes the Allan
variance of white rate noise at cluster times beyond the filter's memory by one
term: ``tau AVAR(tau) = sigma_w^2 (1 - 1.5 tau_lp / tau)`` (:mod:`.sensor_terms`),
so ``u(tau) = tau AVAR(tau)`` is linear in ``1/tau`` there. The test takes the
smallest cluster size n (a power of two) at which the Allan variances at n, 2n,
4n, 8n, 16n follow ``a/tau - b/tau^2 + c + d tau`` within :data:`LINEAR_Z` (a
one-degree-of-freedom GLS residual): white noise, the angle term, and the slow
terms as they look at the fine scales (a bias-instability floor ``c``, a random
walk or a Gauss-Markov term rising as ``d tau``; a large bias instability lifts
``tau AVAR`` already at 0.1 s on the MPU-9150). There the noise is white up to the
angle term; with a filter the statistic then starts one octave further on
(margin against the filter's remaining shape). When the floor or the rising term
differ from 0 there (:data:`SLOW_Z`), the statistic keeps the five octaves and the
fit leaves those two shapes free: the model's own slow terms then do not steer
``sigma_w`` (a bias instability that stops short of the fine scales, as in the
simulators of issue 21, biased it by 4-6 % on an MPU-9150 whose floor meets the
white noise at 0.1 s); otherwise the finest one or two scales. The fitted ``b = 1.5 a tau_lp`` gives ``tau_lp``
(positive: a filter; negative: white angle noise); when it differs from 0 by more
than :data:`ANGLE_Z` standard errors the fit
carries the angle term and the statistic is the pair ``(D_n, D_2n)`` with its
covariance, which determines ``sigma_w`` and the angle term together.

Variances are chi-square with the white-noise equivalent degrees of freedom
(NIST SP 1065 Table 5); the correlation of two overlapping Allan variances of
white noise follows from their Haar kernels (:func:`allan_corr`: 0.46 for 1 and
2 samples, 0.53 for large n and 2n). Filtered noise just beyond its memory is less
white than that: the covariance is scaled up by the scatter of the white-noise
level between 16 blocks of the record when that is larger.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cache

import numpy as np
from scipy import signal

from imustation.analysis.estimators.classical.allan import block_oavar, oadev
from imustation.errors import InputError, RecordTooShort


@dataclass(frozen=True)
class FineScale:
    """Overlapping Allan variance of all samples at ``tau`` (s) and its variance.

    ``avar`` in (rate unit)^2, ``var`` = 2 avar^2 / edf, ``samples`` = cluster size,
    ``edf`` equivalent degrees of freedom.
    """

    tau: float
    avar: float
    var: float
    edf: float
    samples: int
    #: the noise passed the whiteness test at this scale (False: it failed at every scale tried)
    white: bool = True


#: cluster sizes tried by ``fine_samples="auto"`` (samples); each is compared with 4x itself
AUTO_SAMPLES = (1, 2, 4, 8, 16, 32, 64, 128, 256)
#: whiteness test: |tau AVAR(tau) / (4 tau AVAR(4 tau)) - 1| within this many standard deviations
WHITE_Z = 4.0


@dataclass(frozen=True)
class Octaves:
    """Overlapping Allan variances of a record at cluster sizes 1, 2, 4, ... samples (one pass).

    ``avar`` and ``edf`` (the EDF of the identified noise type, NaN if none) by cluster
    size; ``n`` samples at ``fs_hz`` Hz.
    """

    n: int
    fs_hz: float
    avar: dict[int, float]
    edf: dict[int, float]

    def statistic(self, m: int) -> tuple[float, float]:
        """AVAR and its EDF at cluster size ``m`` (white-noise EDF where none was identified)."""
        edf = self.edf[m]
        if not (np.isfinite(edf) and edf > 0):
            edf = white_edf(self.n, m)
        return self.avar[m], edf


def octave_avars(
    rate: np.ndarray,
    fs_hz: float,
    sizes: tuple[int, ...],
    *,
    scale: float = 1.0,
    segments: list[tuple[int, int]] | None = None,
) -> Octaves:
    """:class:`Octaves` at the cluster ``sizes`` (samples) the record is long enough for."""
    res = oadev(rate, fs_hz, [k / fs_hz for k in sizes], scale=scale, segments=segments)
    ms = [int(round(t * fs_hz)) for t in res.tau]
    avar = {m: float(a) ** 2 for m, a in zip(ms, res.adev, strict=True)}
    edf = {m: float(e) for m, e in zip(ms, res.edf, strict=True)}
    return Octaves(len(rate), float(fs_hz), avar, edf)


def fine_scale(
    rate: np.ndarray,
    fs_hz: float,
    *,
    samples: int | str = 1,
    scale: float = 1.0,
    segments: list[tuple[int, int]] | None = None,
    octaves: Octaves | None = None,
) -> FineScale:
    """Fine-scale statistic of :mod:`.composite`: AVAR at ``samples / fs_hz`` s from every sample.

    ``rate`` in rad/s (or integer counts with ``scale`` units per count, summed exactly).
    ``samples="auto"``: the smallest cluster size of :data:`AUTO_SAMPLES` at which
    the noise is white, i.e. ``tau AVAR(tau)`` equals ``4 tau AVAR(4 tau)`` within
    :data:`WHITE_Z` standard deviations (a device low-pass filter lowers the first);
    ``FineScale.white`` says whether any passed. ``octaves``: the record's Allan
    variances at those sizes, if already computed (:func:`octave_avars`).
    """
    n = len(rate)
    sizes = [k for k in AUTO_SAMPLES if 8 * k < n] if samples == "auto" else [int(samples)]
    if not sizes:
        raise RecordTooShort(f"{n} samples: too short for a fine-scale Allan variance")
    if octaves is None or any(k not in octaves.avar for k in sizes):
        wanted = tuple(sorted({j for k in sizes for j in ((k, 4 * k) if samples == "auto" else (k,))}))
        octaves = octave_avars(rate, fs_hz, wanted, scale=scale, segments=segments)
    chosen, white, stats = sizes[0], samples != "auto", {}
    for k in sizes:
        if k not in octaves.avar:
            break
        stats[k] = octaves.statistic(k)
        if samples != "auto" or 4 * k not in octaves.avar:
            break
        a1, e1 = stats[k]
        a4, e4 = octaves.statistic(4 * k)
        ratio = a1 / (4.0 * a4)
        if abs(ratio - 1.0) <= WHITE_Z * ratio * math.sqrt(2.0 / e1 + 2.0 / e4):
            chosen, white = k, True
            break
    if chosen not in stats:
        raise RecordTooShort(f"fine scale of {chosen} sample(s): record too short")
    avar, edf = stats[chosen]
    if not np.isfinite(avar) or avar <= 0:
        raise InputError("fine-scale Allan variance is zero or undefined: the channel is constant")
    return FineScale(chosen / fs_hz, avar, 2.0 * avar * avar / edf, edf, chosen, white)


# ---------------------------------------------------------------------------
# the device-filter-aware statistic of the model family

#: cluster sizes of the filter test (samples)
FILTER_SCALES = tuple(2**k for k in range(11))
#: the three scales n, 2n, 4n are "linear in 1/tau" within this many standard errors
LINEAR_Z = 4.0
#: the angle term (filter deficit or white angle noise) is carried when it is this many standard errors from 0
ANGLE_Z = 4.0


@dataclass(frozen=True)
class FilterHint:
    """What a device's stored settings say about its output filter.

    ``on``: a filter below the output Nyquist frequency is configured; ``memory_s``
    (s): how long its output samples stay correlated (the fine scale starts there);
    ``source``: the settings read, for messages.
    """

    on: bool
    memory_s: float = 0.0
    source: str = ""
    #: the fine scales start no earlier than this (s), whatever the filter: a resonance's band is kept
    #: out of the white-noise estimate (:mod:`~imustation.analysis.estimators.classical.resonance`)
    start_s: float = 0.0
    #: the largest angle deficit tau_lp (s) a filter of the configured bandwidth can have (0: unknown): a
    #: first-order filter's ``1 / (2 pi bw)`` is the largest of the usual designs at a -3 dB bandwidth bw
    #: (Butterworth 0.65 .. 1, Bessel 0.91 .. 1, Chebyshev less), times :data:`TAU_LP_MARGIN`
    tau_lp_max: float = 0.0


@dataclass(frozen=True)
class FineStatistic:
    """The fine-scale statistic and the filter test behind it.

    ``taus`` (s), ``avar`` ((rate unit)^2) and ``cov`` (their covariance): the first cluster
    size n at which the noise is white up to the angle term, and 2n with an angle term; when the
    slow terms show at those scales, n .. 16n with ``nuisance`` (a floor and a rising term) left
    free in the fit (:meth:`weight`). ``term``: ``""``, ``"lp"`` (device
    filter) or ``"wa"`` (white angle noise); ``tau_lp`` (s) the test's estimate of the
    angle deficit (negative: white angle noise of ``sigma_a^2 = -sigma_w^2 tau_lp / 2``)
    and ``angle_z`` its significance; ``samples`` the first cluster size at which the
    noise is white up to the angle term (the model holds from ``samples / fs_hz`` s on),
    ``linear`` whether any size passed the test, ``source`` where the decision came from.
    """

    taus: np.ndarray
    avar: np.ndarray
    cov: np.ndarray
    #: shapes (J, 0 or 2) the fit leaves free at the fine scales: a flat floor and a term rising as tau
    nuisance: np.ndarray
    samples: int
    term: str
    tau_lp: float
    angle_z: float
    linear: bool
    source: str
    #: the Allan variances at 1, 2, 4, ... samples the test used (for :func:`fine_scale`)
    octaves: Octaves | None = None
    #: the slow terms' share of the Allan variance at the first fine scale (the test's floor and
    #: rising term over its white noise); above :data:`SLOW_SHARE` sigma_w rests on their shape
    slow_share: float = 0.0
    #: factor applied to the white-noise covariance of ``avar`` (the scatter between blocks)
    inflation: float = 1.0
    #: when the slow terms show at the fine scales: an upper bound on sigma_w^2 that needs no model of
    #: them, and its standard error ((rate unit)^2 s; :func:`white_bound`), and the cluster size n
    #: (samples) of the pair n, 2n it comes from; NaN, NaN, 0 otherwise
    white_bound: tuple[float, float] = (math.nan, math.nan)
    bound_samples: int = 0
    #: the statistic starts here (s) to keep a resonance out (``FilterHint.start_s``); 0: not moved
    excluded_s: float = 0.0

    @property
    def memory_s(self) -> float:
        """Cluster time (s) from which the model is exact (the filter's memory)."""
        return float(self.taus[0])

    def weight(self) -> np.ndarray:
        """``C^-1`` with the nuisance shapes projected out: ``(D - s A)^T W (D - s A)`` is the GLS
        residual of the fine-scale Allan variances once a floor and a rising term are fitted freely
        (the slow terms' own model then does not steer sigma_w: a bias instability that does not reach
        down to the fine scales, as in the simulators of issue 21, would otherwise bias it)."""
        Ci = np.linalg.inv(self.cov)
        X = self.nuisance
        if X.shape[1] == 0:
            return Ci
        CX = Ci @ X
        return Ci - CX @ np.linalg.solve(X.T @ CX, CX.T)


def white_edf(n: int, m: int) -> float:
    """Equivalent degrees of freedom of the overlapping AVAR of white rate noise at cluster size ``m``
    from ``n`` samples (NIST SP 1065 Table 5)."""
    return (3.0 * (n - 1) / (2.0 * m) - 2.0 * (n - 2) / n) * 4.0 * m * m / (4.0 * m * m + 5.0)


@cache
def allan_corr(n: int, m: int) -> float:
    """Correlation of the overlapping Allan variance estimates at cluster sizes ``n`` and ``m``
    (samples) of white noise: the covariance of two quadratic forms of iid Gaussian data is
    ``2 tr(A B)``, here the summed squared cross-correlation of the two Haar kernels."""

    def kernel(k: int) -> np.ndarray:
        return np.concatenate([np.ones(k), -np.ones(k)])

    def s(a: int, b: int) -> float:
        # by FFT: the direct correlation is quadratic in the sizes (minutes at 2^14 samples, where the
        # statistic starts beyond a resonance)
        r = (
            signal.fftconvolve(kernel(a), kernel(b)[::-1])
            if max(a, b) > 256
            else np.correlate(kernel(a), kernel(b), "full")
        )
        return float(np.sum(r * r))

    return s(n, m) / math.sqrt(s(n, n) * s(m, m))


def _cov(avar: np.ndarray, sizes: list[int], n: int) -> np.ndarray:
    sd = np.array([a * math.sqrt(2.0 / white_edf(n, k)) for a, k in zip(avar, sizes, strict=True)])
    corr = np.array([[allan_corr(a, b) if a != b else 1.0 for b in sizes] for a in sizes])
    return corr * np.outer(sd, sd)


def fine_statistics(
    rate: np.ndarray,
    fs_hz: float,
    *,
    scale: float = 1.0,
    segments: list[tuple[int, int]] | None = None,
    hint: FilterHint | None = None,
) -> FineStatistic:
    """The fine-scale statistic of the model family and its device-filter test (module docstring).

    ``rate`` in rad/s (or integer counts with ``scale`` units per count); ``fs_hz`` Hz;
    ``hint``: the device's filter settings: when the data show a deficit, the scale
    starts no earlier than the filter's memory (a short record lacks the power to see
    its shape); the data alone decide whether there is an angle term.
    """
    n = len(rate)
    # a resonance's band is kept out: the test starts where it has averaged out (its correlation times)
    start = max(1, 2 ** math.ceil(math.log2(max(hint.start_s * fs_hz, 1.0)))) if hint is not None else 1
    scales = FILTER_SCALES if start == 1 else tuple(2**k for k in range(int(math.log2(start)) + 11))
    sizes = [k for k in scales if 16 * k < n]
    if len(sizes) < TEST_OCTAVES:
        raise RecordTooShort(f"{n} samples: too short for the fine-scale statistics")
    octaves = octave_avars(rate, fs_hz, tuple(sizes), scale=scale, segments=segments)
    got = octaves.avar
    sizes = [k for k in sizes if k in got]
    if not sizes or got[sizes[0]] <= 0 or not math.isfinite(got[sizes[0]]):
        raise InputError("fine-scale Allan variance is zero or undefined: the channel is constant")
    source = "data" if start == 1 else f"data; a resonance: from {start / fs_hz:.3g} s"
    if start > 1 and not any(16 * k in got for k in sizes if k >= start):
        raise RecordTooShort(
            f"{n} samples: too short to read the white noise beyond a resonance ({hint.start_s:.3g} s)"
        )
    chosen = _first_linear(got, sizes, start, n, fs_hz)
    linear = chosen is not None
    if hint is not None and hint.on:
        source = f"{source}; settings: {hint.source}"
        hinted = max(start, 2 ** math.ceil(math.log2(max(hint.memory_s * fs_hz, 1.0))))
        if (chosen is None or chosen < hinted) and (chosen is None or _angle(got, chosen, n, fs_hz)[1] > ANGLE_Z):
            later = _first_linear(got, sizes, hinted, n, fs_hz)
            if later is not None:
                chosen, linear = later, True
    if chosen is not None and _angle(got, chosen, n, fs_hz)[1] > ANGLE_Z and _gls(got, 2 * chosen, n, fs_hz):
        # a filter: one octave of margin beyond where the test first passes. There the filter's
        # shape still biases sigma_w^2 by up to ~0.2 % (BMX055 47 Hz: -0.17 % at 8 samples, 0.004 %
        # at 16, from its exact autocovariance) and its samples are more correlated than the
        # white-noise EDF assumes; one octave costs sqrt(2) in precision
        chosen *= 2
    if chosen is None:
        cand = [k for k in sizes if k >= start and _gls(got, k, n, fs_hz) is not None]
        if not cand:
            raise RecordTooShort(f"{n} samples: too short for a fine scale beyond the device filter's memory")
        chosen = cand[-1]
    tau_lp, z = _angle(got, chosen, n, fs_hz)
    # a filter the settings announce needs less evidence than one nobody announced
    lp_z = HINTED_Z if hint is not None and hint.on else ANGLE_Z
    # behind a low-pass filter the settings announce well below the output Nyquist frequency there is
    # no white angle noise (the filter removes its rising spectrum): a fall faster than 1/tau there is
    # the slow terms' onset, and a "wa" term took the white noise's place (MPU-6500 datasheet gyro z:
    # sigma_w -96 %, issue 32). A band that reaches the Nyquist frequency folds what lies above it onto
    # the top of the band (BMX055 accelerometer, 62.5 Hz at 125 Hz): that output is blue, angle-like
    # ... but a resonance whose angle stays bounded is white angle noise beyond its correlation time
    wa_ok = start > 1 or not (hint is not None and hint.on and hint.memory_s * fs_hz > WA_MEMORY_SAMPLES)
    term = "lp" if z > lp_z else ("wa" if z < -ANGLE_Z and wa_ok else "")
    contradicts = ""
    if term == "lp" and hint is not None and hint.on and 0 < hint.tau_lp_max < tau_lp:
        # the settings' filter cannot have this deficit: it is the slow terms' onset (a Gauss-Markov sum
        # flattening the Allan variance), and read as a filter it gave tau_lp = 192 ms for a 42 Hz DLPF
        # (12 h lab-realistic MPU-9150 gyro y) with an interval excluding the filter's ~3 ms
        contradicts = (
            f"; a deficit of tau_lp {tau_lp * 1e3:.3g} ms at {chosen} samples contradicts the configured filter "
            f"(at most {hint.tau_lp_max * 1e3:.3g} ms): not the filter, not carried"
        )
        term = ""
        source += contradicts
    slow = _slow(got, chosen, n, fs_hz)
    if start > 1 and (slow or (term == "lp" and not (hint is not None and hint.on))):
        # beyond the resonance the slow terms (or their onset, read as a filter nobody announced) shape the
        # Allan variance: sigma_w would rest on them there (a 35 Hz, Q 20 resonance over a 10 deg/h flicker:
        # +5 % with an interval from +1.8 %; kept at the fine scales -6 % inside its widened interval).
        # The resonance stays reported and the fine scales are read as without it
        why = "slow terms" if slow else f"a deficit of {tau_lp * 1e3:.3g} ms no filter setting announces"
        plain = fine_statistics(rate, fs_hz, scale=scale, segments=segments,
                                hint=replace(hint, start_s=0.0) if hint.on else None)  # fmt: skip
        return replace(plain, source=f"{plain.source}; a resonance: not read beyond it ({why} at {chosen} samples)")
    if slow:  # the slow terms show at the fine scales: several octaves, their floor and rise left free
        scales = [chosen * 2**j for j in range(STAT_OCTAVES)]
    else:  # white up to the angle term: the one or two finest scales, as precise as it gets
        scales = [chosen, 2 * chosen] if term else [chosen]
    D = np.array([got[j] for j in scales])
    taus = np.array(scales) / fs_hz
    nuisance = np.column_stack([np.ones_like(taus), taus]) if slow else np.zeros((len(taus), 0))
    C = _cov(D, scales, n)
    inflation = _block_inflation(rate, fs_hz, scales, C, nuisance, term, scale, segments)
    C = C * inflation
    share = 0.0
    fit = _gls(got, chosen, n, fs_hz)
    if slow and fit is not None:
        (a, _, c, d), t0 = fit[0], chosen / fs_hz
        share = float(abs(c + d * t0) / (a / t0)) if a > 0 else math.inf  # a <= 0: no white noise left
    bound, first = (math.nan, math.nan), 0
    if slow:  # from the first scale beyond the filter's memory: the settings' when they announce one
        first = max(start, min(chosen, hinted)) if hint is not None and hint.on else chosen
        bound = white_bound(rate, fs_hz, first, got, scale=scale, segments=segments)
    return FineStatistic(
        taus, D, C, nuisance, chosen, term, float(tau_lp), float(z), linear, source, octaves, share, inflation,
        bound, first if math.isfinite(bound[0]) else 0, chosen / fs_hz if start > 1 else 0.0,
    )  # fmt: skip


def white_bound(
    rate: np.ndarray,
    fs_hz: float,
    k: int,
    got: dict[int, float],
    *,
    scale: float = 1.0,
    segments: list[tuple[int, int]] | None = None,
) -> tuple[float, float]:
    """Upper bound on sigma_w^2 ((rate unit)^2 s) from the Allan variances at k and 2k samples
    beyond the device filter's memory, and its standard error; (NaN, NaN) where the record does
    not reach 2k.

    With ``u(tau) = tau AVAR(tau)``, ``U = 2 u(2 tau) - u(tau)`` is exactly sigma_w^2 for white rate
    noise, a device filter beyond its memory (``-1.5 sigma_w^2 tau_lp / tau``) and white angle
    noise (``3 sigma_a^2 / tau``) together, and the other terms add ``tau (4 s(2 tau) - s(tau))``
    for their Allan variance ``s``: never negative unless ``s`` falls faster than ``tau^-2`` from k
    to 2k samples, which no noise term does (Gauss-Markov, flicker, random walk rise or stay
    there). So U bounds sigma_w^2 from above with no model of the slow terms: used when they reach
    the fine scales and sigma_w rests on their shape (the MPU-9150 of the datasheet profile).
    Its variance: the larger of the white-noise one and the scatter of :data:`BLOCKS` blocks.
    """
    if 2 * k not in got or k not in got:
        return (math.nan, math.nan)
    t = np.array([k, 2 * k]) / fs_hz
    g = np.array([-t[0], 2.0 * t[1]])
    avar = np.array([got[k], got[2 * k]])
    U = float(g @ avar)
    var = float(g @ _cov(avar, [k, 2 * k], len(rate)) @ g)
    per_block = [float(g @ row) for row in block_oavar(rate, fs_hz, [k, 2 * k], BLOCKS, scale=scale, segments=segments)
                 if np.all(np.isfinite(row))]  # fmt: skip
    if len(per_block) >= BLOCKS // 2:
        var = max(var, float(np.var(per_block, ddof=1)) / len(per_block))
    return (U, math.sqrt(var))


def fine_white(fine: FineStatistic) -> tuple[float, float]:
    """sigma_w^2 ((rate unit)^2 s) the fine-scale statistic alone reads, and its standard error: the GLS
    white-noise level of ``fine.avar`` (covariance ``fine.cov``, block inflation included) with the angle
    term and the free floor and rise the statistic carries. It needs no model of the slow terms beyond the
    fine scales; the model family's sigma_w also draws on the coarse scales through the slow terms' model
    (:mod:`.white_guard`)."""
    t = np.asarray(fine.taus, dtype=float)
    cols = [1.0 / t] + ([-1.0 / t**2] if fine.term else []) + list(fine.nuisance.T)
    X = np.column_stack(cols)
    if X.shape[1] > len(t):
        return (math.nan, math.nan)
    Ci = np.linalg.inv(fine.cov)
    g = np.linalg.solve(X.T @ Ci @ X, X.T @ Ci)[0]  # GLS weights of the white-noise level
    var = float(g @ fine.cov @ g)
    return (float(g @ fine.avar), math.sqrt(var) if var > 0 else math.nan)


def _block_inflation(
    rate: np.ndarray,
    fs_hz: float,
    scales: list[int],
    C: np.ndarray,
    nuisance: np.ndarray,
    term: str,
    scale: float,
    segments: list[tuple[int, int]] | None,
) -> float:
    """How much more the white-noise level from the fine scales scatters between :data:`BLOCKS`
    blocks of the record than the white-noise covariance ``C`` says (at least 1).

    Filtered noise just beyond its memory, or slow terms at the fine scales, make the Allan
    variances there less precise than white noise's; the blocks' scatter measures it (ADIS16448
    chain: the stated sigma_w interval was 0.6 x the scatter of repeated records without this)."""
    t = np.array(scales) / fs_hz
    cols = [1.0 / t] + ([-1.0 / t**2] if term else []) + list(nuisance.T)
    X = np.column_stack(cols)
    Ci = np.linalg.inv(C)
    g = np.linalg.solve(X.T @ Ci @ X, X.T @ Ci)[0]  # GLS weights of the white-noise level
    var_white = float(g @ C @ g)
    per_block = block_oavar(rate, fs_hz, scales, BLOCKS, scale=scale, segments=segments)
    est = [float(g @ row) for row in per_block if np.all(np.isfinite(row))]
    if len(est) < BLOCKS // 2 or var_white <= 0:
        return 1.0
    var_block = float(np.var(est, ddof=1)) / len(est)
    return float(np.clip(var_block / var_white, 1.0, MAX_INFLATION))


#: cluster sizes of the test at each candidate n: n, 2n, 4n, 8n, 16n
TEST_OCTAVES = 5
#: blocks of the record whose scatter checks the fine-scale statistic's variance, and the largest
#: factor it may apply
BLOCKS = 16
MAX_INFLATION = 25.0
#: octaves of the statistic when the slow terms show at the fine scales
STAT_OCTAVES = 5
#: above this share of the slow terms at the first fine scale sigma_w is flagged (``message``):
#: it then rests on how the slow terms continue below that scale, which nothing measures
SLOW_SHARE = 0.05
#: the slow terms "show at the fine scales" when the floor or the rising term of the test's fit
#: differs from 0 by more than this many standard errors
SLOW_Z = 3.0
#: ... and the filter deficit is carried from this z on when the device's settings announce a filter
HINTED_Z = 2.0
#: a configured filter's tau_lp is at most this many times the first-order value 1 / (2 pi bw)
#: (the chip's stated bandwidth is nominal)
TAU_LP_MARGIN = 2.0
#: an announced filter whose memory exceeds this many output samples (a band well below the Nyquist
#: frequency) rules out white angle noise at the output
WA_MEMORY_SAMPLES = 1.5


def _gls(
    got: dict[int, float], k: int, n: int, fs_hz: float, slow: bool = True
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """GLS fit of ``AVAR = a/tau - b/tau^2 + c + d tau`` (white noise, angle term, a flat floor and a
    rising bias at the fine scales; ``slow=False``: ``c = d = 0``) to the Allan variances at k, 2k, ...
    (:data:`TEST_OCTAVES`) samples; returns the coefficients, their covariance and the residual
    chi-square. ``None`` when the record does not reach the largest size."""
    sizes = [k * 2**j for j in range(TEST_OCTAVES)]
    if any(j not in got for j in sizes):
        return None
    t = np.array(sizes) / fs_hz
    y = np.array([got[j] for j in sizes])
    X = np.column_stack([1.0 / t, -1.0 / t**2, np.ones_like(t), t])
    if not slow:
        X = X[:, :2]
    Ci = np.linalg.inv(_cov(y, sizes, n))
    A = X.T @ Ci @ X
    cov = np.linalg.inv(A)
    beta = cov @ (X.T @ Ci @ y)
    r = y - X @ beta
    return beta, cov, float(r @ Ci @ r)


def white_by_scale(
    fine: FineStatistic, fs_hz: float, octaves: Octaves | None = None
) -> list[tuple[float, float, float]]:
    """The white-noise level sigma_w^2 ((rate unit)^2 s) the test's fit (:func:`_gls`: white noise, angle
    term, floor and rise) reads from each starting cluster size beyond the statistic's first, with its
    standard error: ``(tau, a, se)`` for n = 2, 4, 8 ... times ``fine.samples`` while the record's
    octaves reach 16 n. Where these disagree with the fit's sigma_w, the shape below them (a resonance,
    the slow terms' onset, a filter's tail) is not what the fit assumed (:mod:`.white_guard`).
    ``octaves``: Allan variances reaching further than ``fine.octaves`` (the same record)."""
    octaves = octaves or fine.octaves
    if octaves is None:
        return []
    got, n = octaves.avar, octaves.n
    out = []
    k = 2 * fine.samples
    while True:
        fit = _gls(got, k, n, fs_hz)
        if fit is None:
            return out
        se = math.sqrt(fit[1][0, 0]) if fit[1][0, 0] > 0 else math.inf
        out.append((k / fs_hz, float(fit[0][0]), se))
        k *= 2


def _first_linear(got: dict[int, float], sizes: list[int], start: int, n: int, fs_hz: float) -> int | None:
    """The first cluster size from ``start`` on at which the Allan variances at k .. 16k follow
    white noise plus an angle term plus smooth slow terms (:func:`_gls`) within :data:`LINEAR_Z`."""
    for k in sizes:
        if k < start:
            continue
        fit = _gls(got, k, n, fs_hz)
        if fit is None:
            return None
        if fit[2] <= LINEAR_Z**2:
            return k
    return None


def _slow(got: dict[int, float], k: int, n: int, fs_hz: float) -> bool:
    """Whether the floor or the rising term of :func:`_gls` at k differs from 0 (:data:`SLOW_Z`)."""
    fit = _gls(got, k, n, fs_hz)
    return fit is not None and bool(np.any(np.abs(fit[0][2:]) > SLOW_Z * np.sqrt(np.diag(fit[1])[2:])))


def _angle(got: dict[int, float], k: int, n: int, fs_hz: float) -> tuple[float, float]:
    """``tau_lp`` (s) at cluster size k (:func:`_gls`; ``b = 1.5 a tau_lp``) and its z-score; the slow
    terms are fitted only where they show (they cost the angle term most of its precision)."""
    fit = _gls(got, k, n, fs_hz, slow=_slow(got, k, n, fs_hz))
    if fit is None:
        return 0.0, 0.0
    a, b = fit[0][:2]
    cov = fit[1]
    se = math.sqrt(cov[1, 1]) if cov[1, 1] > 0 else math.inf
    return b / (1.5 * a), b / se
