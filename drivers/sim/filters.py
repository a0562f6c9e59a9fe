"""Output filters of the simulated chips: one description per chip and setting, and its engine.

Why: a real sensor low-pass filters, averages or decimates its samples before it outputs
them, so its PSD rolls off below Nyquist and its Allan deviation bends below the
white-noise line at the shortest cluster times. A simulator that skips this gives the
estimators cleaner data than any real sensor. Each :class:`ChipFilter` says what the
chip's configured registers select - structure, coefficients at the chip's internal
rate, decimation, its -3 dB bandwidth and delay with the datasheet numbers - and
:class:`FilterRun` applies it to the white noise an axis generates at that internal
rate. The chip simulators (``--sim-level bus``) build the description from their
registers, the model level (``acquisition/modelsim.py``) from the device's settings
(:func:`for_device`); both go through :mod:`imustation.drivers.sim.sources`, so they
give the same samples for the same seed. docs/simulation.md has the table.

Where a datasheet gives only a bandwidth and a delay (InvenSense DLPF_CFG), the filter
is a two-pole low-pass (bilinear transform, pre-warped so the -3 dB point is exact)
whose damping is solved so that its group delay at DC equals the datasheet delay, plus
whole samples of pure delay where the datasheet delay is longer than a Butterworth's;
a delay shorter than a single pole's (2 pi BW delay < 1) has no low-pass of this kind
without a resonance, and gets the single pole (error listed in docs/simulation.md).
A pure delay does not change a stationary noise stream, so the generator leaves it out
and only the description carries it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from imustation.drivers.adis16448 import INTERNAL_RATE_HZ as ADIS_INTERNAL_RATE_HZ  # the chip's register table

#: white-noise samples per numpy step inside a block (bounded memory at high ratios)
CHUNK_INTERNAL = 1 << 18
#: the filter state starts stationary: the pre-roll lasts until the impulse response is below this
_SETTLED = 1e-9
_SQRT2 = math.sqrt(2.0)
#: -3 dB point of a mean over an interval T, in 1/T: sinc(x) = 1/sqrt(2)
_SINC_HALF_POWER = 0.44294647068945225


@dataclass(frozen=True)
class ChipFilter:
    """What a chip does to its samples between its internal sampling and its output.

    ``ratio`` internal samples per output sample; the IIR ``b``/``a`` then the moving
    averages ``boxcars`` (taps) run at ``fs_out_hz * ratio`` and every ``ratio``-th result
    (the newest of its interval) is output. ``interval_mean``: the chip outputs the mean of
    the continuous signal over each output interval (no internal rate needed). Bandwidth
    (Hz) and delay (s) are the datasheet's (``None`` where it gives the structure itself);
    ``pure_delay`` whole internal samples belong to the description only.
    """

    chip: str
    fs_out_hz: float
    ratio: int = 1
    b: tuple[float, ...] = (1.0,)
    a: tuple[float, ...] = (1.0,)
    boxcars: tuple[int, ...] = ()
    interval_mean: bool = False
    pure_delay: int = 0
    bandwidth_hz: float | None = None
    delay_s: float | None = None
    structure: str = ""
    source: str = ""

    @property
    def fs_internal_hz(self) -> float:
        return self.fs_out_hz * self.ratio

    @property
    def white_equivalent(self) -> bool:
        """Whether white noise comes out white with the same density (a mean over each
        output interval): then drawing it at the output rate is the same stream in law."""
        if self.interval_mean:
            return True
        no_iir = self.b == (1.0,) and self.a == (1.0,)
        return no_iir and self.boxcars == ((self.ratio,) if self.ratio > 1 else ())

    def response(self, f_hz: np.ndarray) -> np.ndarray:
        """Complex response at frequencies ``f_hz`` (Hz) of the chain at the internal rate, pure delay excluded."""
        f = np.asarray(f_hz, dtype=float)
        if self.interval_mean:
            return np.sinc(f / self.fs_out_hz) * np.exp(-1j * np.pi * f / self.fs_out_hz)
        w = 2.0 * np.pi * f / self.fs_internal_hz
        z = np.exp(-1j * w)
        h = np.polyval(self.b[::-1], z) / np.polyval(self.a[::-1], z)
        for n in self.boxcars:
            with np.errstate(invalid="ignore", divide="ignore"):
                box = np.sin(n * w / 2.0) / (n * np.sin(w / 2.0))
            h = h * np.where(np.isclose(np.sin(w / 2.0), 0.0), 1.0, box) * np.exp(-1j * w * (n - 1) / 2.0)
        return h

    def output_gain(self, f_hz: np.ndarray) -> np.ndarray:
        """Output PSD of white input over its density, at output frequencies ``f_hz`` (0..fs_out/2):
        the ``ratio`` aliases of ``|H|^2`` that decimation folds onto each frequency."""
        f = np.asarray(f_hz, dtype=float)
        if self.interval_mean:
            return np.ones_like(f)  # sum over k of sinc^2(f/fs + k) = 1
        return sum(np.abs(self.response(f + k * self.fs_out_hz)) ** 2 for k in range(self.ratio))

    def model_bandwidth_hz(self) -> float:
        """-3 dB frequency of the implemented chain (before decimation), Hz."""
        top = self.fs_out_hz if self.interval_mean else self.fs_internal_hz / 2.0
        f = np.linspace(0.0, top, 20001)
        below = np.nonzero(np.abs(self.response(f)) ** 2 < 0.5)[0]
        if not len(below):
            return top
        i = below[0]
        from scipy.optimize import brentq

        return float(brentq(lambda x: abs(self.response(np.array([x]))[0]) ** 2 - 0.5, f[i - 1], f[i]))

    def model_delay_s(self) -> float:
        """Group delay at DC of the implemented chain plus the description's pure delay, s."""
        if self.interval_mean:
            return 0.5 / self.fs_out_hz
        b, a = np.asarray(self.b), np.asarray(self.a)
        k = np.arange(max(len(b), len(a)))
        iir = np.sum(k[: len(b)] * b) / np.sum(b) - np.sum(k[: len(a)] * a) / np.sum(a)
        fir = sum((n - 1) / 2.0 for n in self.boxcars)
        return (iir + fir + self.pure_delay) / self.fs_internal_hz


