"""Noise parameters for visual-inertial estimators: Kalibr, OpenVINS, VINS-Fusion, ORB-SLAM3.

All four tools model each axis as white noise plus a random-walk bias
(docs/reference/noise-formulas.md §3, Kalibr wiki "IMU-Noise-Model"):

* white:  E[n(t1) n(t2)] = sigma_g^2 delta(t1 - t2), ``sigma_g`` in rad/s/sqrt(Hz)
  (m/s^2/sqrt(Hz) for accelerometers) — the continuous-time density, i.e. the
  IEEE-952 ``N`` and the paper's ``sigma_w``; **not** ``N * sqrt(rate)``.
* bias:   db/dt = sigma_bg w(t), ``sigma_bg`` in rad/s^2/sqrt(Hz) (m/s^3/sqrt(Hz)) —
  the IEEE-952 rate random walk ``K`` (not ``K/sqrt 3``, not ``B``).

The identified models here usually have a first-order Gauss-Markov bias
(db/dt = -b/tau_b + w, PSD(w) = sigma_b^2), which these tools cannot express.
Two documented conversions to a random-walk figure (``rw``):

``"diffusion"`` (default, conservative)
    ``sigma_bg = sqrt(sigma_k^2 + sum_i sigma_b_i^2)``: the short-time limit —
    for tau << tau_b the Gauss-Markov Allan variance is ``sigma_b^2 tau / 3``,
    exactly a random walk with ``K = sigma_b``. At every tau the random walk's
    Allan variance is at least the Gauss-Markov one (the GM saturates at
    ``tau ~ tau_b`` and then falls), so the filter never under-states bias drift.
``"tau_b"``
    each Gauss-Markov term is replaced by the random walk whose Allan variance
    equals it at ``tau = tau_b``: ``K_i^2 = 3 AVAR_GM(tau_b) / tau_b = 0.504 sigma_b^2``
    (``K_i = 0.710 sigma_b``). Matches the drift at the bias time scale, still
    over-states it beyond; under-states nothing by more than 1/0.71 below tau_b.

A bias instability ``B`` (flicker, Allan floor ``0.664 B``; the automatic model choice
fits it) enters both as the random walk whose Allan deviation meets the floor where
the floor meets the white-noise line (``tau_x = sigma_w^2 / (0.664 B)^2``):
``K_B = 0.664 B sqrt(3 / tau_x) = sqrt(3) (0.664 B)^2 / sigma_w``. Below ``tau_x`` the white
noise dominates anyway; beyond it the random walk over-states the floor.

With ``source="ieee"`` the densities come from the IEEE-952 fit of the Allan
curve instead: ``sigma_g = N``, ``sigma_bg = K``.

Each tool takes one value per sensor, not per axis: per quantity the largest value among
the axes whose fit vouches for it is written (:func:`choose_axes`: conservative among the
trustworthy ones; none left: :class:`Untrustworthy`, unless forced); the rule, the axes left
out and every axis's value go into the header comments.

**Inflation for the filter** (:func:`inflate`, ``export --inflate``): the measured
densities describe a static sensor on a bench; a moving platform adds vibration,
temperature change, scale-factor and misalignment errors and time-stamp jitter that
the filter sees as extra noise, so VIO users routinely multiply the measured values
by about 10 (up to 20) before use (Kalibr wiki "IMU-Noise-Model"; asked in
ethz-asl/kalibr#663 and ori-drs/allan_variance_ros#44). It is never applied unless
asked for: the factors, the measured and the written values are all in the header
comments.

Key names and file conventions followed (public code, checked):

* Kalibr: ``kalibr_common/ConfigReader.py`` ``ImuParameters`` (ethz-asl/kalibr;
  docs/reference/noise-formulas.md §3.2): flat ``rostopic, update_rate, *_noise_density, *_random_walk``.
* OpenVINS: ``config/euroc_mav/kalibr_imu_chain.yaml`` (rpng/open_vins): the
  Kalibr keys under ``imu0:`` plus ``time_offset``, OpenCV ``%YAML:1.0`` header.
* VINS-Fusion: ``vins_estimator/src/estimator/parameters.cpp`` (reads ``imu``,
  ``imu_topic``, ``acc_n``, ``acc_w``, ``gyr_n``, ``gyr_w``, ``g_norm``) and
  ``config/euroc/euroc_stereo_imu_config.yaml`` (HKUST-Aerial-Robotics/VINS-Fusion);
  the EuRoC config puts continuous-time densities there, as written here.
* ORB-SLAM3: ``Examples/Stereo-Inertial/EuRoC.yaml`` (UZ-SLAMLab/ORB_SLAM3):
  ``IMU.NoiseGyro, IMU.NoiseAcc, IMU.GyroWalk, IMU.AccWalk`` (the EuRoC Kalibr
  values) and integer ``IMU.Frequency``.

The VINS-Fusion and ORB-SLAM3 files are fragments to merge into a full
camera configuration. This module only builds dicts and text; no file I/O.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

from imustation.analysis.estimators.models.noise_models import GaussMarkov
from imustation.analysis.estimators.models.sensor_terms import FLICKER_FLOOR
from imustation.analysis.estimators.selection.adequacy import NO_FIT
from imustation.analysis.pipeline.channel import ChannelAnalysis, DegenerateChannel, analyze_channel
from imustation.analysis.pipeline.choices import EXPORT_FORMATS as FORMATS
from imustation.analysis.pipeline.choices import EXPORT_SOURCES as SOURCES
from imustation.analysis.pipeline.choices import RW_CONVERSIONS
from imustation.analysis.pipeline.loaders import Channel
from imustation.analysis.pipeline.warmup import META_KEY as WARMUP_META_KEY
from imustation.analysis.reports.numbers import interval
from imustation.analysis.reports.tables import UNIDENTIFIED_RATIO, density_flag
from imustation.analysis.reports.wording import user_text
from imustation.errors import InputError
from imustation.units import G0

#: a Gauss-Markov bias decorrelating faster than this (s) looks like white noise at the time
#: scales VIO filters integrate over (camera frame intervals and longer): its random-walk
#: figure is flagged (typically a record too short to identify the slow bias)
WHITE_LIKE_TAU_B_S = 1.0
#: formats read by OpenCV's cv::FileStorage, which wants this first line
_OPENCV_DIRECTIVE = "%YAML:1.0"


def gm_to_rw_at_tau_b(sigma_b: float, tau_b: float) -> float:
    """Random-walk density K (unit/s/sqrt(Hz)) with the Gauss-Markov's Allan variance at tau = tau_b."""
    return math.sqrt(3.0 * float(GaussMarkov(sigma_b, tau_b).avar(tau_b)) / tau_b)


