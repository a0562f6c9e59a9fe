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
smallest cluster size n (a power of two, not below what the device's settings
say about its filter) at which ``u_n, u_2n, u_4n`` lie on one line within
:data:`LINEAR_Z` standard errors (``u_n - 3 u_2n + 2 u_4n = 0``): there the noise is
white up to the angle term; with a filter the statistic then starts one octave
further on (margin against the filter's remaining shape). The slope between n and 2n gives ``tau_lp``
(positive: a filter; negative: white angle noise); when it differs from 0 by more
than :data:`ANGLE_Z` standard errors (or the settings say a filter is on) the fit
carries the angle term and the statistic is the pair ``(D_n, D_2n)`` with its
covariance, which determines ``sigma_w`` and the angle term together.

Variances are chi-square with the white-noise equivalent degrees of freedom
(NIST SP 1065 Table 5); the correlation of two overlapping Allan variances of
white noise follows from their Haar kernels (:func:`allan_corr`: 0.46 for 1 and
2 samples, 0.53 for large n and 2n).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np

from imustation.analysis.estimators.allan import oadev
from imustation.errors import InputError


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
        raise InputError(f"{n} samples: too short for a fine-scale Allan variance")
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
        raise InputError(f"fine scale of {chosen} sample(s): record too short")
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


@dataclass(frozen=True)
class FineStatistic:
    """The fine-scale statistic and the filter test behind it.

    ``taus`` (s), ``avar`` ((rate unit)^2) and ``cov`` (their covariance): one cluster
    size, or ``n`` and ``2n`` with an angle term. ``term``: ``""``, ``"lp"`` (device
    filter) or ``"wa"`` (white angle noise); ``tau_lp`` (s) the test's estimate of the
    angle deficit (negative: white angle noise of ``sigma_a^2 = -sigma_w^2 tau_lp / 2``)
    and ``angle_z`` its significance; ``samples`` the first cluster size at which the
    noise is white up to the angle term (the model holds from ``samples / fs_hz`` s on),
    ``linear`` whether any size passed the test, ``source`` where the decision came from.
    """

    taus: np.ndarray
    avar: np.ndarray
    cov: np.ndarray
    samples: int
    term: str
    tau_lp: float
    angle_z: float
    linear: bool
    source: str
    #: the Allan variances at 1, 2, 4, ... samples the test used (for :func:`fine_scale`)
    octaves: Octaves | None = None

    @property
    def memory_s(self) -> float:
        """Cluster time (s) from which the model is exact (the filter's memory)."""
        return float(self.taus[0])

    def as_fine_scale(self) -> FineScale:
        """The first scale as the single statistic of the standard model's estimator."""
        var = float(self.cov[0, 0])
        return FineScale(float(self.taus[0]), float(self.avar[0]), var, 2.0 * float(self.avar[0]) ** 2 / var,
                         self.samples, self.linear)  # fmt: skip


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
        r = np.correlate(kernel(a), kernel(b), "full")
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
    sizes = [k for k in FILTER_SCALES if 16 * k < n]
    if len(sizes) < 3:
        raise InputError(f"{n} samples: too short for the fine-scale statistics")
    octaves = octave_avars(rate, fs_hz, tuple(sizes), scale=scale, segments=segments)
    got = octaves.avar
    sizes = [k for k in sizes if k in got]
    if not sizes or got[sizes[0]] <= 0 or not math.isfinite(got[sizes[0]]):
        raise InputError("fine-scale Allan variance is zero or undefined: the channel is constant")
    source = "data"
    chosen = _first_linear(got, sizes, 1, n, fs_hz)
    linear = chosen is not None
    if hint is not None and hint.on:
        source = f"data; settings: {hint.source}"
        hinted = max(1, 2 ** math.ceil(math.log2(max(hint.memory_s * fs_hz, 1.0))))
        if (chosen is None or chosen < hinted) and (chosen is None or _angle(got, chosen, n, fs_hz)[1] > ANGLE_Z):
            later = _first_linear(got, sizes, hinted, n, fs_hz)
            if later is not None:
                chosen, linear = later, True
    if chosen is not None and _angle(got, chosen, n, fs_hz)[1] > ANGLE_Z and 4 * chosen in got:
        # a filter: one octave of margin beyond where the test first passes. There the filter's
        # shape still biases sigma_w^2 by up to ~0.2 % (BMX055 47 Hz: -0.17 % at 8 samples, 0.004 %
        # at 16, from its exact autocovariance) and its samples are more correlated than the
        # white-noise EDF assumes; one octave costs sqrt(2) in precision
        chosen *= 2
    if chosen is None:
        cand = [k for k in sizes if 2 * k in got]
        if not cand:
            raise InputError(f"{n} samples: too short for a fine scale beyond the device filter's memory")
        chosen = cand[-1]
    pair = [chosen, 2 * chosen]
    D = np.array([got[j] for j in pair])
    C = _cov(D, pair, n)
    tau1 = chosen / fs_hz
    tau_lp, z = _angle(got, chosen, n, fs_hz)
    term = "lp" if z > ANGLE_Z else ("wa" if z < -ANGLE_Z else "")
    if term:
        taus, avar, cov = np.array([tau1, 2 * tau1]), D, C
    else:
        taus, avar, cov = np.array([tau1]), D[:1], C[:1, :1]
    return FineStatistic(taus, avar, cov, chosen, term, float(tau_lp), float(z), linear, source, octaves)


def _first_linear(got: dict[int, float], sizes: list[int], start: int, n: int, fs_hz: float) -> int | None:
    """The first cluster size from ``start`` on at which n, 2n, 4n lie on one line in 1/tau."""
    for k in sizes:
        if k < start or 4 * k not in got:
            continue
        trio = [k, 2 * k, 4 * k]
        t = np.array(trio) / fs_hz
        u = np.array([got[j] for j in trio]) * t
        cu = _cov(np.array([got[j] for j in trio]), trio, n) * np.outer(t, t)
        c = np.array([1.0, -3.0, 2.0])
        z = float(c @ u) / math.sqrt(float(c @ cu @ c))
        if abs(z) <= LINEAR_Z:
            return k
    return None


def _angle(got: dict[int, float], k: int, n: int, fs_hz: float) -> tuple[float, float]:
    """``tau_lp`` (s) from the Allan variances at k and 2k samples, and its z-score."""
    pair = [k, 2 * k]
    D = np.array([got[j] for j in pair])
    C = _cov(D, pair, n)
    t1 = k / fs_hz
    d = D[1] * 2 * t1 - D[0] * t1  # u_2k - u_k = s 1.5 tau_lp / (2 t1)
    var_d = C[0, 0] * t1**2 + C[1, 1] * (2 * t1) ** 2 - 2 * C[0, 1] * t1 * 2 * t1
    s = 2.0 * D[1] * 2 * t1 - D[0] * t1
    return 2.0 * t1 * d / (1.5 * s), (d / math.sqrt(var_d) if var_d > 0 else 0.0)
