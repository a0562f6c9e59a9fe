"""An inertial-sensor noise generator written from the published formulas, sharing no code with the project.

It imports numpy and scipy.signal only (never ``imustation``), so a check of the project's
estimators against it is not a check of the project against itself. Every term is stated in
IEEE Std 952-1997's two-sided conventions (Annex C: the Allan variance of each term), SI units:

* white rate noise, density ``N`` (rad/s/sqrt(Hz)): samples of variance ``N^2 f`` at rate ``f``;
  AVAR ``N^2 / tau``;
* white angle noise ``sigma_a`` (rad per sample): the rate is the difference of white angle
  samples times ``f``; AVAR ``3 sigma_a^2 / tau^2`` (IEEE 952's quantisation-noise shape);
* bias instability (flicker rate noise) ``B`` (rad/s): N. J. Kasdin's fractional-difference filter
  (Proc. IEEE 83(5), 1995, eq. 116: ``h_0 = 1, h_k = h_{k-1} (k - 1 + alpha/2) / k``, alpha = 1)
  driven by white samples of variance ``B^2``: its one-sided PSD ``2 B^2 dt / |2 sin(pi f dt)|`` is
  ``B^2 / (pi f)`` at low frequency (IEEE 952's two-sided ``B^2 / (2 pi f)``); AVAR ``(2 ln 2 / pi) B^2``
  flat from a few samples up to the record's length; the 1/f spectrum continues up to the Nyquist frequency (a real
  bias instability does not stop at some fine scale);
* rate random walk ``K`` (rad/s^2/sqrt(Hz)): rate increments of variance ``K^2 / f``; AVAR ``K^2 tau / 3``;
* first-order Gauss-Markov (exponentially correlated) rate, stationary deviation ``s`` (rad/s), time
  constant ``T`` (s): the exact AR(1) ``x_k = e^{-1/(f T)} x_{k-1} + w_k``;
* a sinusoid ``A sin(2 pi f0 t + phase)``;
* a second-order resonance (a structural mode seen by the gyro): white noise differenced (its angle
  stays bounded, so its rate PSD is 0 at 0 Hz) through the resonator ``1 / (1 - 2 r cos w z^-1 +
  r^2 z^-2)``, centre ``f_r``, quality ``Q`` (``r = exp(-pi f_r / (Q f))``), scaled to a stated peak
  PSD relative to the white noise's; or, ``resonance_dc``, not differenced: a second-order Gauss-Markov
  process (IEEE 952's exponentially correlated noise of second order), whose power at 0 Hz is white
  rate noise over long times and belongs to the channel's N (``N^2 (1 + peak |H(0)|^2 / |H(f_r)|^2)``);
* a device filter: the white rate noise drawn at an internal rate ``f_i``, through a Butterworth
  low-pass (order 1..4, bilinear transform), a moving average of ``taps`` samples, or both, then
  **decimated by picking every r-th sample** (no averaging: the band above the output Nyquist
  frequency folds onto it). The output's white-noise density is then ``N sqrt(r sum_l g(l r))``
  with ``g`` the filter's impulse-response autocorrelation (:func:`output_density`);
* integer counts: the rate rounded to ``lsb`` (rad/s per count) and clipped to int16; the rounding
  adds white rate noise of ``lsb^2 / 12`` per sample (density ``lsb / sqrt(12 f)``), which
  :meth:`Channel.truth_n` includes.

The truth of a channel (:class:`Truth`) is what an estimator of N, B, K should return: N the output
samples' white-noise density (filter folding and rounding included), B the flicker's, K the walk's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

#: one-sided PSD of flicker rate noise B^2 / (pi f) = 2 q dt / (2 pi f dt): Kasdin's innovations' variance q = B^2
FLICKER_INNOVATION = 1.0


@dataclass(frozen=True)
class DeviceFilter:
    """White noise drawn at ``internal_hz``, low-passed (Butterworth ``order`` at ``bandwidth_hz``
    and/or a ``taps``-sample moving average), then every ``ratio``-th sample kept."""

    internal_hz: float
    ratio: int
    bandwidth_hz: float = 0.0
    order: int = 2
    taps: int = 1

    def coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        b, a = np.ones(1), np.ones(1)
        if self.bandwidth_hz > 0:
            b, a = signal.butter(self.order, self.bandwidth_hz, fs=self.internal_hz)
        if self.taps > 1:
            b = np.convolve(b, np.ones(self.taps) / self.taps)
        return b, a

    def impulse(self, n: int = 40000) -> np.ndarray:
        b, a = self.coefficients()
        return signal.lfilter(b, a, np.r_[1.0, np.zeros(n - 1)])


def output_density(n_density: float, filt: DeviceFilter | None) -> float:
    """White-noise density (rad/s/sqrt(Hz)) of the decimated output of white rate noise ``n_density``
    through ``filt``: the output samples' autocovariance ``N^2 f_i g(l r)`` summed over lags, times the
    output interval ``r / f_i`` (the density an estimator of long-term white noise sees)."""
    if filt is None:
        return n_density
    h = filt.impulse()
    g = np.correlate(h, h, "full")[len(h) - 1 :]
    r = filt.ratio
    lagsum = g[0] + 2.0 * g[r::r].sum()
    return n_density * math.sqrt(r * lagsum)


def kasdin_flicker(n: int, B: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` samples of flicker rate noise of bias instability ``B`` (module docstring), by FFT convolution."""
    k = np.arange(1, n)
    h = np.concatenate([[1.0], np.cumprod((k - 1 + 0.5) / k)])
    w = rng.normal(0.0, B * math.sqrt(FLICKER_INNOVATION), n)
    size = 1 << int(math.ceil(math.log2(2 * n)))
    out = np.fft.irfft(np.fft.rfft(h, size) * np.fft.rfft(w, size), size)[:n]
    return out