def walk_terms(params: dict[str, float]) -> str:
    """Which terms of an ML_i parameter dict make :func:`random_walk_from_params`, as the export's comment
    names them: "rate random walk K", "bias instability B", "Gauss-Markov sigma_b" (comma-joined)."""
    terms = []
    if params.get("sigma_k", 0.0) > 0:
        terms.append("rate random walk K")
    if params.get("B", 0.0) > 0 and params.get("sigma_w", 0.0) > 0:
        terms.append("bias instability B")
    if any(k.startswith("sigma_b") and math.isfinite(v) and v > 0 for k, v in params.items()):
        terms.append("Gauss-Markov sigma_b")
    return ", ".join(terms)


def random_walk_from_params(params: dict[str, float], rw: str = "diffusion") -> float:
    """Random-walk figure (unit/s/sqrt(Hz)) from an ML_i parameter dict (see module docstring).

    ``params``: ``sigma_k`` and/or ``sigma_b``/``tau_b`` (or ``sigma_b1, tau_b1, ...``) and/or
    ``B`` with ``sigma_w``, SI.
    """
    if rw not in RW_CONVERSIONS:
        raise InputError(f"random-walk conversion {rw!r}: use one of {', '.join(RW_CONVERSIONS)}")
    total = params.get("sigma_k", 0.0) ** 2
    B, sigma_w = params.get("B", 0.0), params.get("sigma_w", 0.0)
    if B > 0 and sigma_w > 0:
        total += 3.0 * (FLICKER_FLOOR * B) ** 4 / sigma_w**2
    gms = [(params[k], params["tau_b" + k[len("sigma_b") :]]) for k in params if k.startswith("sigma_b")]
    for sigma_b, tau_b in gms:
        if not (math.isfinite(sigma_b) and sigma_b > 0):
            continue
        if rw == "diffusion" or math.isinf(tau_b):
            total += sigma_b**2
        else:
            total += gm_to_rw_at_tau_b(sigma_b, tau_b) ** 2
    return math.sqrt(total)


