"""Signal sources that feed chip simulators with physical values (SI units).

:class:`NoiseSource` draws each axis from the standard noise model (by default
the paper's Table IV parameters for the device) plus a turn-on bias, and gives
a die temperature that drifts slowly. With ``profile = "datasheet"`` (or the
keys themselves) it adds bias instability, rate random walk and a bias that
follows the die temperature (:mod:`.noise_terms`), and puts the white noise
through the output filter the chip's settings select (:mod:`.filters`), drawn
at the chip's internal rate. Only simulators may import the analysis noise
models (layer rule).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np

from imustation.analysis.estimators.models.reference import ACCEL_DEFAULTS, TABLE_IV
from imustation.analysis.estimators.models.standard import StandardModel, StandardNoiseStream
from imustation.drivers.sim.filters import ChipFilter, FilterRun
from imustation.drivers.sim.noise_terms import DieTemperature, SlowBias
from imustation.drivers.sim.profiles import defaults
from imustation.drivers.sim.simkeys import SIM_KEYS, sim_value_problem
from imustation.errors import SettingError
from imustation.units import DEG2RAD, G0


class SignalSource(Protocol):
    """What a chip simulator reads. Noise sources also offer ``fits(fs_hz, chip_filter)`` and
    ``use_filter(chip_filter)`` (see :func:`fits`, :func:`with_filter`)."""

    fs_hz: float

    def next(self, n: int) -> np.ndarray:
        """The next ``n`` samples, shape ``(n, n_axes)``, SI units."""
        ...

    def temperature(self, t_s: float) -> float:
        """Die temperature at time ``t_s`` (s since start), degC."""
        ...


#: default turn-on bias spread of simulated gyros, deg/s
GYRO_TURN_ON_BIAS_STD_DPS = 0.5
#: default turn-on bias spread of simulated accelerometers, mg. Kept small so a
#: static capture reads 1 g within a few mg; datasheet zero-g offsets are larger
#: (tens of mg) - raise it, or set accel_b_on_mg, to simulate them.
ACCEL_TURN_ON_BIAS_STD_MG = 1.0
#: the station is static and level: gravity reads +1 g on z (specific force)
DEFAULT_GRAVITY_G = (0.0, 0.0, 1.0)
#: salt that makes a device's accelerometer stream independent of its gyro stream
_ACCEL_SEED_SALT = 0x0ACCE1

# --- one axis of the standard model --------------------------------------------------------------


class _AxisNoise:
    """White noise and Gauss-Markov bias of one axis, the white noise through the chip's filter.

    Without a filter that changes it (none, or a mean over each output interval, which
    leaves white noise white at the same density) this is the paper's discrete model,
    sample for sample :class:`StandardNoiseStream`'s. Otherwise the bias is drawn at the
    output rate as there and the white noise at the chip's internal rate.
    """

    def __init__(self, model: StandardModel, fs_hz: float, rng: np.random.Generator, chip_filter: ChipFilter | None):
        self.model = model
        self.rng = rng
        self.gm = StandardNoiseStream(model, fs_hz, rng)  # draws the bias's stationary start first
        shaped = chip_filter is not None and not chip_filter.white_equivalent
        self.run = FilterRun(chip_filter, rng, model.sigma_w) if shaped else None
        self.legacy = self.run is None and model.sigma_b > 0

    def next(self, n: int) -> np.ndarray:
        if self.legacy:
            return self.gm.next(n)
        gm = self.gm
        if gm.sigma_bd > 0:
            from scipy.signal import lfilter

            w = self.rng.normal(0.0, gm.sigma_bd, n)
            bias, _ = lfilter([1.0], [1.0, -gm.phi], w, zi=[gm.phi * gm.b])
            gm.b = float(bias[-1])
        else:
            bias = gm.b
        white = self.run.next(n) if self.run is not None else self.rng.normal(0.0, gm.sigma_wd, n)
        return white + (bias + self.model.b_on)


class NoiseSource:
    """Independent standard-model noise on every axis, plus temperature and the further terms.

    Parameters
    ----------
    models : one :class:`StandardModel` per axis (SI units, with ``b_on``).
    fs_hz : output rate, Hz.
    seed : integer seed; the same seed gives the same stream.
    temp_c, temp_drift_c, temp_period_s : die temperature ``temp_c +
        temp_drift_c * sin(2 pi t / temp_period_s)`` (a slow room drift), degC, s.
    warmup_c, warmup_tau_s : the die's rise after power-on, ``warmup_c (1 - exp(-t /
        warmup_tau_s))``, K and s.
    offset : a constant added to every sample, per axis, SI units (gravity
        for accelerometers; the models' ``b_on`` is the sensor's own bias).
    bias_instability, rate_random_walk, bias_tempco : per axis B (rad/s or m/s^2),
        K (rad/s/sqrt(s) or m/s^2/sqrt(s)), bias per kelvin of die temperature
        (rad/s/K or m/s^2/K); ``None`` = none.
    filtering : apply the chip's output filter (:meth:`use_filter`); off, the source
        takes any filter and its white noise stays the paper's.
    """

    def __init__(
        self,
        models: Sequence[StandardModel],
        fs_hz: float,
        seed: int,
        *,
        temp_c: float = 30.0,
        temp_drift_c: float = 0.5,
        temp_period_s: float = 6 * 3600.0,
        offset: Sequence[float] | None = None,
        warmup_c: float = 0.0,
        warmup_tau_s: float = 600.0,
        bias_instability: Sequence[float] | None = None,
        rate_random_walk: Sequence[float] | None = None,
        bias_tempco: Sequence[float] | None = None,
        filtering: bool = False,
    ):
        self.models = tuple(models)
        n_axes = len(self.models)
        self.offset = np.zeros(n_axes) if offset is None else np.asarray(offset, dtype=float)
        if self.offset.shape != (n_axes,):
            raise ValueError(f"offset needs one value per axis ({n_axes})")
        self.fs_hz = float(fs_hz)
        self.seed = int(seed)
        rng = np.random.default_rng(seed)
        # the axes' generators as they always were, so the paper's streams stay the same
        self._rngs = [np.random.default_rng(rng.integers(2**63)) for _ in self.models]
        self._streams: list[_AxisNoise] | None = None
        self.die = DieTemperature(temp_c, temp_drift_c, temp_period_s, warmup_c, warmup_tau_s)
        self.filtering = bool(filtering)
        self.chip_filter: ChipFilter | None = None
        terms = [np.zeros(n_axes) if v is None else np.asarray(v, dtype=float) for v in
                 (bias_instability, rate_random_walk, bias_tempco)]  # fmt: skip
        slow = any(np.any(t) for t in terms)
        self._slow = SlowBias(self.fs_hz, *terms, self.die, self.seed) if slow else None
        self._buf = np.zeros((0, n_axes))
        self._pos = 0

    #: samples drawn per refill: chip simulators ask for a few dozen at a time,
    #: and one vectorised draw of a large block costs far less per sample
    BLOCK = 1 << 16

    def use_filter(self, chip_filter: ChipFilter | None) -> None:
        """The output filter the chip's registers select; before the first sample only."""
        if self._streams is not None:
            raise RuntimeError("the output filter is set before the first sample")
        if chip_filter is not None and abs(chip_filter.fs_out_hz - self.fs_hz) > 1e-9 * self.fs_hz:
            raise ValueError(f"{chip_filter.chip} outputs {chip_filter.fs_out_hz:g} Hz, the source {self.fs_hz:g} Hz")
        self.chip_filter = chip_filter

    def fits(self, fs_hz: float, chip_filter: ChipFilter | None) -> bool:
        """Whether a chip reconfigured to ``fs_hz`` and ``chip_filter`` can keep reading this source."""
        return self.fs_hz == fs_hz and (not self.filtering or self.chip_filter == chip_filter)

    def next(self, n: int) -> np.ndarray:
        if n <= 0:
            return np.zeros((0, len(self.models)))
        if self._pos + n > len(self._buf):
            if self._streams is None:
                applied = self.chip_filter if self.filtering else None
                pairs = zip(self.models, self._rngs, strict=True)
                self._streams = [_AxisNoise(m, self.fs_hz, r, applied) for m, r in pairs]
            size = max(n, self.BLOCK)
            rest = self._buf[self._pos :]
            fresh = np.column_stack([s.next(size) for s in self._streams])
            if self._slow is not None:
                fresh += self._slow.next(size)
            self._buf = np.concatenate([rest, fresh]) if len(rest) else fresh
            self._pos = 0
        out = self._buf[self._pos : self._pos + n] + self.offset
        self._pos += n
        return out

    def temperature(self, t_s: float) -> float:
        return self.die(t_s)

    @classmethod
    def for_device(
        cls,
        table_key: str,
        axes: Sequence[str],
        fs_hz: float,
        sim: Mapping[str, object],
        default_seed: int,
    ) -> NoiseSource:
        """A gyroscope source from a ``[device.sim]`` table over its profile's defaults.

        ``profile``: ``"paper"`` (Table IV, the default) or ``"datasheet"``
        (:mod:`.profiles`). ``sigma_w``/``sigma_b``/``tau_b`` and the further terms
        override every axis (a number) or each axis (a list, one per axis).
        ``b_on_dps`` fixes the turn-on biases (deg/s, number or list); otherwise they
        are drawn from N(0, turn_on_bias_std_dps^2) with the seed.
        """
        _check_keys(sim)
        seed = sim_seed(sim, default_seed)
        return cls._build(
            TABLE_IV.get(table_key, {}),
            table_key,
            axes,
            fs_hz,
            sim,
            seed,
            prefix="",
            b_on_key="b_on_dps",
            b_on_std_key="turn_on_bias_std_dps",
            b_on_std=GYRO_TURN_ON_BIAS_STD_DPS,
            b_on_unit=DEG2RAD,
            b_on_salt=0x5EED,
            offset=None,
        )

    @classmethod
    def for_accel(
        cls,
        table_key: str,
        axes: Sequence[str],
        fs_hz: float,
        sim: Mapping[str, object],
        default_seed: int,
    ) -> NoiseSource:
        """An accelerometer source (m/s^2) over :data:`ACCEL_DEFAULTS` (or its profile), with gravity.

        Keys as for :meth:`for_device` with an ``accel_`` prefix; turn-on biases in
        mg (``accel_b_on_mg``, ``accel_turn_on_bias_std_mg``). ``gravity_g`` (three
        numbers, g; default ``[0, 0, 1]``: static, level station) is added to every
        sample. The stream is independent of the same device's gyro stream; the die
        temperature (and its warm-up) is the device's.
        """
        _check_keys(sim)
        seed = (sim_seed(sim, default_seed) + _ACCEL_SEED_SALT) % (2**31)
        gravity = sim.get("gravity_g", DEFAULT_GRAVITY_G)
        if (
            not isinstance(gravity, (list, tuple))
            or len(gravity) != len(axes)
            or not all(isinstance(g, (int, float)) and not isinstance(g, bool) for g in gravity)
        ):
            raise SettingError(f"sim.gravity_g = {gravity!r}: expected {len(axes)} numbers (g), e.g. [0, 0, 1]")
        return cls._build(
            ACCEL_DEFAULTS[table_key],
            table_key,
            axes,
            fs_hz,
            sim,
            seed,
            prefix="accel_",
            b_on_key="accel_b_on_mg",
            b_on_std_key="accel_turn_on_bias_std_mg",
            b_on_std=ACCEL_TURN_ON_BIAS_STD_MG,
            b_on_unit=1e-3 * G0,
            b_on_salt=_ACCEL_SEED_SALT,
            offset=[float(g) * G0 for g in gravity],
        )

    @classmethod
    def _build(
        cls,
        base: Mapping[str, StandardModel],
        table_key: str,
        axes: Sequence[str],
        fs_hz: float,
        sim: Mapping[str, object],
        seed: int,
        *,
        prefix: str,
        b_on_key: str,
        b_on_std_key: str,
        b_on_std: float,
        b_on_unit: float,
        b_on_salt: int,
        offset: Sequence[float] | None,
    ) -> NoiseSource:
        """Per-axis models from ``base`` (or the profile) overridden by ``sim[prefix + param]``; the further terms."""
        for key, value in sim.items():
            problem = sim_value_problem(key, value, len(axes))
            if problem:
                raise SettingError(f"sim.{key} = {value!r}: expected {problem}")
        profile = str(sim.get("profile", "paper"))
        eff = {**_profile_for_axes(defaults(table_key, profile), sorted(base), axes, table_key), **sim}
        rng = np.random.default_rng([seed, b_on_salt])

        def per_axis(key: str, default: float) -> np.ndarray:
            value = eff.get(key, default)
            return np.asarray(value if isinstance(value, (list, tuple)) else [value] * len(axes), dtype=float)

        drawn_b_on = rng.normal(0.0, float(eff.get(b_on_std_key, b_on_std)), len(axes))
        b_on = per_axis(b_on_key, 0.0) if b_on_key in eff else drawn_b_on
        ref = [base.get(axis) or next(iter(base.values()), StandardModel(1e-4, 1e-6, 600.0)) for axis in axes]
        sigma_w = per_axis(prefix + "sigma_w", math.nan)
        sigma_b = per_axis(prefix + "sigma_b", math.nan)
        tau_b = per_axis(prefix + "tau_b", math.nan)
        models = [
            replace(
                StandardModel(
                    r.sigma_w if math.isnan(sigma_w[i]) else sigma_w[i],
                    r.sigma_b if math.isnan(sigma_b[i]) else sigma_b[i],
                    r.tau_b if math.isnan(tau_b[i]) else tau_b[i],
                ),
                b_on=float(b_on[i]) * b_on_unit,
            )
            for i, r in enumerate(ref)
        ]
        tempco = per_axis(prefix + "bias_tempco", 0.0)
        if prefix + "bias_tempco" not in sim:
            # a datasheet gives a spread over parts, not a sign: each axis's from the seed
            tempco = tempco * np.random.default_rng([seed, 0x7C0]).choice([-1.0, 1.0], len(axes))
        return cls(
            models,
            fs_hz,
            seed,
            temp_c=float(eff.get("temp_c", 30.0)),
            temp_drift_c=float(eff.get("temp_drift_c", 0.5)),
            temp_period_s=float(eff.get("temp_period_s", 6 * 3600.0)),
            warmup_c=float(eff.get("warmup_c", 0.0)),
            warmup_tau_s=float(eff.get("warmup_tau_s", 600.0)),
            offset=offset,
            bias_instability=per_axis(prefix + "bias_instability", 0.0),
            rate_random_walk=per_axis(prefix + "rate_random_walk", 0.0),
            bias_tempco=tempco,
            filtering=bool(eff.get("filter", profile == "datasheet")),
        )


