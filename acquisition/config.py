"""Station configuration (TOML): loading and validation.

Layout (docs/reference/design-contracts.md, "Configuration"): a ``[station]`` table and any number of
``[[device]]`` and ``[[thermometer]]`` tables; each device names a ``driver``, a
``bus`` URL, an optional ``address`` and the driver's settings; an optional
``[device.sim]`` table shapes its simulation. Every problem is reported as one
:class:`~imustation.errors.ConfigError` naming the file, the key and what is
allowed, before any hardware is touched.
"""

from __future__ import annotations

import os
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from imustation.drivers import DRIVERS, THERMOMETER_DRIVERS
from imustation.drivers.bus.spi_open import counter_pin
from imustation.drivers.bus.url import KNOWN_SCHEMES, parse_bus_url
from imustation.drivers.sim import sim_axes
from imustation.drivers.sim.faults import parse_faults
from imustation.drivers.sim.simkeys import SIM_KEYS, sim_value_problem
from imustation.errors import ConfigError, ImustationError

STATION_KEYS = {"name": str, "flush_interval_s": (int, float), "seed": int}
DEVICE_CORE_KEYS = ("name", "driver", "bus", "address", "sim")
_NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]{0,63}$")


@dataclass(frozen=True)
class DeviceConfig:
    name: str
    driver: str
    bus: str
    address: int | None
    settings: dict[str, Any]
    sim: dict[str, Any] = field(default_factory=dict)
    index: int = 0


@dataclass(frozen=True)
class ThermometerConfig(DeviceConfig):
    """A ``[[thermometer]]`` entry: the same fields as a device, a separate driver registry."""


@dataclass(frozen=True)
class StationConfig:
    path: str
    text: str
    name: str
    flush_interval_s: float
    seed: int
    devices: tuple[DeviceConfig, ...]
    thermometers: tuple[ThermometerConfig, ...] = ()