@dataclass(frozen=True)
class AxisNoise:
    """One axis: white-noise density (unit/sqrt(Hz)) and random-walk density (unit/s/sqrt(Hz)).

    ``noise_untrusted`` / ``walk_untrusted``: why no value of that quantity may be written from
    this axis ("" when it may): its model does not fit the Allan deviation, a parameter sits at its
    search bound, the fit did not converge, or the value is not identified (its interval missing or
    far too wide; a bias faster than :data:`WHITE_LIKE_TAU_B_S`). ``warning`` / ``noise_warning``
    also hold doubts that do not forbid the value (a noise density whose interval is wider than
    a factor 1.1 but identified).
    """

    channel: str
    noise_density: float
    random_walk: float
    #: why the random-walk figure is doubtful ("" when it is not)
    warning: str = ""
    #: why the noise-density figure is doubtful ("" when it is not): the model does not fit the Allan
    #: deviation, or its interval is wide (slow terms at the fine scales, docs/noise-model.md "Limit")
    noise_warning: str = ""
    noise_untrusted: str = ""
    walk_untrusted: str = ""
    #: the model terms the random walk is made of ("" when it is the Allan fit's K): a bias instability
    #: or a Gauss-Markov bias converted is not the rate random walk K that analyze's table shows
    walk_terms: str = ""

    @property
    def axis(self) -> str:
        return self.channel.rsplit("/", 1)[-1]


class Untrustworthy(InputError):
    """Nothing a fit vouches for is left of a sensor's quantity: no file is written (``--force`` writes it)."""


#: quantities of an export, as the file's comments name them
QUANTITY_NAMES = {"noise": "noise density", "walk": "random walk"}


@dataclass(frozen=True)
class SensorNoise:
    """One sensor (gyroscope or accelerometer) of a device. Per quantity the exported value is the
    largest among the axes whose fit vouches for it (``noise_from`` / ``walk_from``: their channel
    ids; every axis when built without them), times the inflation factors ``inflate_noise`` and
    ``inflate_walk`` (1: the measured value). ``forced``: the quantities written from axes no fit
    vouches for (``export --force``)."""

    kind: str
    rate_hz: float
    axes: tuple[AxisNoise, ...]
    source: str
    rw: str
    inflate_noise: float = 1.0
    inflate_walk: float = 1.0
    noise_from: tuple[str, ...] | None = None
    walk_from: tuple[str, ...] | None = None
    forced: tuple[str, ...] = ()

    def _chosen(self, ids: tuple[str, ...] | None) -> list[AxisNoise]:
        return [a for a in self.axes if ids is None or a.channel in ids]

    @property
    def measured_noise_density(self) -> float:
        return max(a.noise_density for a in self._chosen(self.noise_from))

    @property
    def measured_random_walk(self) -> float:
        return max(a.random_walk for a in self._chosen(self.walk_from))

    @property
    def noise_density(self) -> float:
        """The value written: the measured largest trusted axis times ``inflate_noise``."""
        return self.measured_noise_density * self.inflate_noise

    @property
    def random_walk(self) -> float:
        """The value written: the measured largest trusted axis times ``inflate_walk``."""
        return self.measured_random_walk * self.inflate_walk

    @property
    def inflated(self) -> bool:
        return self.inflate_noise != 1.0 or self.inflate_walk != 1.0

    def rule(self, quantity: str) -> str:
        """How the written value of ``quantity`` ('noise'/'walk') was chosen, for the file's comments."""
        ids = self.noise_from if quantity == "noise" else self.walk_from
        used = self._chosen(ids)
        axes = ", ".join(a.axis for a in used)
        left = [a for a in self.axes if a not in used]
        why = "; ".join(
            f"{a.axis} left out: {a.noise_untrusted if quantity == 'noise' else a.walk_untrusted}" for a in left
        )
        name = f"{self.kind} {QUANTITY_NAMES[quantity]}"
        if quantity in self.forced:
            return f"FORCED {name}: the largest of every axis ({axes}); no fit vouches for it (--force)"
        return f"{name}: the largest of the axes whose fit vouches for it ({axes})" + (f"; {why}" if why else "")