class FilterRun:
    """One axis's white noise drawn at the internal rate and put through a :class:`ChipFilter`.

    Parameters
    ----------
    chip_filter : the description (not :attr:`~ChipFilter.white_equivalent`).
    rng : the axis's generator; the stream continues it.
    density : two-sided white-noise density (rad/s/sqrt(Hz) or m/s^2/sqrt(Hz)).

    The state (IIR, moving-average tails) is kept between calls and starts stationary
    (a pre-roll of noise, drawn first), so the stream does not depend on how it is asked.
    """

    def __init__(self, chip_filter: ChipFilter, rng: np.random.Generator, density: float):
        from scipy.signal import lfilter  # here: scipy.signal costs ~1 s to import; simulators start without it

        self._lfilter = lfilter
        self.f = chip_filter
        self.rng = rng
        self.sigma = float(density) * math.sqrt(chip_filter.fs_internal_hz)
        self._b = np.asarray(chip_filter.b, dtype=float)
        self._a = np.asarray(chip_filter.a, dtype=float)
        self._iir = not (len(self._b) == len(self._a) == 1)
        self._zi = np.zeros(max(len(self._b), len(self._a)) - 1)
        self._tails = [np.zeros(n - 1) for n in chip_filter.boxcars if n > 1]
        self._taps = [n for n in chip_filter.boxcars if n > 1]
        self._since = 0  # internal samples since the last output sample
        self._run(self.rng.normal(0.0, self.sigma, preroll(chip_filter)))

    def _run(self, x: np.ndarray) -> np.ndarray:
        if self._iir:
            x, self._zi = self._lfilter(self._b, self._a, x, zi=self._zi)
        for i, n in enumerate(self._taps):
            z = np.concatenate([self._tails[i], x])
            c = np.cumsum(z)
            x = np.empty(len(z) - n + 1)
            x[0] = c[n - 1]
            np.subtract(c[n:], c[:-n], out=x[1:])
            x /= n
            self._tails[i] = z[len(z) - (n - 1) :]
        return x

    def next(self, n: int) -> np.ndarray:
        """The next ``n`` output samples (the newest filtered sample of each output interval)."""
        r = self.f.ratio
        todo = n * r
        parts = []
        while todo:  # a few numpy steps per block, never per sample; bounded memory at any ratio
            m = min(todo, CHUNK_INTERNAL)
            y = self._run(self.rng.normal(0.0, self.sigma, m))
            parts.append(y[r - 1 - self._since :: r])
            self._since = (self._since + m) % r
            todo -= m
        return parts[0] if len(parts) == 1 else np.concatenate(parts)


