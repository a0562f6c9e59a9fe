"""Simulated hardware: byte-level chip simulators behind simulated buses.

These fakes ship beside the real drivers and answer exactly as the chips do
(register files, FIFOs), driven by signal sources (the standard noise model
with the paper's Table IV parameters or a device's datasheet values, through
the output filter its settings select; or a replayed recording). Test-only back
doors carry a ``sim_`` prefix.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from imustation.drivers.sim.i2c import SimSMBus
from imustation.drivers.sim.simkeys import ACCEL_SIM_KEYS, GYRO_SIM_KEYS
from imustation.drivers.sim.sources import NoiseSource, SignalSource, with_filter

__all__ = [
    "SimSMBus",
    "NoiseSource",
    "SignalSource",
    "make_simulator",
    "make_thermometer_simulator",
    "simulated_truth",
    "station_device_seed",
    "device_sources",
    "sim_axes",
]

_XYZ = ("x", "y", "z")
SourceFactory = Callable[[float], NoiseSource]


def _reject(driver: str, sim: dict, keys: tuple[str, ...], why: str) -> None:
    from imustation.errors import SettingError

    for key in sim:
        if key in keys:
            raise SettingError(f"sim.{key}: driver {driver!r} {why}")


def _bmx055_gyro(sim: dict, seed: int) -> dict[str, SourceFactory]:
    _reject("bmx055", sim, ACCEL_SIM_KEYS, "is the gyroscope die (the accelerometer is driver 'bmx055_accel')")
    return {"gyro": lambda fs: NoiseSource.for_device("bmx055", _XYZ, fs, sim, seed)}


def _bmx055_accel(sim: dict, seed: int) -> dict[str, SourceFactory]:
    _reject("bmx055_accel", sim, GYRO_SIM_KEYS, "has no gyroscope (its keys start with accel_)")
    return {"accel": lambda fs: NoiseSource.for_accel("bmx055", _XYZ, fs, sim, seed)}


def _invensense(table_key: str) -> Callable[[dict, int], dict[str, SourceFactory]]:
    def sources(sim: dict, seed: int) -> dict[str, SourceFactory]:
        return {
            "gyro": lambda fs: NoiseSource.for_device(table_key, _XYZ, fs, sim, seed),
            "accel": lambda fs: NoiseSource.for_accel(table_key, _XYZ, fs, sim, seed),
        }

    return sources


def _gyro_only(table_key: str, axes: tuple[str, ...]) -> Callable[[dict, int], dict[str, SourceFactory]]:
    """Sources of the SPI/serial devices: the gyro from Table IV (their simulators make
    the accelerometer signal themselves: gravity on +z plus white noise)."""

    def sources(sim: dict, seed: int) -> dict[str, SourceFactory]:
        return {"gyro": lambda fs: NoiseSource.for_device(table_key, axes, fs, sim, seed)}

    return sources


#: driver -> (sim table, seed) -> channel -> signal source factory (fs_hz -> source)
SOURCES: dict[str, Callable[[dict, int], dict[str, SourceFactory]]] = {
    "bmx055": _bmx055_gyro,
    "bmx055_accel": _bmx055_accel,
    "mpu9150": _invensense("mpu9150"),
    "mpu6500": _invensense("mpu6500"),
    "adis16448": _gyro_only("adis16448", _XYZ),
    "mti": _gyro_only("mti", _XYZ),
    "dsp3000": _gyro_only("dsp3000", ("z",)),
}


def _with_replays(driver: str, settings: dict, sources: dict[str, SourceFactory], sim: dict) -> dict:
    """Swap the noise model for a recording where ``sim.replay`` / ``sim.accel_replay`` name one.

    The recording is checked once against the device's configured output rate and is
    one stream whatever rate the chip asks with: a chip that powers up at another
    rate draws its few start-up samples (which drivers discard) from it too.
    """
    from imustation.drivers.sim.sources import ReplaySource

    out = dict(sources)
    axes = sim_axes(driver)
    rate = _configured_rate(driver, settings)
    for channel, key in (("gyro", "replay"), ("accel", "accel_replay")):
        if key in sim and channel in out:
            source = ReplaySource.open(str(sim[key]), rate, axes, sim)
            out[channel] = lambda fs, source=source: source
    return out


def sim_axes(driver: str) -> tuple[str, ...]:
    """The axes a driver's simulated gyro/accelerometer sources have (the DSP-3000 is single-axis)."""
    return ("z",) if driver == "dsp3000" else _XYZ