def parse_inflation(text: str) -> tuple[float, float]:
    """``"10"`` -> (10, 10); ``"10,5"`` -> noise density x10, random walk x5. Factors must be >= 1."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        factors = [float(p) for p in parts]
    except ValueError:
        factors = []
    if len(factors) not in (1, 2) or not all(math.isfinite(f) and f >= 1.0 for f in factors):
        raise InputError(f"--inflate {text!r}: give one factor >= 1 (e.g. 10) or two, noise and random walk (10,5)")
    return (factors[0], factors[-1])


def inflate(sensor: SensorNoise, noise: float, walk: float) -> SensorNoise:
    """``sensor`` with its written values inflated by ``noise`` (density) and ``walk`` (random walk)."""
    return replace(sensor, inflate_noise=float(noise), inflate_walk=float(walk))


def inflate_sensors(
    gyro: SensorNoise, accel: SensorNoise | None, noise: float, walk: float
) -> tuple[SensorNoise, SensorNoise | None]:
    """:func:`inflate` of the gyroscope and the accelerometer (if any) by the same factors."""
    return inflate(gyro, noise, walk), None if accel is None else inflate(accel, noise, walk)


#: a bias parameter whose 90 % interval spans more than this factor is "poorly determined"
WIDE_INTERVAL = 10.0


def _noise_doubts(res: ChannelAnalysis, fit) -> str:
    """Why ``fit``'s white-noise density is doubtful ("" if it is not): its model does not fit the
    measured Allan deviation, or its 90 % interval is missing or doubtful (:func:`~.tables.density_flag`)."""
    doubts = []
    adq = res.adequacy_of(fit)
    if adq is not None and adq.verdict == NO_FIT:
        doubts.append(f"the model does not fit the Allan deviation ({adq.summary()})")
    lo, hi = fit.ci90.get("sigma_w", (math.nan, math.nan))
    if density_flag(fit) or not (lo > 0 and math.isfinite(hi)):  # wide, or no interval at all
        doubts.append(f"90 % interval {interval(fit.sigma_w, lo, hi)}")
    return "; ".join(doubts)


def _noise_unidentified(fit) -> str:
    """Why ``fit``'s white-noise density is not identified ("" if it is): a missing interval or one
    wider than the noise table's 'not identified' (:data:`~.tables.UNIDENTIFIED_RATIO`)."""
    lo, hi = fit.ci90.get("sigma_w", (math.nan, math.nan))
    if not (lo > 0 and math.isfinite(hi)) or hi / lo > UNIDENTIFIED_RATIO:
        return f"sigma_w not identified (90 % interval {interval(fit.sigma_w, lo, hi)})"
    return ""


def _poorly_determined(fit) -> str:
    """The first bias parameter (random walk, bias instability, Gauss-Markov sigma_b) whose 90 %
    interval spans more than :data:`WIDE_INTERVAL`, as text ("" if none)."""
    for key in fit.params:
        if key == "sigma_k" or key == "B" or key.startswith("sigma_b"):
            lo, hi = fit.ci90.get(key, (math.nan, math.nan))
            if not (lo > 0 and math.isfinite(hi)) or hi / lo > WIDE_INTERVAL:
                return f"{key}: 90 % interval {interval(fit.params[key], lo, hi, '.2g')}"
    return ""