def load_config(path: str | os.PathLike) -> StationConfig:
    """Read and validate a station config file."""
    p = os.fspath(path)
    try:
        with open(p, "rb") as fh:
            raw = fh.read()
    except FileNotFoundError:
        raise ConfigError(p, None, "no such file") from None
    except OSError as exc:
        raise ConfigError(p, None, f"cannot read: {exc.strerror}") from None
    try:
        text = raw.decode("utf-8")
        data = tomllib.loads(text)
    except UnicodeDecodeError:
        raise ConfigError(p, None, "not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(p, None, f"invalid TOML: {exc}") from None
    except RecursionError:  # tomllib parses nested arrays and tables recursively
        raise ConfigError(p, None, "invalid TOML: arrays or tables nested too deep") from None
    return parse_config(data, path=p, text=text)


def parse_config(data: Mapping[str, Any], *, path: str = "<config>", text: str = "") -> StationConfig:
    for key in data:
        if key not in ("station", "device", "thermometer"):
            raise ConfigError(path, key, "unknown table (allowed: [station], [[device]], [[thermometer]])")
    station = data.get("station", {})
    if not isinstance(station, dict):
        raise ConfigError(path, "station", "must be a table")
    for key, value in station.items():
        if key not in STATION_KEYS:
            raise ConfigError(path, f"station.{key}", f"unknown key (allowed: {', '.join(STATION_KEYS)})")
        if not isinstance(value, STATION_KEYS[key]) or isinstance(value, bool):
            raise ConfigError(path, f"station.{key}", f"wrong type {type(value).__name__}")
    if not 0 <= station.get("seed", 1) < 2**63:
        raise ConfigError(path, "station.seed", f"{station['seed']}: an integer 0 .. 2^63-1")
    flush = float(station.get("flush_interval_s", 1.0))
    if not 0.05 <= flush <= 60:
        raise ConfigError(path, "station.flush_interval_s", f"{flush} outside 0.05 .. 60 s")

    devices = data.get("device", [])
    if not isinstance(devices, list) or not devices:
        raise ConfigError(path, "device", "at least one [[device]] table is required")
    names: set[str] = set()
    parsed = []
    for i, dev in enumerate(devices):
        parsed.append(_parse_device(path, i, dev, names))
    thermos = []
    for i, th in enumerate(data.get("thermometer", [])):
        thermos.append(_parse_thermometer(path, i, th, names))
    return StationConfig(
        path=path,
        text=text,
        name=str(station.get("name", "station")),
        flush_interval_s=flush,
        seed=int(station.get("seed", 1)),
        devices=tuple(parsed),
        thermometers=tuple(thermos),
    )


def _common(path: str, where: str, entry: Any, names: set[str]) -> tuple[str, str, int | None]:
    if not isinstance(entry, dict):
        raise ConfigError(path, where, "must be a table")
    name = entry.get("name")
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise ConfigError(path, f"{where}.name", f"{name!r}: a name of letters, digits, _ or - is required")
    if name in names:
        raise ConfigError(path, f"{where}.name", f"{name!r} is used twice; names must be unique")
    names.add(name)
    bus = entry.get("bus")
    if not isinstance(bus, str):
        raise ConfigError(path, f"{where}.bus", 'a bus URL string is required, e.g. "i2c:1"')
    try:
        parse_bus_url(bus, KNOWN_SCHEMES)
    except ImustationError as exc:
        raise ConfigError(path, f"{where}.bus", str(exc)) from None
    address = entry.get("address")
    if address is not None and (not isinstance(address, int) or not 0x03 <= address <= 0x77):
        raise ConfigError(path, f"{where}.address", f"{address!r}: a 7-bit I2C address 0x03..0x77")
    return name, bus, address


def _parse_device(path: str, i: int, entry: Any, names: set[str]) -> DeviceConfig:
    where = f"device[{i}]"
    name, bus, address = _common(path, where, entry, names)
    driver = entry.get("driver")
    if driver not in DRIVERS:
        raise ConfigError(path, f"{where}.driver", f"{driver!r} is not a driver (known: {', '.join(sorted(DRIVERS))})")
    sim = entry.get("sim", {})
    if not isinstance(sim, dict):
        raise ConfigError(path, f"{where}.sim", "must be a table")
    for key, value in sim.items():
        if key not in SIM_KEYS:
            raise ConfigError(path, f"{where}.sim.{key}", f"unknown key (allowed: {', '.join(SIM_KEYS)})")
        problem = sim_value_problem(key, value, len(sim_axes(driver)))
        if problem:
            raise ConfigError(path, f"{where}.sim.{key}", f"{value!r}: expected {problem}")
    try:
        parse_faults(sim.get("faults", []), "sim.faults")
    except ImustationError as exc:
        raise ConfigError(path, f"{where} ({name})", str(exc)) from None
    settings = {k: v for k, v in entry.items() if k not in DEVICE_CORE_KEYS}
    try:
        settings = DRIVERS[driver].check_settings(settings)
    except ImustationError as exc:
        raise ConfigError(path, f"{where} ({name})", str(exc)) from None
    pin = settings.get("data_ready", "none")
    if pin != "none":
        # the wire goes to the one pin the bridge counts on (a sim: bus simulates a CP2130)
        scheme = parse_bus_url(bus, KNOWN_SCHEMES).scheme
        counting = counter_pin("cp2130" if scheme == "sim" else scheme)
        if pin != counting:
            allowed = f'"{counting}" or "none"' if counting else '"none" (no bridge counter on this bus)'
            raise ConfigError(path, f"{where}.data_ready", f"{pin!r} on a {scheme}: bus: allowed {allowed}")
    if address is None:
        address = getattr(DRIVERS[driver], "default_address", None)
    return DeviceConfig(name, driver, bus, address, settings, dict(sim), i)


def _parse_thermometer(path: str, i: int, entry: Any, names: set[str]) -> ThermometerConfig:
    where = f"thermometer[{i}]"
    name, bus, address = _common(path, where, entry, names)
    driver = entry.get("driver")
    if driver not in THERMOMETER_DRIVERS:
        known = ", ".join(sorted(THERMOMETER_DRIVERS)) or "none yet"
        raise ConfigError(path, f"{where}.driver", f"{driver!r} is not a thermometer driver (known: {known})")
    sim = entry.get("sim", {})
    if not isinstance(sim, dict):
        raise ConfigError(path, f"{where}.sim", "must be a table")
    settings = {k: v for k, v in entry.items() if k not in DEVICE_CORE_KEYS}
    try:
        settings = THERMOMETER_DRIVERS[driver].check_settings(settings)
    except ImustationError as exc:
        raise ConfigError(path, f"{where} ({name})", str(exc)) from None
    return ThermometerConfig(name, str(driver), bus, address, settings, dict(sim), i)