@dataclass(frozen=True)
class Spec:
    """One channel. Rates in Hz, densities in rad/s/sqrt(Hz), B and sinusoid amplitudes in rad/s,
    K in rad/s^2/sqrt(Hz), times in s; ``lsb`` rad/s per count (0: float samples)."""

    name: str
    fs_hz: float
    N: float
    B: float = 0.0
    K: float = 0.0
    gm: tuple[tuple[float, float], ...] = ()  # (stationary sigma, T)
    sigma_a: float = 0.0
    sines: tuple[tuple[float, float], ...] = ()  # (amplitude, frequency)
    resonance: tuple[float, float, float] = ()  # (centre Hz, Q, peak PSD / white PSD)
    resonance_dc: bool = False  # a second-order Gauss-Markov process (power at 0 Hz) instead of a zero-DC mode
    filt: DeviceFilter | None = None
    lsb: float = 0.0
    settings: dict = field(default_factory=dict)  # what a run file would store about the filter


@dataclass(frozen=True)
class Truth:
    N: float
    B: float
    K: float


def truth(spec: Spec) -> Truth:
    """N, B, K an estimator should return for ``spec`` (module docstring)."""
    n = output_density(spec.N, spec.filt)
    if spec.resonance and spec.resonance_dc:  # its power at 0 Hz is white noise over long times
        b, a = _resonator(spec.fs_hz, spec.resonance[0], spec.resonance[1], True)
        _, h = signal.freqz(b, a, worN=[0.0, spec.resonance[0]], fs=spec.fs_hz)
        n = math.sqrt(n * n + spec.N**2 * spec.resonance[2] * abs(h[0]) ** 2 / abs(h[1]) ** 2)
    if spec.lsb > 0:
        n = math.hypot(n, spec.lsb / math.sqrt(12.0 * spec.fs_hz))
    return Truth(n, spec.B, spec.K)


def _resonator(fs: float, centre: float, q: float, dc: bool) -> tuple[list[float], list[float]]:
    r = math.exp(-math.pi * centre / (q * fs))
    w = 2.0 * math.pi * centre / fs
    return ([1.0] if dc else [1.0, -1.0]), [1.0, -2.0 * r * math.cos(w), r * r]