def axis_noise(res: ChannelAnalysis, source: str = "model", rw: str = "diffusion") -> AxisNoise:
    """White-noise and random-walk densities of one analysed channel (SI)."""
    cid = res.channel.id
    warning = noise_warning = noise_untrusted = walk_untrusted = ""
    if source in ("model", "mli"):
        fit = res.noise_model if source == "model" else res.mli
        if fit is None:
            raise InputError(f"channel {cid}: no {source} fit in the analysis (source {source!r})")
        nd = fit.sigma_w
        rwv = random_walk_from_params(fit.params, rw)
        terms = walk_terms(fit.params)
        noise_warning = _noise_doubts(res, fit)
        taus = [v for k, v in fit.params.items() if k.startswith("tau_b") and math.isfinite(v)]
        if fit.at_bound or not fit.converged:
            warning = f"fit not converged or at a bound ({', '.join(fit.at_bound) or user_text(fit.message)})"
        elif taus and min(taus) < WHITE_LIKE_TAU_B_S:
            warning = f"tau_b = {min(taus):.3g} s < {WHITE_LIKE_TAU_B_S:g} s: that bias acts as white noise"
        else:
            wide = _poorly_determined(fit)
            if wide:
                warning = f"bias term poorly determined by this record ({wide})"
        adq = res.adequacy_of(fit)
        misfit = (
            f"the model does not fit the Allan deviation ({adq.summary()})" if adq and adq.verdict == NO_FIT else ""
        )
        walk_untrusted = misfit or warning
        noise_untrusted = misfit or _noise_unidentified(fit)
    elif source == "ieee":
        nd, rwv = res.ieee.N, res.ieee.K
        terms = ""
    else:
        raise InputError(f"source {source!r}: use one of {', '.join(SOURCES)}")
    if not (math.isfinite(nd) and nd > 0):
        raise InputError(f"channel {cid}: white-noise density {nd} from {source} is not positive")
    if not (math.isfinite(rwv) and rwv > 0):
        hint = " (the Allan fit needs no rate-random-walk term; try --source model)" if source == "ieee" else ""
        raise InputError(f"channel {cid}: random-walk density {rwv} from {source} is not positive{hint}")
    return AxisNoise(cid, float(nd), float(rwv), warning, noise_warning, noise_untrusted, walk_untrusted, terms)


def sensor_noise(
    results: list[ChannelAnalysis], kind: str, source: str = "model", rw: str = "diffusion", *, force: bool = False
) -> SensorNoise:
    """Combine the analysed axes of one sensor (all at one rate) with :func:`choose_axes`."""
    if not results:
        raise InputError(f"no {kind} channels to export")
    rates = {r.channel.fs_hz for r in results}
    if len(rates) != 1:
        raise InputError(f"{kind} channels have different rates {sorted(rates)}: export one device at a time")
    axes = tuple(axis_noise(r, source, rw) for r in results)
    return choose_axes(SensorNoise(kind, rates.pop(), axes, source, rw), force=force)


def choose_axes(sensor: SensorNoise, *, force: bool = False) -> SensorNoise:
    """``sensor`` with, per quantity, the axes whose fit vouches for it (:class:`AxisNoise`
    ``noise_untrusted``/``walk_untrusted`` empty) as the ones its written value comes from.

    Raises :class:`Untrustworthy` naming every axis and why when no axis is left for a quantity,
    unless ``force`` (then that quantity is chosen among every axis and named in ``forced``).
    """
    chosen, forced, refused = {}, [], []
    for q in QUANTITY_NAMES:
        why = {a.channel: a.noise_untrusted if q == "noise" else a.walk_untrusted for a in sensor.axes}
        ok = tuple(c for c, w in why.items() if not w)
        if not ok:
            if not force:
                name = f"{sensor.kind} {QUANTITY_NAMES[q]}"
                refused.append(f"{name}: " + "; ".join(f"{c}: {w}" for c, w in why.items()))
            forced.append(q)
            ok = tuple(why)
        chosen[q] = ok
    if refused:
        raise Untrustworthy(
            "no axis left that a fit vouches for, nothing written (--force writes the largest axis, marked): "
            + " | ".join(refused)
        )
    return replace(sensor, noise_from=chosen["noise"], walk_from=chosen["walk"], forced=tuple(forced))


def export_dict(
    gyro: SensorNoise, accel: SensorNoise | None, fmt: str, *, topic: str = "/imu0", g_norm: float = G0
) -> dict:
    """The keys ``fmt`` expects, in SI continuous-time units; ``accel=None`` leaves its keys out."""
    if fmt not in FORMATS:
        raise InputError(f"format {fmt!r}: use one of {', '.join(FORMATS)}")
    rate = gyro.rate_hz
    acc = {} if accel is None else {"nd": accel.noise_density, "rw": accel.random_walk}
    if fmt in ("kalibr", "openvins"):
        d = {"rostopic": topic, "update_rate": float(rate)}
        if acc:
            d["accelerometer_noise_density"] = acc["nd"]
            d["accelerometer_random_walk"] = acc["rw"]
        d["gyroscope_noise_density"] = gyro.noise_density
        d["gyroscope_random_walk"] = gyro.random_walk
        if fmt == "openvins":
            d["time_offset"] = 0.0
            return {"imu0": d}
        return d
    if fmt == "vins":
        d = {"imu": 1, "imu_topic": topic}
        if acc:
            d["acc_n"] = acc["nd"]
        d["gyr_n"] = gyro.noise_density
        if acc:
            d["acc_w"] = acc["rw"]
        d["gyr_w"] = gyro.random_walk
        d["g_norm"] = float(g_norm)
        return d
    d = {"IMU.NoiseGyro": gyro.noise_density}
    if acc:
        d["IMU.NoiseAcc"] = acc["nd"]
    d["IMU.GyroWalk"] = gyro.random_walk
    if acc:
        d["IMU.AccWalk"] = acc["rw"]
    d["IMU.Frequency"] = int(round(rate))  # ORB-SLAM3 reads an integer
    return d


