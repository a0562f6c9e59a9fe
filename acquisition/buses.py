"""Turn a device's bus URL into a register device, real or simulated.

Real: ``i2c:N`` opens ``/dev/i2c-N`` through smbus2 (one adapter object per URL,
shared by the devices on it). Simulated: each distinct URL becomes one
:class:`~imustation.drivers.sim.i2c.SimSMBus` carrying the simulators of the
devices configured on it; the same :class:`~imustation.drivers.bus.i2c.I2CBus`
code runs on top of either.
"""

from __future__ import annotations

from imustation.acquisition.config import DeviceConfig, ThermometerConfig
from imustation.clock import Clock
from imustation.drivers import DRIVERS, THERMOMETER_DRIVERS
from imustation.drivers.bus.base import RegisterDevice
from imustation.drivers.bus.i2c import I2CBus, open_i2c
from imustation.drivers.bus.url import parse_bus_url
from imustation.drivers.sim import make_simulator, make_thermometer_simulator, station_device_seed
from imustation.drivers.sim.i2c import SimSMBus
from imustation.errors import ConfigError


class BusFactory:
    """Opens (and later closes) every bus a station needs."""

    def __init__(self, *, simulate: bool, clock: Clock, seed: int):
        self.simulate = simulate
        self.clock = clock
        self.seed = seed
        self._i2c: dict[str, I2CBus] = {}
        #: (bus URL, address) -> name of the device or thermometer using it
        self._claimed: dict[tuple[str, int], str] = {}

    def device_seed(self, name: str) -> int:
        return station_device_seed(self.seed, name)

    def register_device(self, dev: DeviceConfig) -> RegisterDevice:
        kind = DRIVERS[dev.driver].bus_kind
        if kind != "i2c":
            raise ConfigError("<config>", f"device {dev.name}", f"bus kind {kind!r} not supported yet")
        return self._i2c_device("device", dev, make_simulator)

    def register_thermometer(self, th: ThermometerConfig) -> RegisterDevice:
        """The register device of a ``[[thermometer]]`` (I2C; simulated with ``simulate``)."""
        kind = THERMOMETER_DRIVERS[th.driver].bus_kind
        if kind != "i2c":
            raise ConfigError("<config>", f"thermometer {th.name}", f"bus kind {kind!r} not supported yet")
        return self._i2c_device("thermometer", th, make_thermometer_simulator)

    def _i2c_device(self, what: str, dev: DeviceConfig | ThermometerConfig, make_sim) -> RegisterDevice:
        url = dev.bus
        address = dev.address
        if address is None:
            drivers = DRIVERS if what == "device" else THERMOMETER_DRIVERS
            address = getattr(drivers[dev.driver], "default_address", None)
        if address is None:
            raise ConfigError("<config>", f"{what} {dev.name}.address", "an I2C address is required")
        other = self._claimed.setdefault((url, address), dev.name)
        if other != dev.name:
            where = f"{what} {dev.name}.address"
            raise ConfigError("<config>", where, f"0x{address:02X} on {url} is already used by {other!r}")
        if self.simulate:
            bus = self._i2c.get(url)
            if bus is None:
                bus = self._i2c[url] = I2CBus(SimSMBus(), url)
            chip, plan = make_sim(dev.driver, self.clock, dev.settings, dev.sim, self.device_seed(dev.name))
            bus._smbus.attach(address, chip, plan)
        else:
            parsed = parse_bus_url(url)
            if parsed.scheme == "sim":
                raise ConfigError("<config>", f"{what} {dev.name}.bus", "sim: buses need --simulate")
            bus = self._i2c.get(url) or self._i2c.setdefault(url, open_i2c(url))
        return bus.device(address)

    def close(self) -> None:
        for bus in self._i2c.values():
            bus.close()
        self._i2c.clear()