def preroll(chip_filter: ChipFilter) -> int:
    """Internal samples that bring the filter state to stationarity (IIR settled, tails full)."""
    n = sum(k - 1 for k in chip_filter.boxcars if k > 1)
    if len(chip_filter.a) > 1:
        r = float(np.max(np.abs(np.roots(chip_filter.a))))
        n += len(chip_filter.a) + (int(math.ceil(math.log(_SETTLED) / math.log(r))) if r > 0 else 0)
    return n


# --- design ---------------------------------------------------------------------------


def _damping_delay_product(zeta: float) -> float:
    """Omega_c x DC group delay of 1/(s^2 + 2 zeta wn s + wn^2) scaled to -3 dB at Omega_c."""
    c = 1.0 - 2.0 * zeta * zeta
    u = math.sqrt(c + math.sqrt(c * c + 1.0))  # -3 dB frequency over wn
    return 2.0 * zeta * u


_ZETA_MAX = 1e3


def design_lowpass(bandwidth_hz: float, delay_s: float | None, fs_hz: float) -> tuple[tuple, tuple, int, str]:
    """A low-order low-pass at ``fs_hz`` with -3 dB at ``bandwidth_hz`` and DC group delay ``delay_s``.

    Returns ``(b, a, pure_delay_samples, structure)``. Without a delay: a 2nd-order
    Butterworth. The bilinear transform is pre-warped at the bandwidth (exact -3 dB) and
    keeps the analog DC group delay. See the module docstring for the choice.
    """
    from scipy.signal import bilinear

    if bandwidth_hz >= 0.4999 * fs_hz:
        return (1.0,), (1.0,), 0, "none (bandwidth at Nyquist)"
    wc = 2.0 * fs_hz * math.tan(math.pi * bandwidth_hz / fs_hz)

    def section(d: float) -> tuple[str, float, float]:
        """(kind, zeta, achieved delay) of the two-pole/one-pole part for a wanted delay ``d``."""
        p = wc * d
        if p >= _SQRT2:
            return "butterworth", 1.0 / _SQRT2, _SQRT2 / wc
        if p > _damping_delay_product(_ZETA_MAX):
            from scipy.optimize import brentq

            zeta = brentq(lambda z: _damping_delay_product(z) - p, 1.0 / _SQRT2, _ZETA_MAX, xtol=1e-12)
            return "two-pole", zeta, d
        return "one-pole", math.inf, 1.0 / wc

    if delay_s is None:
        kind, zeta, pure = "butterworth", 1.0 / _SQRT2, 0
    else:
        best = None
        for d in range(int(math.ceil(delay_s * fs_hz)) + 1):
            kind, zeta, got = section(delay_s - d / fs_hz) if delay_s - d / fs_hz > 0 else section(0.0)
            err = abs(got + d / fs_hz - delay_s)
            if best is None or err < best[0] - 1e-12:
                best = (err, kind, zeta, d)
        _, kind, zeta, pure = best
    if kind == "one-pole":
        b, a = bilinear([wc], [1.0, wc], fs_hz)
        text = "1st-order low-pass"
    else:
        u = math.sqrt((1 - 2 * zeta**2) + math.sqrt((1 - 2 * zeta**2) ** 2 + 1))
        wn = wc / u
        b, a = bilinear([wn * wn], [1.0, 2.0 * zeta * wn, wn * wn], fs_hz)
        text = "2nd-order Butterworth" if kind == "butterworth" else f"2nd-order low-pass, damping {zeta:.3f}"
    if pure:
        text += f" + {pure} sample(s) pure delay"
    return tuple(float(x) for x in b), tuple(float(x) for x in a), pure, text