def _plan(clock, sim: dict, seed: int):
    from imustation.drivers.sim.faults import FaultPlan, parse_faults

    return FaultPlan(parse_faults(sim.get("faults", [])), clock, seed) if sim.get("faults") else None


def make_simulator(driver: str, clock, settings: dict, sim: dict, seed: int):
    """The byte-level simulator of ``driver``'s chip and its fault plan.

    ``settings`` are the device's validated settings, ``sim`` its ``[device.sim]``
    table, ``seed`` the per-device seed (``sim.seed`` overrides it); ``sim.quirks``
    names field quirks the chip shows (:mod:`.quirks`). Returns ``(simulator, plan)``;
    the bus applies the plan's bus-level faults.
    """
    from imustation.errors import SettingError

    if driver not in SOURCES:
        raise SettingError(f"driver {driver!r} has no simulator")
    from imustation.drivers.sim.quirks import chip_quirks

    quirks = chip_quirks(driver, sim.get("quirks"))
    plan = _plan(clock, sim, seed)
    sources = _with_replays(driver, settings, SOURCES[driver](sim, seed), sim)
    if driver == "bmx055":
        from imustation.drivers.sim.bmx055 import BMG160Sim

        return BMG160Sim(clock, sources["gyro"], plan), plan
    if driver == "bmx055_accel":
        from imustation.drivers.sim.bmx055_accel import BMA2x2Sim

        return BMA2x2Sim(clock, sources["accel"], plan), plan
    if driver == "adis16448":
        from imustation.drivers.sim.adis16448 import ADIS16448Sim

        return ADIS16448Sim(clock, sources["gyro"], plan, seed), plan
    if driver == "mti":
        from imustation.drivers.sim.xsens_mti import MTiSim

        return MTiSim(clock, sources["gyro"], plan, seed), plan
    if driver == "dsp3000":
        from imustation.drivers.sim.kvh_dsp3000 import DSP3000Sim

        return DSP3000Sim(clock, sources["gyro"], plan, rate_hz=settings["rate_hz"], quirks=quirks), plan
    from imustation.drivers.invensense import VARIANTS
    from imustation.drivers.sim.invensense import InvenSenseSim

    return InvenSenseSim(VARIANTS[driver], clock, sources["gyro"], sources["accel"], plan, quirks), plan


#: [thermometer.sim] keys: ambient temperature temp_c + temp_drift_c * sin(2 pi t / temp_period_s + phase)
THERMOMETER_SIM_KEYS = ("seed", "temp_c", "temp_drift_c", "temp_period_s", "faults")
THERMOMETER_TEMP_C = 22.0
THERMOMETER_DRIFT_C = 0.5
THERMOMETER_PERIOD_S = 6 * 3600.0


def make_thermometer_simulator(driver: str, clock, settings: dict, sim: dict, seed: int):
    """The simulator of a ``[[thermometer]]`` chip and its fault plan (contract of :func:`make_simulator`).

    The MCP9804 simulator reads an ambient temperature ``temp_c`` (default 22.0
    degC) with a slow sinusoidal drift (``temp_drift_c``, default 0.5 degC, over
    ``temp_period_s``, default 6 h; the phase is drawn from the seed, so
    thermometers in one room differ), quantised by the chip to its resolution.
    """
    import numpy as np

    from imustation.errors import SettingError

    for key in sim:
        if key not in THERMOMETER_SIM_KEYS:
            raise SettingError(f"sim.{key}: not a thermometer sim key (allowed: {', '.join(THERMOMETER_SIM_KEYS)})")
    if driver != "mcp9804":
        raise SettingError(f"thermometer driver {driver!r} has no simulator")
    from imustation.drivers.sim.mcp9804 import MCP9804Sim
    from imustation.drivers.sim.sources import sim_number, sim_seed

    seed = sim_seed(sim, seed)
    plan = _plan(clock, sim, seed)
    temp_c = sim_number(sim, "temp_c", THERMOMETER_TEMP_C)
    drift_c = sim_number(sim, "temp_drift_c", THERMOMETER_DRIFT_C)
    period_s = sim_number(sim, "temp_period_s", THERMOMETER_PERIOD_S, positive=True)
    phase = float(np.random.default_rng([seed, 0x7E4A]).uniform(0.0, 2.0 * math.pi))

    def ambient(t_s: float) -> float:
        return temp_c + drift_c * math.sin(2.0 * math.pi * t_s / period_s + phase)

    return MCP9804Sim(clock, ambient, plan), plan


