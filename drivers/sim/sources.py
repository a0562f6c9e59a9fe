"""Signal sources that feed chip simulators with physical values (SI units).

:class:`NoiseSource` draws each axis from the standard noise model (by default
the paper's Table IV parameters for the device) plus a turn-on bias, and gives
a die temperature that drifts slowly. Only simulators may import the analysis
noise models (layer rule).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np

from imustation.analysis.models import StandardModel, StandardNoiseStream
from imustation.analysis.reference import ACCEL_DEFAULTS, TABLE_IV
from imustation.errors import SettingError
from imustation.units import DEG2RAD, G0


class SignalSource(Protocol):
    fs_hz: float

    def next(self, n: int) -> np.ndarray:
        """The next ``n`` samples, shape ``(n, n_axes)``, SI units."""
        ...

    def temperature(self, t_s: float) -> float:
        """Die temperature at time ``t_s`` (s since start), degC."""
        ...


#: keys a [device.sim] table may hold
SIM_KEYS = (
    "seed",
    "sigma_w",
    "sigma_b",
    "tau_b",
    "b_on_dps",
    "turn_on_bias_std_dps",
    "temp_c",
    "temp_drift_c",
    "temp_period_s",
    "faults",
    # accelerometers (defaults: analysis.reference.ACCEL_DEFAULTS, not the paper)
    "accel_sigma_w",
    "accel_sigma_b",
    "accel_tau_b",
    "accel_b_on_mg",
    "accel_turn_on_bias_std_mg",
    "gravity_g",
    # a recorded signal instead of the noise model (see ReplaySource)
    "replay",
    "replay_rate_hz",
    "accel_replay",
)

#: keys that shape a gyroscope source / an accelerometer source
GYRO_SIM_KEYS = ("sigma_w", "sigma_b", "tau_b", "b_on_dps", "turn_on_bias_std_dps", "replay")
ACCEL_SIM_KEYS = (
    "accel_sigma_w",
    "accel_sigma_b",
    "accel_tau_b",
    "accel_b_on_mg",
    "accel_turn_on_bias_std_mg",
    "gravity_g",
    "accel_replay",
)

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


class NoiseSource:
    """Independent standard-model noise on every axis, plus temperature.

    Parameters
    ----------
    models : one :class:`StandardModel` per axis (SI units, with ``b_on``).
    fs_hz : sample rate, Hz.
    seed : integer seed; the same seed gives the same stream.
    temp_c, temp_drift_c, temp_period_s : die temperature ``temp_c +
        temp_drift_c * sin(2 pi t / temp_period_s)`` (a slow room drift).
    offset : a constant added to every sample, per axis, SI units (gravity
        for accelerometers; the models' ``b_on`` is the sensor's own bias).
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
    ):
        self.models = tuple(models)
        self.offset = np.zeros(len(self.models)) if offset is None else np.asarray(offset, dtype=float)
        if self.offset.shape != (len(self.models),):
            raise ValueError(f"offset needs one value per axis ({len(self.models)})")
        self.fs_hz = float(fs_hz)
        self.seed = int(seed)
        rng = np.random.default_rng(seed)
        self._streams = [StandardNoiseStream(m, fs_hz, np.random.default_rng(rng.integers(2**63))) for m in self.models]
        self.temp_c, self.temp_drift_c, self.temp_period_s = temp_c, temp_drift_c, temp_period_s
        self._buf = np.zeros((0, len(self._streams)))
        self._pos = 0

    #: samples drawn per refill: chip simulators ask for a few dozen at a time,
    #: and one vectorised draw of a large block costs far less per sample
    BLOCK = 1 << 16

    def next(self, n: int) -> np.ndarray:
        if n <= 0:
            return np.zeros((0, len(self._streams)))
        if self._pos + n > len(self._buf):
            rest = self._buf[self._pos :]
            fresh = np.column_stack([s.next(max(n, self.BLOCK)) for s in self._streams])
            self._buf = np.concatenate([rest, fresh]) if len(rest) else fresh
            self._pos = 0
        out = self._buf[self._pos : self._pos + n] + self.offset
        self._pos += n
        return out

    def temperature(self, t_s: float) -> float:
        return self.temp_c + self.temp_drift_c * math.sin(2.0 * math.pi * t_s / self.temp_period_s)

    @classmethod
    def for_device(
        cls,
        table_key: str,
        axes: Sequence[str],
        fs_hz: float,
        sim: Mapping[str, object],
        default_seed: int,
    ) -> NoiseSource:
        """A gyroscope source from a ``[device.sim]`` table over the Table IV defaults.

        ``sigma_w``/``sigma_b``/``tau_b`` override every axis (a number) or
        each axis (a list, one per axis). ``b_on_dps`` fixes the turn-on biases
        (deg/s, number or list); otherwise they are drawn from
        N(0, turn_on_bias_std_dps^2) with the seed.
        """
        _check_keys(sim)
        seed = sim_seed(sim, default_seed)
        return cls._build(
            TABLE_IV.get(table_key, {}),
            axes,
            fs_hz,
            sim,
            seed,
            prefix="",
            b_on_key="b_on_dps",
            b_on_std=float(sim.get("turn_on_bias_std_dps", GYRO_TURN_ON_BIAS_STD_DPS)),
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
        """An accelerometer source (m/s^2) over :data:`ACCEL_DEFAULTS`, with gravity.

        Keys as for :meth:`for_device` with an ``accel_`` prefix; turn-on biases in
        mg (``accel_b_on_mg``, ``accel_turn_on_bias_std_mg``). ``gravity_g`` (three
        numbers, g; default ``[0, 0, 1]``: static, level station) is added to every
        sample. The stream is independent of the same device's gyro stream.
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
            axes,
            fs_hz,
            sim,
            seed,
            prefix="accel_",
            b_on_key="accel_b_on_mg",
            b_on_std=float(sim.get("accel_turn_on_bias_std_mg", ACCEL_TURN_ON_BIAS_STD_MG)),
            b_on_unit=1e-3 * G0,
            b_on_salt=_ACCEL_SEED_SALT,
            offset=[float(g) * G0 for g in gravity],
        )

    @classmethod
    def _build(
        cls,
        base: Mapping[str, StandardModel],
        axes: Sequence[str],
        fs_hz: float,
        sim: Mapping[str, object],
        seed: int,
        *,
        prefix: str,
        b_on_key: str,
        b_on_std: float,
        b_on_unit: float,
        b_on_salt: int,
        offset: Sequence[float] | None,
    ) -> NoiseSource:
        """Per-axis models from ``base`` overridden by ``sim[prefix + param]``; turn-on biases."""
        rng = np.random.default_rng([seed, b_on_salt])

        def per_axis(key: str, i: int, default: float) -> float:
            value = sim.get(key, default)
            if isinstance(value, (list, tuple)):
                if len(value) != len(axes):
                    raise SettingError(f"sim.{key}: {len(value)} values for {len(axes)} axes")
                value = value[i]
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise SettingError(f"sim.{key} = {value!r}: expected a number") from None
            if not math.isfinite(value):
                raise SettingError(f"sim.{key} = {value!r}: expected a finite number")
            if not value > 0 and key != b_on_key:
                raise SettingError(f"sim.{key} = {value!r}: must be > 0")
            return value

        drawn_b_on = rng.normal(0.0, b_on_std, len(axes))
        models = []
        for i, axis in enumerate(axes):
            ref = base.get(axis) or next(iter(base.values()), StandardModel(1e-4, 1e-6, 600.0))
            model = StandardModel(
                per_axis(prefix + "sigma_w", i, ref.sigma_w),
                per_axis(prefix + "sigma_b", i, ref.sigma_b),
                per_axis(prefix + "tau_b", i, ref.tau_b),
            )
            b_on = per_axis(b_on_key, i, drawn_b_on[i]) if b_on_key in sim else drawn_b_on[i]
            models.append(replace(model, b_on=b_on * b_on_unit))
        return cls(
            models,
            fs_hz,
            seed,
            temp_c=sim_number(sim, "temp_c", 30.0),
            temp_drift_c=sim_number(sim, "temp_drift_c", 0.5),
            temp_period_s=sim_number(sim, "temp_period_s", 6 * 3600.0, positive=True),
            offset=offset,
        )


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