# --- the chips ------------------------------------------------------------------------------

#: BMX055 gyro (BMG160) internal data rate, Hz: the unfiltered ODR of BW code 0x00 (BMX055 datasheet, gyro BW)
BMG160_INTERNAL_HZ = 2000.0
#: BMX055 accelerometer (BMA2x2) internal rate, Hz: the 0.5 ms update time of PMU_BW 0x0F (BMX055 datasheet)
BMA2X2_INTERNAL_HZ = 2000.0
#: InvenSense accelerometer output rate, Hz (MPU-6000/6050 Register Map rev 4.2, register 25)
INVENSENSE_ACCEL_HZ = 1000.0

#: MPU-6050/9150 DLPF_CFG delays, ms: code -> (gyro, accel) (MPU-6000/6050 Register Map rev 4.2, register 26)
DELAYS_6050_MS = {0: (0.98, 0.0), 1: (1.9, 2.0), 2: (2.8, 3.0), 3: (4.8, 4.9), 4: (8.3, 8.5), 5: (13.4, 13.8),
                  6: (18.6, 19.0)}  # fmt: skip
#: MPU-6500 delays, ms: gyro DLPF_CFG (FCHOICE_B = 00) from the MPU-9250 Register Map rev 1.4,
#: register 26 (the MPU-9250 holds the MPU-6500 die; UNCONFIRMED for the MPU-6500 itself);
#: accel A_DLPF_CFG from the MPU-6500 Register Map, register 29 (UNCONFIRMED: not re-checked)
DELAYS_6500_MS = {0: (0.97, 1.94), 1: (2.9, 5.80), 2: (3.9, 7.80), 3: (5.9, 11.80), 4: (9.9, 19.80),
                  5: (17.85, 35.70), 6: (33.48, 66.96), 7: (0.17, 1.94)}  # fmt: skip


@cache
def bmg160(code: int) -> ChipFilter:
    """BMX055 gyro, BW register code 0..7 (ODR and -3 dB bandwidth: the driver's table)."""
    from imustation.drivers import bmx055 as chip

    row = next(r for r in chip.ODR_TABLE if r.code == code)
    ratio = round(BMG160_INTERNAL_HZ / row.odr_hz)
    b, a, pure, text = design_lowpass(row.bandwidth_hz, None, BMG160_INTERNAL_HZ)
    return ChipFilter(
        f"BMX055 gyro BW 0x{code:02X}", float(row.odr_hz), ratio, b, a, pure_delay=pure,
        bandwidth_hz=float(row.bandwidth_hz), structure=f"{text} at 2 kHz{_kept(ratio)}",
        source="BMX055 datasheet, gyro register 0x10 (BW); structure and delay: our choice",
    )  # fmt: skip


@cache
def bma2x2(code: int) -> ChipFilter:
    """BMX055 accelerometer, PMU_BW code 0x08..0x0F (bandwidth = rate / 2: the driver's table)."""
    from imustation.drivers import bmx055_accel as chip

    row = next(r for r in chip.BW_TABLE if r.code == code)
    ratio = round(BMA2X2_INTERNAL_HZ / row.odr_hz)
    b, a, pure, text = design_lowpass(row.bandwidth_hz, None, BMA2X2_INTERNAL_HZ)
    return ChipFilter(
        f"BMX055 accel PMU_BW 0x{code:02X}", float(row.odr_hz), ratio, b, a, pure_delay=pure,
        bandwidth_hz=float(row.bandwidth_hz), structure=f"{text} at 2 kHz{_kept(ratio)}",
        source="BMX055 datasheet, accelerometer register 0x10 (PMU_BW); structure and delay: our choice",
    )  # fmt: skip