def _profile_for_axes(
    profile: Mapping[str, float | tuple[float, ...]], profile_axes: list[str], axes: Sequence[str], table_key: str
) -> dict[str, float | tuple[float, ...]]:
    """The profile's per-axis values (given for ``profile_axes``, in that order) for the ``axes`` asked for."""
    missing = [a for a in axes if a not in profile_axes]
    out: dict[str, float | tuple[float, ...]] = {}
    for key, value in profile.items():
        if isinstance(value, tuple):
            if missing or len(value) != len(profile_axes):
                raise SettingError(
                    f"profile of {table_key}: {key} is given for axes {', '.join(profile_axes)}, "
                    f"not for {', '.join(missing) or 'these'}"
                )
            value = tuple(value[profile_axes.index(a)] for a in axes)
        out[key] = value
    return out


def sim_number(sim: Mapping[str, object], key: str, default: float, *, positive: bool = False) -> float:
    """``sim[key]`` (or ``default``) as a finite float; ``positive``: also > 0. SettingError otherwise."""
    value = sim.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SettingError(f"sim.{key} = {value!r}: expected a finite number")
    if positive and not value > 0:
        raise SettingError(f"sim.{key} = {value!r}: must be > 0")
    return float(value)


def sim_seed(sim: Mapping[str, object], default: int) -> int:
    """``sim["seed"]`` (or ``default``): an integer 0 .. 2^63 - 1 (numpy's seeds are non-negative)."""
    seed = sim.get("seed", default)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise SettingError(f"sim.seed = {seed!r}: expected an integer 0 .. 2^63-1")
    return seed