def _scalar(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise InputError(f"value {v} cannot be exported")
        return f"{v:.6e}"  # always a dot and a signed exponent: a float for YAML 1.1 and OpenCV alike
    return json.dumps(str(v))  # a double-quoted YAML scalar


def to_yaml(d: dict, comments: list[str] = (), directive: str | None = None, indent: int = 0) -> str:
    """Block-style YAML of nested dicts of str/int/float, with leading ``#`` comments."""
    lines = [] if indent else ([directive] if directive else []) + [f"# {c}" if c else "#" for c in comments]
    for k, v in d.items():
        pad = " " * indent
        if isinstance(v, dict):
            lines.append(f"{pad}{k}:")
            lines.append(to_yaml(v, indent=indent + 2).rstrip("\n"))
        else:
            lines.append(f"{pad}{k}: {_scalar(v)}")
    return "\n".join(lines) + "\n"


def _units() -> list[str]:
    return [
        "units: noise densities rad/s/sqrt(Hz) (gyro), m/s^2/sqrt(Hz) (accel), continuous time;",
        "random walks rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz); rate Hz. Discrete per-sample sigma = density*sqrt(rate).",
    ]


def device_channels(channels: Sequence[Channel], device: str | None, kind: str, path: str) -> list[Channel]:
    """Channels of ``kind`` ('gyro'/'accel') of ``device``; the only device with them when not named."""
    by_dev: dict[str, list] = {}
    for ch in channels:
        if ch.id.split("/")[1] == kind:
            by_dev.setdefault(ch.meta["device"], []).append(ch)
    if device is not None:
        return by_dev.get(device, [])
    if len(by_dev) > 1:
        opt = "--device" if kind == "gyro" else "--accel-device"
        raise InputError(f"{path}: {kind} channels on {', '.join(sorted(by_dev))}; choose one with {opt}")
    return next(iter(by_dev.values()), [])


def export_channels(
    channels: Sequence[Channel], run: str, *, device: str | None, accel_device: str | None, gyro_only: bool
) -> tuple[list[Channel], list[Channel]]:
    """The (gyroscope, accelerometer) channels of run file ``run`` an export fits: ``device``'s gyro
    (the only device with one when None) and ``accel_device``'s accelerometer (default: the gyro's
    device, else the only device with one, e.g. the BMX055's separate accelerometer die); none with
    ``gyro_only``. :class:`InputError` when a sensor has no channels."""
    gyros = device_channels(channels, device, "gyro", run)
    if not gyros:
        raise InputError(f"{run}: no gyroscope channels" + (f" on device {device}" if device else ""))
    accels = [] if gyro_only else device_channels(channels, accel_device or gyros[0].meta["device"], "accel", run)
    if accel_device is None and not accels and not gyro_only:
        accels = device_channels(channels, None, "accel", run)  # e.g. the BMX055's separate accelerometer die
    if not accels and not gyro_only:
        raise InputError(
            f"{run}: no accelerometer channels"
            + (f" on device {accel_device}" if accel_device else "")
            + "; name one with --accel-device or pass --gyro-only"
        )
    return gyros, accels


def analysed_samples(ch: Channel) -> str:
    """How many of ``ch``'s samples the fit reads, e.g. ``"705583 samples; the warm-up cut left out 14400 of
    719983"``: its segments after :func:`~.warmup.apply_warmup`, not the recorded count."""
    used = sum(b - a for a, b in ch.segments)
    if used == ch.n:
        return f"{used} samples"
    cut = ch.meta.get(WARMUP_META_KEY)
    why = "the warm-up cut left out" if cut is not None and cut.cut_s > 0 else "left out"
    return f"{used} samples; {why} {ch.n - used} of {ch.n}"


def fit_axes(
    chs: Sequence[Channel],
    kind: str,
    run: str,
    model: str,
    skipped: list[str],
    note: Callable[[str], None] = lambda line: None,
) -> list[ChannelAnalysis]:
    """Analyse every axis of one sensor (``kind``: 'gyroscope'/'accelerometer') with ``model``.

    An axis with nothing to characterise is skipped (its reason appended to ``skipped`` and
    passed to ``note``, with one "fitting ..." line per axis) so the sensor's other axes are
    exported; :class:`InputError` when every axis of the sensor was skipped.
    """
    out = []
    for ch in chs:
        note(f"fitting {ch.id} ({analysed_samples(ch)}) ...")
        try:
            out.append(analyze_channel(ch, model=model))
        except DegenerateChannel as exc:  # the sensor's other axes are exported
            note(f"warning: {exc}")
            skipped.append(str(exc))
        ch.release()
    if chs and not out:
        raise InputError(f"{run}: every {kind} axis was skipped ({'; '.join(skipped)})")
    return out


def export_text(
    gyro: SensorNoise,
    accel: SensorNoise | None,
    fmt: str,
    *,
    topic: str = "/imu0",
    g_norm: float = G0,
    origin: str = "",
    skipped: Sequence[str] = (),
    warmup: Sequence[str] = (),
) -> str:
    """The file for ``fmt``: keys of :func:`export_dict`, with comments naming units, source and axes
    (and the axes ``skipped``, each a sentence with its reason, and the ``warmup`` cut per device)."""
    d = export_dict(gyro, accel, fmt, topic=topic, g_norm=g_norm)
    how = (
        "IEEE-952 Allan fit: noise density = N, random walk = K"
        if gyro.source == "ieee"
        else f"ML_i fit: noise density = sigma_w, random walk from the bias model ({gyro.rw!r} conversion, "
        "docs/reports.md)"
    )
    comments = [f"imustation export --format {fmt}" + (f" of {origin}" if origin else ""), *_units(), how]
    comments += [f"warm-up {w}" for w in warmup]
    for s in (gyro, accel):
        if s is not None and s.inflated:
            comments.append(
                f"INFLATED {s.kind}: noise density x{s.inflate_noise:g}, random walk x{s.inflate_walk:g} (--inflate); "
                f"measured {s.measured_noise_density:.4e}, {s.measured_random_walk:.4e} -> written "
                f"{s.noise_density:.4e}, {s.random_walk:.4e}"
            )
    comments.append("written per sensor and quantity: the largest axis value among the axes whose fit vouches for")
    comments.append("it (the model fits the Allan deviation, no parameter at a search bound, the value identified):")
    for s in (gyro, accel):
        if s is not None:
            comments += [f"  {s.rule(q)}" for q in QUANTITY_NAMES]
    comments.append("per axis, measured (noise density, random walk):")
    for s in (gyro, accel):
        if s is None:
            continue
        for a in s.axes:
            # a walk converted from B or a Gauss-Markov bias is not the K analyze prints ("< x" when the
            # record shows no rate random walk): name what it is made of, so the two can be compared
            comments.append(f"  {a.channel}: {a.noise_density:.4e}, {a.random_walk:.4e}")
            if a.walk_terms not in ("", "rate random walk K"):
                made_of = f"random walk from {a.walk_terms} (analyze's K: the rate random walk alone)"
                comments.append(f"  {a.channel}: {made_of}")
            if a.noise_warning:
                comments.append(f"  WARNING {a.channel}: noise density doubtful: {a.noise_warning}")
            if a.warning:
                comments.append(f"  WARNING {a.channel}: random walk doubtful: {a.warning}; record longer")
    for why in skipped:
        comments.append(f"  {why}")
    if accel is None:
        comments.append("no accelerometer exported: accelerometer keys left out (add them before use)")
    if fmt == "vins":
        comments.append("g_norm: standard gravity; replace by the local value. Merge into the full VINS config.")
    if fmt == "orbslam3":
        comments.append("merge into the ORB-SLAM3 settings file (camera keys not written)")
    directive = None if fmt == "kalibr" else _OPENCV_DIRECTIVE
    return to_yaml(d, comments, directive)