def _kept(ratio: int) -> str:
    return f", 1 sample of every {ratio} kept" if ratio > 1 else ""


def _unfiltered(chip: str, fs_hz: float, why: str) -> ChipFilter:
    return ChipFilter(chip, float(fs_hz), structure=f"none ({why})", source="not simulated")


@cache
def invensense_gyro(driver: str, dlpf_cfg: int, smplrt_div: int, fchoice_b: int = 0) -> ChipFilter:
    """MPU-9150 / MPU-6500 gyro: CONFIG.DLPF_CFG, SMPLRT_DIV (and the 6500's GYRO_CONFIG.FCHOICE_B)."""
    from imustation.drivers.invensense import VARIANTS

    variant = VARIANTS[driver]
    row = next((r for r in variant.dlpf if r.code == dlpf_cfg), None)
    if fchoice_b or row is None:
        fs = (32000.0 if fchoice_b else 8000.0) / (1 + smplrt_div)
        return _unfiltered(f"{variant.model} gyro", fs, "FCHOICE_B bypass" if fchoice_b else "reserved DLPF_CFG")
    delays = DELAYS_6500_MS if variant.has_accel_config2 else DELAYS_6050_MS
    ratio = 1 + smplrt_div if row.div_applies else 1  # MPU-6500: no divider for DLPF_CFG 0 and 7 (Register 25)
    delay = delays[dlpf_cfg][0] * 1e-3
    b, a, pure, text = design_lowpass(row.gyro_bw_hz, delay, row.internal_hz)
    return ChipFilter(
        f"{variant.model} gyro DLPF_CFG {dlpf_cfg}", row.internal_hz / ratio, ratio, b, a, pure_delay=pure,
        bandwidth_hz=float(row.gyro_bw_hz), delay_s=delay,
        structure=f"{text} at {row.internal_hz / 1000:g} kHz{_kept(ratio)}",
        source=("MPU-9250 Register Map rev 1.4, register 26 (UNCONFIRMED for the MPU-6500)" if variant.has_accel_config2
                else "MPU-6000/6050 Register Map rev 4.2, register 26"),
    )  # fmt: skip


@cache
def invensense_accel(driver: str, dlpf_cfg: int, fs_out_hz: float, fchoice_b: int = 0) -> ChipFilter:
    """MPU-9150 accel (CONFIG.DLPF_CFG) / MPU-6500 accel (ACCEL_CONFIG2.A_DLPF_CFG, A_FCHOICE_B),
    output at ``fs_out_hz``."""
    from imustation.drivers.invensense import VARIANTS

    variant = VARIANTS[driver]
    row = next((r for r in variant.dlpf if r.code == dlpf_cfg), None)
    if fchoice_b or row is None:
        return _unfiltered(f"{variant.model} accel", fs_out_hz, "A_FCHOICE_B bypass" if fchoice_b else "reserved code")
    delays = DELAYS_6500_MS if variant.has_accel_config2 else DELAYS_6050_MS
    delay = delays[dlpf_cfg][1] * 1e-3
    ratio = INVENSENSE_ACCEL_HZ / fs_out_hz
    if abs(ratio - round(ratio)) < 1e-9:
        ratio, fs_int, where = round(ratio), INVENSENSE_ACCEL_HZ, f"at 1 kHz{_kept(round(ratio))}"
    else:
        # the 1 kHz accelerometer sampled at a rate it is no multiple of: designed at the output rate instead
        ratio, fs_int, where = 1, fs_out_hz, f"at the {fs_out_hz:g} Hz output rate (1 kHz is no multiple of it)"
    b, a, pure, text = design_lowpass(row.accel_bw_hz, delay, fs_int)
    return ChipFilter(
        f"{variant.model} accel DLPF {dlpf_cfg}", float(fs_out_hz), ratio, b, a, pure_delay=pure,
        bandwidth_hz=float(row.accel_bw_hz), delay_s=delay, structure=f"{text} {where}",
        source=("MPU-6500 Register Map, register 29 (UNCONFIRMED)" if variant.has_accel_config2
                else "MPU-6000/6050 Register Map rev 4.2, register 26"),
    )  # fmt: skip