def _resonance(
    n: int, fs: float, centre: float, q: float, peak: float, n_density: float, rng, dc: bool = False
) -> np.ndarray:
    b, a = _resonator(fs, centre, q, dc)
    _, H = signal.freqz(b, a, worN=[centre], fs=fs)
    # white samples of variance v give one-sided PSD 2 v |H|^2 / fs; the white noise's is 2 N^2
    v = peak * n_density**2 * fs / abs(H[0]) ** 2
    x = signal.lfilter(b, a, rng.normal(0.0, math.sqrt(v), n + 20000))
    return x[20000:]


def generate(spec: Spec, hours: float, seed: int) -> np.ndarray:
    """The channel's samples (rad/s, float64; int16 counts when ``spec.lsb`` > 0) for ``hours`` h."""
    rng = np.random.default_rng(seed)
    fs = spec.fs_hz
    n = int(round(hours * 3600.0 * fs))
    if spec.filt is None:
        x = rng.normal(0.0, spec.N * math.sqrt(fs), n)
    else:
        f = spec.filt
        warm = 20000
        raw = rng.normal(0.0, spec.N * math.sqrt(f.internal_hz), n * f.ratio + warm)
        b, a = f.coefficients()
        x = signal.lfilter(b, a, raw)[warm:][:: f.ratio][:n]
    if spec.sigma_a > 0:
        angle = rng.normal(0.0, spec.sigma_a, n + 1)
        x += np.diff(angle) * fs
    if spec.B > 0:
        x += kasdin_flicker(n, spec.B, rng)
    if spec.K > 0:
        x += np.cumsum(rng.normal(0.0, spec.K / math.sqrt(fs), n))
    for sigma, T in spec.gm:
        phi = math.exp(-1.0 / (fs * T))
        e = rng.normal(0.0, sigma * math.sqrt(1.0 - phi * phi), n)
        x += signal.lfilter([1.0], [1.0, -phi], e, zi=[phi * rng.normal(0.0, sigma)])[0]
    t = np.arange(n) / fs
    for amp, f0 in spec.sines:
        x += amp * np.sin(2.0 * math.pi * f0 * t + rng.uniform(0, 2 * math.pi))
    if spec.resonance:
        x += _resonance(n, fs, *spec.resonance, spec.N, rng, spec.resonance_dc)
    if spec.lsb > 0:
        return np.clip(np.rint(x / spec.lsb), -32768, 32767).astype(np.int16)
    return x


DEG = math.pi / 180.0
DPH = DEG / 3600.0  # rad/s per deg/h
ARW = DEG / 60.0  # rad/s/sqrt(Hz) per deg/sqrt(h)