def simulated_truth(config) -> dict:
    """Channel id -> the :class:`StandardModel` its simulator draws from (for demos/tests).

    ``config`` is a station config; seeds match those the station uses.
    Accelerometer models are the sensor's noise and turn-on bias; gravity
    (``sim.gravity_g``, default +1 g on z) comes on top of them.
    """
    out = {}
    for dev in config.devices:
        seed = station_device_seed(config.seed, dev.name)
        for channel, factory in SOURCES[dev.driver](dev.sim, seed).items():
            if ("replay" if channel == "gyro" else "accel_replay") in dev.sim:
                continue  # a recording: no model to compare with
            src = factory(output_rate(dev))
            for axis, model in zip(sim_axes(dev.driver), src.models, strict=True):
                out[f"{dev.name}/{channel}/{axis}"] = model
    return out


def device_sources(dev, seed: int) -> dict[str, SignalSource]:
    """Channel -> the signal source the device's simulator reads (noise model or replay), at its output rate.

    ``dev`` is a configured device, ``seed`` its per-device seed
    (:func:`station_device_seed`; ``sim.seed`` overrides it as in the simulators).
    Each source is told the output filter the device's settings select, as the chip
    simulators tell theirs from the registers the driver writes (:func:`.filters.for_device`).
    Used at the noise-model level (acquisition.modelsim, acquisition.synthesize).
    """
    from imustation.drivers.sim import filters

    factories = _with_replays(dev.driver, dev.settings, SOURCES[dev.driver](dev.sim, seed), dev.sim)
    rate = output_rate(dev)
    chip_filters = filters.for_device(dev.driver, dev.settings)
    out: dict[str, SignalSource] = {}
    for channel, factory in factories.items():
        chip_filter = chip_filters.get(channel)
        fs = rate if chip_filter is None else chip_filter.fs_out_hz
        source = with_filter(factory(fs), chip_filter)
        # an InvenSense accelerometer outputs 1 kHz: above that the chip repeats its samples
        out[channel] = source if math.isclose(fs, rate, rel_tol=1e-6) else _Held(source, rate)
    return out


class _Held:
    """A source read faster than it produces: sample ``k`` of the output is the source's
    ``floor(k fs_src / fs_hz)`` (what the InvenSense simulator does above 1 kHz)."""

    def __init__(self, source: SignalSource, fs_hz: float):
        import numpy as np

        self._np = np
        self.source, self.fs_hz = source, float(fs_hz)
        self.k = 0
        self.drawn = 0
        self.last = None

    def next(self, n: int):
        np = self._np
        idx = np.floor(np.arange(self.k, self.k + n) * self.source.fs_hz / self.fs_hz).astype(np.int64)
        self.k += n
        fresh = self.source.next(int(idx[-1]) + 1 - self.drawn)
        pool = fresh if self.last is None else np.vstack([self.last[None, :], fresh])
        first = self.drawn - (0 if self.last is None else 1)  # source index of pool[0]
        out = pool[idx - first]
        self.drawn += len(fresh)
        self.last = pool[-1]
        return out

    def temperature(self, t_s: float) -> float:
        return self.source.temperature(t_s)


def station_device_seed(station_seed: int, name: str) -> int:
    """The per-device simulation seed: stable for a device name and station seed."""
    import zlib

    return (station_seed * 1_000_003 + zlib.crc32(name.encode())) % (2**31)


def output_rate(dev: Any) -> float:
    """The output rate a device config (``driver``, ``settings``) asks for, Hz."""
    return _configured_rate(dev.driver, dev.settings)


def _configured_rate(driver: str, settings: dict) -> float:
    """Output data rate of a configured device, Hz (the ADIS16448 sets it by decimation)."""
    if driver == "adis16448":
        from imustation.drivers.adis16448 import rate_hz

        return rate_hz(settings["decimation"])
    return float(settings["rate_hz"])
