"""Simulated hardware: byte-level chip simulators behind simulated buses.

These fakes ship beside the real drivers and answer exactly as the chips do
(register files, FIFOs), driven by signal sources (the standard noise model
with the paper's Table IV parameters, or a replayed recording). Test-only back
doors carry a ``sim_`` prefix.
"""

from imustation.drivers.sim.i2c import SimSMBus
from imustation.drivers.sim.sources import NoiseSource, SignalSource

__all__ = ["SimSMBus", "NoiseSource", "SignalSource", "make_simulator", "simulated_truth", "station_device_seed"]


def make_simulator(driver: str, clock, settings: dict, sim: dict, seed: int):
    """The byte-level simulator of ``driver``'s chip and its fault plan.

    ``settings`` are the device's validated settings, ``sim`` its ``[device.sim]``
    table, ``seed`` the per-device seed (``sim.seed`` overrides it). Returns
    ``(simulator, plan)``; the bus applies the plan's bus-level faults.
    """
    from imustation.drivers.sim.faults import FaultPlan, parse_faults
    from imustation.errors import SettingError

    plan = FaultPlan(parse_faults(sim.get("faults", [])), clock, seed) if sim.get("faults") else None
    if driver == "bmx055":
        from imustation.drivers.sim.bmx055 import BMG160Sim

        source = lambda fs: NoiseSource.for_device("bmx055", ("x", "y", "z"), fs, sim, seed)  # noqa: E731
        return BMG160Sim(clock, source, plan), plan
    if driver in _SERIAL_SPI_SIMS:
        key, axes = _SERIAL_SPI_SIMS[driver]
        source = lambda fs: NoiseSource.for_device(key, axes, fs, sim, seed)  # noqa: E731
        if driver == "adis16448":
            from imustation.drivers.sim.adis16448 import ADIS16448Sim

            return ADIS16448Sim(clock, source, plan, seed), plan
        if driver == "mti":
            from imustation.drivers.sim.xsens_mti import MTiSim

            return MTiSim(clock, source, plan, seed), plan
        from imustation.drivers.sim.kvh_dsp3000 import DSP3000Sim

        return DSP3000Sim(clock, source, plan, rate_hz=settings["rate_hz"]), plan
    raise SettingError(f"driver {driver!r} has no simulator")


#: driver -> (Table IV key, simulated gyro axes) of the SPI and serial devices
_SERIAL_SPI_SIMS = {
    "adis16448": ("adis16448", ("x", "y", "z")),
    "mti": ("mti", ("x", "y", "z")),
    "dsp3000": ("dsp3000", ("z",)),
}


def _output_rate(dev) -> float:
    if dev.driver == "adis16448":
        from imustation.drivers.adis16448 import rate_hz

        return rate_hz(dev.settings["decimation"])
    return float(dev.settings["rate_hz"])


def simulated_truth(config) -> dict:
    """Channel id -> the :class:`StandardModel` its simulator draws from (for demos/tests).

    ``config`` is a station config; seeds match those the station uses.
    """
    from imustation.drivers.sim.sources import NoiseSource

    out = {}
    for dev in config.devices:
        if dev.driver == "bmx055":
            seed = station_device_seed(config.seed, dev.name)
            src = NoiseSource.for_device("bmx055", ("x", "y", "z"), dev.settings["rate_hz"], dev.sim, seed)
            for axis, model in zip(("x", "y", "z"), src.models, strict=True):
                out[f"{dev.name}/gyro/{axis}"] = model
        elif dev.driver in _SERIAL_SPI_SIMS:
            key, axes = _SERIAL_SPI_SIMS[dev.driver]
            seed = station_device_seed(config.seed, dev.name)
            src = NoiseSource.for_device(key, axes, _output_rate(dev), dev.sim, seed)
            for axis, model in zip(axes, src.models, strict=True):
                out[f"{dev.name}/gyro/{axis}"] = model
    return out


def station_device_seed(station_seed: int, name: str) -> int:
    """The per-device simulation seed: stable for a device name and station seed."""
    import zlib

    return (station_seed * 1_000_003 + zlib.crc32(name.encode())) % (2**31)
