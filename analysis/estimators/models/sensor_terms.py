"""Noise terms that real sensors add to the paper's model: bias instability and the device filter.

**Bias instability** (code ``fl``, IEEE Std 952-1997 C.1): flicker rate noise of
two-sided PSD ``B^2 / (2 pi f)``, whose Allan deviation is flat at
``sqrt(2 ln 2 / pi) B = 0.664 B``. No finite state space has that spectrum, so the
likelihood carries a documented approximation: a fixed sum of first-order
Gauss-Markov terms with correlation times one per decade, ``T_j = 10^k`` s from
below the sample time to above three record lengths (:func:`flicker_times`), all
driven by the one amplitude B. A 1/f spectrum is the integral of Lorentzians
``T/(1 + (2 pi f T)^2)`` over ``d ln T`` with weight ``2 B^2 / pi``; the sum samples
that integral every ``ln 10``, so term j has ``sigma_b_j^2 = 2 B^2 ln(10) / (pi T_j)``.
Error of the approximation (tests/test_model_family.py): its Allan deviation is
within -2.2 % ... +1.0 % of 0.664 B for ``10 T_min <= tau <= T_max / 10``, i.e. over
every cluster time of the record from ~0.01 s up. The decade-aligned grid depends
on the sampling rate and the record length only, so repeats of one device use the
same terms.

**Cut-off** (IEEE Std 952-1997 C.1 gives the flicker spectrum a cut-off frequency
``f0``, above which it stops): a bias instability whose 1/f spectrum ends well
below the sampling rate is the same sum started at a later decade ``cut_s``
(:func:`flicker_times` ``from_s``, the term a decade below keeping a share that
fades with the cut-off, :func:`flicker_weights`): below ``cut_s`` the sum's Allan
deviation falls away from the floor instead of adding to the white noise. The model choice
(:mod:`.model_choice`) tries decade cut-offs when the uncut sum does not fit.

**Device low-pass filter** (code ``lp``): a sensor's digital filter with unit DC
gain turns the white rate noise into filtered noise whose integral over any
interval ``T`` longer than the filter's memory has variance
``sigma_w^2 (T - tau_lp)`` and whose neighbouring intervals share ``sigma_w^2
tau_lp / 2``: exactly the statistics of white rate noise plus an angle noise of
*negative* variance ``-sigma_w^2 tau_lp / 2`` (``tau_lp = dt sum_k |k| r_k`` with
r_k the autocorrelation of the filtered samples; for a first-order filter it is
its time constant). So beyond the memory one number describes any linear filter,
whatever its order or coefficients, and the Kalman filter carries it as the
angle-noise variance. Beyond the memory it adds ``-1.5 sigma_w^2 tau_lp / tau^2`` to the Allan
variance; below, the Allan variance depends on the filter's shape, and
:class:`LowPass` draws it as the first-order (AR(1)) filter with the same
``tau_lp``; ``memory_s`` says from where on the model is exact
(docs/noise-model.md, "Filtered devices", argues this choice).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from imustation.analysis.estimators.models.noise_models import GaussMarkov, Term, gm_unit_avar
from imustation.errors import InputError

#: Allan deviation floor of flicker noise over B (IEEE 952): sqrt(2 ln 2 / pi)
FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
#: ratio of neighbouring correlation times of the flicker sum (one per decade)
FLICKER_RATIO = 10.0


def flicker_times(fs_hz: float, duration_s: float, from_s: float = 0.0) -> tuple[float, ...]:
    """Correlation times (s) of the flicker sum for a record: ``10^k`` from the decade at or
    below the sample time ``1/fs_hz`` up to the decade at or above ``3 x duration_s``; with a
    cut-off ``from_s`` (s, a power of ten), only the times from ``from_s`` on."""
    if not (fs_hz > 0 and duration_s > 0):
        raise InputError(f"flicker terms need a positive rate and duration, got {fs_hz} Hz, {duration_s} s")
    lo = math.floor(math.log10(1.0 / fs_hz) + 1e-9)
    if from_s > 0:  # the decade below the cut-off carries the fading share (flicker_weights)
        lo = max(lo, math.floor(math.log10(from_s) - 1e-9))
    hi = math.ceil(math.log10(3.0 * duration_s) - 1e-9)
    return tuple(10.0**k for k in range(lo, hi + 1))


def flicker_weights(times: tuple[float, ...] | np.ndarray, cut_s: float = 0.0) -> np.ndarray:
    """``sigma_b_j^2 / B^2`` of each term of the flicker sum, 1/s (``2 ln(ratio) / (pi T_j)``).

    With a cut-off ``cut_s`` (s), a term below it keeps the share ``1 - log10(cut_s / T_j)``
    (0 a decade below): the sum then changes continuously with the cut-off, which need not
    be a power of ten."""
    t = np.asarray(times, dtype=float)
    w = 2.0 * math.log(FLICKER_RATIO) / (math.pi * t)
    if cut_s > 0:
        w = w * np.clip(1.0 - np.log10(cut_s / t), 0.0, 1.0)
    return w


@dataclass(frozen=True)
class BiasInstability(Term):
    """Bias instability B (rad/s; m/s^2 for accelerometers): flicker noise as a fixed Gauss-Markov sum.

    ``times`` (s) are the sum's correlation times (:func:`flicker_times`); every
    statistic is the sum's, exactly. ``cut_s`` (s): the cut-off the times start at (0: none,
    the sum starts at the sample time).
    """

    B: float
    times: tuple[float, ...]
    cut_s: float = 0.0
    code = "fl"

    @property
    def n_states(self) -> int:  # type: ignore[override]
        return len(self.times)

    def components(self) -> tuple[Term, ...]:
        w = flicker_weights(self.times, self.cut_s)
        return tuple(GaussMarkov(self.B * math.sqrt(float(wj)), T) for wj, T in zip(w, self.times, strict=True))

    def avar(self, tau, fs_hz=None):
        tau = np.asarray(tau, dtype=float)
        return sum((c.avar(tau, fs_hz) for c in self.components()), np.zeros_like(tau))

    def _psd2(self, f, fs_hz):
        return sum((c._psd2(f, fs_hz) for c in self.components()), np.zeros_like(f))

    def simulate(self, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        return sum((c.simulate(n, dt, rng) for c in self.components()), np.zeros(n))

    def params(self) -> dict[str, float]:
        return {"B": float(self.B)}


def lowpass_alpha(tau_lp: np.ndarray, dt: float) -> np.ndarray:
    """Coefficient ``a`` of the first-order filter ``y_k = a y_{k-1} + (1 - a) x_k`` whose
    angle deficit is ``tau_lp`` (s) at sample time ``dt`` (s): ``2 a / (1 - a^2) = tau_lp / dt``."""
    r = np.asarray(tau_lp, dtype=float) / dt
    safe = np.where(r > 1e-8, r, 1.0)
    return np.where(r > 1e-8, (np.sqrt(1.0 + safe * safe) - 1.0) / safe, 0.5 * r)


def first_order_unit_avar(tau_lp: np.ndarray, tau: float, fs_hz: float) -> np.ndarray:
    """What a first-order filter of angle deficit ``tau_lp`` (s, array) adds to the AVAR of unit
    white rate noise at ``tau`` (s), sampled at ``fs_hz`` (beyond its memory: ``-1.5 tau_lp/tau^2``)."""
    dt = 1.0 / fs_hz
    a = lowpass_alpha(tau_lp, dt)
    a = np.clip(a, 1e-300, None)
    T = -dt / np.log(a)
    # stationary variance of the filtered samples (1 - a)/(dt (1 + a)) = sigma_b^2 T / 2
    q = 2.0 * (1.0 - a) / (dt * (1.0 + a)) / T
    return q * gm_unit_avar(T, tau, fs_hz) - 1.0 / tau


@dataclass(frozen=True)
class LowPass(Term):
    """A device low-pass filter acting on the white rate noise ``sigma_w`` (rad s^-1/sqrt(Hz)).

    ``tau_lp`` (s): the angle deficit (equivalent first-order time constant, module
    docstring); ``memory_s`` (s): the filter's memory, below which the statistics
    here are the first-order filter's and not necessarily the device's (0: unknown).
    In the state space it is angle noise of variance ``-sigma_w^2 tau_lp / 2``.
    """

    sigma_w: float
    tau_lp: float
    memory_s: float = 0.0
    code = "lp"

    def angle_variance(self) -> float:
        return -(self.sigma_w**2) * self.tau_lp / 2.0

    @property
    def valid_from_s(self) -> float:
        """Cluster time (s) from which :meth:`avar` is the device's: ``memory_s``, or five
        equivalent time constants when the memory is unknown."""
        return self.memory_s if self.memory_s > 0 else 5.0 * self.tau_lp

    def avar(self, tau, fs_hz=None):
        """``-1.5 sigma_w^2 tau_lp / tau^2`` from :attr:`valid_from_s` on (exact for any filter there);
        below, the first-order filter's (continuous, or sampled with ``fs_hz``)."""
        tau = np.asarray(tau, dtype=float)
        s2 = self.sigma_w**2
        beyond = -1.5 * s2 * self.tau_lp / tau**2
        if fs_hz is None:  # continuous first-order filter of time constant tau_lp
            T = self.tau_lp
            within = GaussMarkov(self.sigma_w / T, T).avar(tau) - s2 / tau
        else:
            flat = [float(first_order_unit_avar(np.array(self.tau_lp), float(t), fs_hz)) for t in tau.ravel()]
            within = s2 * np.array(flat).reshape(tau.shape)
        return np.where(tau >= self.valid_from_s * (1.0 - 1e-9), beyond, within)

    def _psd2(self, f, fs_hz):
        s2 = self.sigma_w**2
        if fs_hz is None:
            return s2 * (1.0 / (1.0 + (2.0 * np.pi * f * self.tau_lp) ** 2) - 1.0)
        dt = 1.0 / fs_hz
        a = float(lowpass_alpha(np.array(self.tau_lp), dt))
        h2 = (1.0 - a) ** 2 / (1.0 - 2.0 * a * np.cos(2.0 * np.pi * f * dt) + a * a)
        return s2 * (h2 - 1.0)

    def simulate(self, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        return np.zeros(n)  # the filter acts on the white term: NoiseModel.simulate calls filter_white

    def filter_white(self, x: np.ndarray, dt: float) -> np.ndarray:
        """The white-noise samples ``x`` through the first-order filter of the same ``tau_lp``."""
        a = float(lowpass_alpha(np.array(self.tau_lp), dt))
        y, _ = lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])
        return y

    def params(self) -> dict[str, float]:
        return {"tau_lp": float(self.tau_lp)}