@cache
def adis16448(decimation: int, taps: int) -> ChipFilter:
    """ADIS16448: SENS_AVG Bartlett FIR (two cascaded ``taps``-tap averages, taps = 2^B) at 819.2 Hz,
    then SMPL_PRD's average-and-decimate over 2^D samples (ADIS16448 datasheet, SENS_AVG / SMPL_PRD)."""
    ratio = 2**decimation
    boxcars = tuple(n for n in (taps, taps, ratio) if n > 1)
    text = f"Bartlett FIR 2 x {taps} taps" if taps > 1 else "no Bartlett FIR"
    return ChipFilter(
        f"ADIS16448 D={decimation} taps={taps}", ADIS_INTERNAL_RATE_HZ / ratio, ratio, boxcars=boxcars,
        structure=f"{text}, then the mean of {ratio} sample(s) at 819.2 Hz",
        source="ADIS16448 datasheet, SENS_AVG (0x38) / SMPL_PRD (0x36)",
    )  # fmt: skip


@cache
def interval_mean(chip: str, fs_out_hz: float) -> ChipFilter:
    """A chip that outputs the mean rate over each output interval (Xsens MTi, KVH DSP-3000)."""
    return ChipFilter(
        chip, float(fs_out_hz), interval_mean=True, bandwidth_hz=_SINC_HALF_POWER * fs_out_hz, delay_s=0.5 / fs_out_hz,
        structure="mean over each output interval",
        source="the rate output is the angle over the output interval divided by it (UNCONFIRMED)",
    )  # fmt: skip


def for_device(driver: str, settings: Mapping[str, Any]) -> dict[str, ChipFilter]:
    """Channel -> the filter a device's validated settings select (what its driver writes to the chip)."""
    if driver == "bmx055":
        from imustation.drivers.bmx055 import odr_row

        return {"gyro": bmg160(odr_row(settings["rate_hz"], settings["bandwidth_hz"]).code)}
    if driver == "bmx055_accel":
        from imustation.drivers.bmx055_accel import bw_row

        return {"accel": bma2x2(bw_row(settings["rate_hz"]).code)}
    if driver in ("mpu9150", "mpu6500"):
        from imustation.drivers.invensense import VARIANTS, sample_divider

        row, div = sample_divider(VARIANTS[driver], settings["rate_hz"], settings["bandwidth_hz"])
        rate = row.internal_hz / (1 + div)
        # the driver writes the DLPF code to A_DLPF_CFG too (6500)
        return {
            "gyro": invensense_gyro(driver, row.code, div),
            "accel": invensense_accel(driver, row.code, min(rate, INVENSENSE_ACCEL_HZ)),
        }
    if driver == "adis16448":
        return {"gyro": adis16448(int(settings["decimation"]), int(settings["filter_taps"]))}
    if driver == "mti":
        return {"gyro": interval_mean("Xsens MTi", float(settings["rate_hz"]))}
    if driver == "dsp3000":
        return {"gyro": interval_mean("KVH DSP-3000", float(settings["rate_hz"]))}
    return {}


def every_setting() -> list[ChipFilter]:
    """Every chip and setting (output at the internal rate where the rate is free): the docs table."""
    from imustation.drivers import bmx055, bmx055_accel, invensense

    out = [bmg160(r.code) for r in bmx055.ODR_TABLE]
    out += [bma2x2(r.code) for r in bmx055_accel.BW_TABLE]
    for driver, variant in invensense.VARIANTS.items():
        out += [invensense_gyro(driver, r.code, 0) for r in variant.dlpf]
        out += [invensense_accel(driver, r.code, INVENSENSE_ACCEL_HZ) for r in variant.dlpf]
    out += [adis16448(0, 2**b) for b in range(8)] + [adis16448(d, 1) for d in range(1, 4)]
    out += [interval_mean("Xsens MTi", 400.0), interval_mean("KVH DSP-3000", 100.0)]
    return out