def _check_keys(sim: Mapping[str, object]) -> None:
    for key in sim:
        if key not in SIM_KEYS:
            raise SettingError(f"sim.{key}: unknown (known: {', '.join(SIM_KEYS)})")


def fits(source: SignalSource | None, fs_hz: float, chip_filter: ChipFilter | None) -> bool:
    """Whether a chip (re)configured to ``fs_hz`` and ``chip_filter`` keeps reading ``source``.

    Sources without a filter notion (test doubles) are kept while the rate is unchanged."""
    if source is None:
        return False
    check = getattr(source, "fits", None)
    return check(fs_hz, chip_filter) if check is not None else source.fs_hz == fs_hz


def with_filter(source: SignalSource, chip_filter: ChipFilter | None) -> SignalSource:
    """``source`` told the chip's output filter (sources without a filter notion are returned as they are)."""
    use = getattr(source, "use_filter", None)
    if use is not None:
        use(chip_filter)
    return source


class ReplaySource:
    """A recorded signal played back to a chip simulator (``[device.sim] replay = ...``).

    Sources (rates in SI units, one column per axis):

    * ``"run.h5#device/gyro"`` - a channel of a run file (counts x scale), its rate
      from the file;
    * ``"rates.npy"`` / ``"rates.csv"`` - an ``(n, k)`` array, rate given by
      ``replay_rate_hz`` (default: the device's configured output rate).

    No resampling: the recording's rate must equal the configured output rate. When the
    recording is used up the next draw raises :class:`DeviceError`, so the capture
    logs a fault instead of inventing data.
    """

    def __init__(self, data: np.ndarray, fs_hz: float, label: str, *, temp_c: float = 25.0):
        self.data = np.ascontiguousarray(data, dtype=float)
        self.fs_hz = float(fs_hz)
        self.label = label
        self.temp_c = temp_c
        self._pos = 0

    def next(self, n: int) -> np.ndarray:
        from imustation.errors import DeviceError

        if self._pos + n > len(self.data):
            raise DeviceError(f"replayed recording {self.label} used up after {len(self.data)} samples")
        out = self.data[self._pos : self._pos + n]
        self._pos += n
        return out

    def temperature(self, t_s: float) -> float:
        return self.temp_c

    def fits(self, fs_hz: float, chip_filter: ChipFilter | None) -> bool:
        """A recording passed through its own device's filter: any filter fits, the rate must."""
        return self.fs_hz == fs_hz

    def use_filter(self, chip_filter: ChipFilter | None) -> None:
        """Nothing: the recording is played as recorded."""

    @classmethod
    def open(cls, spec: str, fs_hz: float, axes: Sequence[str], sim: Mapping[str, object]) -> ReplaySource:
        """Load ``spec`` for a chip producing ``axes`` at ``fs_hz``; one-line errors on mismatch."""
        from imustation.errors import RunFileError

        temp_c = float(sim.get("temp_c", 25.0))
        if "#" in spec:
            path, channel = spec.split("#", 1)
            device, _, quantity = channel.partition("/")
            from imustation.runfile import open_run

            try:
                with open_run(path) as run:
                    info = run.devices.get(device)
                    if info is None or quantity not in info.channels:
                        raise SettingError(f"sim.replay = {spec!r}: no channel {channel} in {path}")
                    ch = info.channels[quantity]
                    data = run.read(device, quantity).astype(float) * ch.scale + ch.offset
                    rate = info.rate_hz
            except RunFileError as exc:
                raise SettingError(f"sim.replay = {spec!r}: {exc}") from None
        else:
            try:
                if spec.lower().endswith(".npy"):
                    data = np.load(spec, allow_pickle=False)
                else:
                    data = np.loadtxt(spec, delimiter="," if spec.lower().endswith(".csv") else None, ndmin=2)
            except (OSError, ValueError) as exc:
                raise SettingError(f"sim.replay = {spec!r}: cannot read ({exc})") from None
            rate = float(sim.get("replay_rate_hz", fs_hz))
        data = np.asarray(data, dtype=float)
        if data.ndim == 1:
            data = data[:, None]
        if data.shape[1] != len(axes):
            raise SettingError(f"sim.replay = {spec!r}: {data.shape[1]} columns for {len(axes)} axes")
        if not np.all(np.isfinite(data)):
            raise SettingError(f"sim.replay = {spec!r}: holds NaN or infinite values")
        if abs(rate - fs_hz) > 1e-6 * fs_hz:
            raise SettingError(
                f"sim.replay = {spec!r}: recorded at {rate:g} Hz, the device is set to {fs_hz:g} Hz (no resampling)"
            )
        return cls(data, fs_hz, spec, temp_c=temp_c)