def zoo() -> list[Spec]:
    """The independent channels of ``bench_zoo.py``: each IEEE-952 term alone and in realistic
    mixes, with device filters of several orders and decimation ratios, coarse and fine counts."""
    butter42 = DeviceFilter(1000.0, 5, 42.0, 2)
    butter47 = DeviceFilter(2000.0, 5, 47.0, 4)
    fold = DeviceFilter(2000.0, 16, 62.5, 2)  # 125 Hz output of a 62.5 Hz filter: folds much of its band
    rc = DeviceFilter(1000.0, 10, 20.0, 1)
    bartlett = DeviceFilter(819.2, 2, 0.0, 1, taps=4)
    hint42 = {"bandwidth_hz": 42.0}
    n1 = 0.3 * ARW
    return [
        Spec("white", 400.0, n1),
        Spec("white+flicker", 400.0, n1, B=10 * DPH),
        Spec("white+strong flicker (118 deg/h)", 400.0, n1, B=118 * DPH),
        Spec("white+flicker+walk", 400.0, n1, B=10 * DPH, K=2 * DPH / 60.0),
        Spec("white+weak walk", 200.0, n1, K=0.02 * DPH / 60.0),
        Spec("dlpf42+flicker+walk", 200.0, 0.005 * DEG, B=20 * DPH, K=5 * DPH / 60, filt=butter42, settings=hint42),
        Spec("dlpf42+strong flicker", 200.0, 0.005 * DEG, B=150 * DPH, filt=butter42, settings=hint42),
        Spec(
            "butter4 47Hz+flicker",
            400.0,
            0.014 * DEG,
            B=8 * DPH,
            K=1 * DPH / 60,
            filt=butter47,
            settings={"bandwidth_hz": 47.0},
        ),  # fmt: skip
        Spec("folding 62.5Hz@125Hz+flicker", 125.0, 1.5e-3, B=4e-5, K=2e-6, filt=fold, settings={"bandwidth_hz": 62.5}),
        Spec("rc 20Hz@100Hz+flicker", 100.0, 2e-4, B=2e-5, filt=rc, settings={"bandwidth_hz": 20.0}),
        Spec(
            "bartlett4+flicker+walk",
            409.6,
            0.0035 * DEG,
            B=6 * DPH,
            K=0.5 * DPH / 60,
            filt=bartlett,
            settings={"filter_taps": 4, "decimation": 2},
        ),  # fmt: skip
        Spec("white+gm 100s", 400.0, n1, gm=((10 * DPH, 100.0),)),
        Spec("white+gm 5s+walk", 200.0, n1, gm=((30 * DPH, 5.0),), K=2 * DPH / 60),
        Spec("white+gm 300s+flicker", 400.0, n1, B=5 * DPH, gm=((20 * DPH, 300.0),)),
        Spec("sine 7Hz+flicker", 400.0, n1, B=10 * DPH, sines=((3 * n1 * math.sqrt(400.0), 7.0),)),
        Spec("sine 0.05Hz+flicker", 200.0, n1, B=10 * DPH, sines=((20 * DPH, 0.05),)),
        Spec(
            "resonance 20Hz Q2 x2.3+flicker+walk",
            400.0,
            0.01 * DEG,
            B=8 * DPH,
            K=1 * DPH / 60,
            resonance=(20.0, 2.0, 2.3),
        ),  # fmt: skip
        Spec("resonance 35Hz Q20 x30+flicker", 400.0, n1, B=10 * DPH, resonance=(35.0, 20.0, 30.0)),
        Spec("int16 coarse (1.5 lsb)+flicker", 200.0, n1, B=10 * DPH, lsb=n1 * math.sqrt(200.0) / 1.5),
        Spec(
            "int16 8 lsb dlpf+flicker+walk",
            200.0,
            0.005 * DEG,
            B=20 * DPH,
            K=3 * DPH / 60,
            filt=butter42,
            lsb=0.005 * DEG * math.sqrt(200.0) / 8,
            settings=hint42,
        ),  # fmt: skip
        Spec("white angle+white+flicker", 400.0, n1, B=10 * DPH, sigma_a=2 * n1 / math.sqrt(400.0)),
        Spec("fog 100Hz white+tiny flicker", 100.0, 0.0667 / 60 * DEG, B=0.05 * DPH, K=0.005 * DPH / 60),
    ]


def resonance_zoo() -> list[Spec]:
    """Resonances beside the zoo's two (issue 32): IEEE 952's second-order exponentially correlated noise
    with its power at 0 Hz, a zero-DC mode at another Q, and a broad hump like the ADIS16405 z gyro's
    (10 .. 30 Hz at 2.3 x the white PSD) at its 819.2 Hz rate with its noise density."""
    n1 = 0.3 * ARW
    return [
        Spec("2nd-order GM 35Hz Q20 x30 (DC kept)+flicker", 400.0, n1, B=10 * DPH, resonance=(35.0, 20.0, 30.0),
             resonance_dc=True),
        Spec("resonance 60Hz Q5 x8+flicker+walk", 400.0, n1, B=5 * DPH, K=1 * DPH / 60, resonance=(60.0, 5.0, 8.0)),
        Spec("ADIS16405-like hump 18Hz Q1 x2.3+flicker+walk", 819.2, 0.05 * DEG, B=25 * DPH, K=3 * DPH / 60,
             resonance=(18.0, 1.0, 2.3)),
    ]  # fmt: skip
