"""Turn a device's bus URL into the transport its driver needs, real or simulated.

The driver's ``bus_kind`` decides the transport:

* ``"i2c"`` - a register device. Real: ``i2c:N`` opens ``/dev/i2c-N`` through
  smbus2 (one adapter object per URL, shared by the devices on it). Simulated:
  each distinct URL becomes one :class:`~imustation.drivers.sim.i2c.SimSMBus`
  carrying the simulators of the devices configured on it; the same
  :class:`~imustation.drivers.bus.i2c.I2CBus` code runs on top of either.
* ``"spi"`` - an :class:`~imustation.drivers.bus.spi.SPIDevice` on a USB bridge
  (``cp2130:`` / ``mcp2210:``) through pyusb. Simulated: the same bridge code
  on a virtual pyusb backend whose bridge simulator routes the SPI bytes to the
  chip simulator (``sim:`` means a simulated CP2130).
* ``"serial"`` - a :class:`~imustation.drivers.bus.serial_port.SerialPort`
  (``serial:/dev/ttyUSB0?baud=N``) through pyserial. Simulated: the same port
  code opens ``imusim://<device>``, a pyserial URL handler whose far end is
  the device simulator.

One bridge or serial port serves one device.
"""

from __future__ import annotations

from typing import Any

from imustation.acquisition.config import DeviceConfig, ThermometerConfig
from imustation.clock import Clock
from imustation.drivers import DRIVERS, THERMOMETER_DRIVERS
from imustation.drivers.bus.base import RegisterDevice
from imustation.drivers.bus.i2c import I2CBus, open_i2c
from imustation.drivers.bus.serial_port import SerialPort
from imustation.drivers.bus.spi import USBSPIBridge
from imustation.drivers.bus.spi_open import open_spi
from imustation.drivers.bus.trace import Trace, TraceWriter, TracingTransport
from imustation.drivers.bus.url import SPI_SCHEMES, parse_bus_url, parse_usb_target
from imustation.drivers.sim import make_simulator, make_thermometer_simulator, station_device_seed
from imustation.drivers.sim.i2c import SimSMBus
from imustation.errors import ConfigError

#: URL schemes each bus kind accepts (``sim:`` only with --simulate)
SCHEMES_FOR_KIND = {"i2c": ("i2c", "sim"), "spi": (*SPI_SCHEMES, "sim"), "serial": ("serial", "sim")}
SIM_SERIAL = "0001"  # USB serial number of simulated bridges without one in the URL


class BusFactory:
    """Opens (and later closes) every bus a station needs."""

    def __init__(
        self,
        *,
        simulate: bool,
        clock: Clock,
        seed: int,
        trace: TraceWriter | None = None,
        replay: Trace | None = None,
    ):
        self.simulate = simulate
        self.clock = clock
        self.seed = seed
        #: record every transaction (``capture --trace``) / answer from a trace (``--replay``)
        self.trace = trace
        self.replay = replay
        self._i2c: dict[str, I2CBus] = {}
        #: the simulated adapter under each simulated I2C bus, where its chips are attached
        self._sim_smbus: dict[str, SimSMBus] = {}
        #: (bus URL, address) -> name of the device or thermometer using it
        self._claimed: dict[tuple[str, int], str] = {}
        self._spi: dict[str, USBSPIBridge] = {}
        self._serial: dict[str, SerialPort] = {}
        self._usb_backend: Any = None
        self._sim_names: list[str] = []

    def device_seed(self, name: str) -> int:
        return station_device_seed(self.seed, name)

    def register_device(self, dev: DeviceConfig) -> Any:
        """The transport of ``dev``: register device (I2C), SPI device or serial port.

        With a replay trace the transport answers from the trace; with a trace
        writer it is wrapped so that every transaction is recorded.
        """
        kind = DRIVERS[dev.driver].bus_kind
        if self.replay is not None:
            return self.replay.transport(dev.name, kind, self.clock)
        transport = self._open_device(dev, kind)
        return TracingTransport(transport, kind, dev.name, self.trace, self.clock) if self.trace else transport

    def _open_device(self, dev: DeviceConfig, kind: str) -> Any:
        scheme = parse_bus_url(dev.bus).scheme
        if scheme not in SCHEMES_FOR_KIND[kind]:
            allowed = ", ".join(f"{s}:" for s in SCHEMES_FOR_KIND[kind])
            raise ConfigError(
                "<config>", f"device {dev.name}.bus", f"driver {dev.driver!r} needs a {kind} bus ({allowed})"
            )
        if scheme == "sim" and not self.simulate:
            raise ConfigError("<config>", f"device {dev.name}.bus", "sim: buses need --simulate")
        if kind == "spi":
            return self._open_spi(dev)
        if kind == "serial":
            return self._open_serial(dev)
        return self._i2c_device("device", dev, make_simulator)

    def register_thermometer(self, th: ThermometerConfig) -> RegisterDevice:
        """The register device of a ``[[thermometer]]`` (I2C; simulated with ``simulate``)."""
        kind = THERMOMETER_DRIVERS[th.driver].bus_kind
        if self.replay is not None:
            return self.replay.transport(th.name, kind, self.clock)
        regs = self._open_thermometer(th, kind)
        return TracingTransport(regs, kind, th.name, self.trace, self.clock) if self.trace else regs

    def _open_thermometer(self, th: ThermometerConfig, kind: str) -> RegisterDevice:
        if kind != "i2c":
            raise ConfigError("<config>", f"thermometer {th.name}", f"bus kind {kind!r} not supported yet")
        if parse_bus_url(th.bus).scheme == "sim" and not self.simulate:
            raise ConfigError("<config>", f"thermometer {th.name}.bus", "sim: buses need --simulate")
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
                adapter = self._sim_smbus[url] = SimSMBus()
                bus = self._i2c[url] = I2CBus(adapter, url)
            chip, plan = make_sim(dev.driver, self.clock, dev.settings, dev.sim, self.device_seed(dev.name))
            self._sim_smbus[url].attach(address, chip, plan)
        else:
            bus = self._i2c.get(url) or self._i2c.setdefault(url, open_i2c(url))
        return bus.device(address)

    def _claim(self, table: dict, key: str, dev: DeviceConfig) -> None:
        if key in table:
            raise ConfigError("<config>", f"device {dev.name}.bus", f"{key} already serves another device (one each)")

    def _open_spi(self, dev: DeviceConfig) -> USBSPIBridge:
        driver = DRIVERS[dev.driver]
        url = dev.bus if not dev.bus.lower().startswith("sim:") else "cp2130:" + dev.bus[4:]
        parsed = parse_bus_url(url, SPI_SCHEMES)
        key = f"{parsed.scheme}:{parsed.target}"
        self._claim(self._spi, key, dev)
        backend = None
        if self.simulate:
            from imustation.drivers.sim.spi_bridges import CP2130Sim, MCP2210Sim
            from imustation.drivers.sim.usb_backend import SimUSBBackend

            if self._usb_backend is None:
                self._usb_backend = SimUSBBackend()
            cls = CP2130Sim if parsed.scheme == "cp2130" else MCP2210Sim
            target = parse_usb_target(parsed, 0, 0)
            chip, plan = make_simulator(dev.driver, self.clock, dev.settings, dev.sim, self.device_seed(dev.name))
            function = cls(target.serial or SIM_SERIAL, plan)
            if target.vid or target.pid:
                function.descriptor.idVendor, function.descriptor.idProduct = target.vid, target.pid
            bridge_cs = parsed.int_param("cs", 0, 0, 15)
            function.attach(bridge_cs, chip)
            pin = dev.settings.get("data_ready", "none")
            if pin == cls.COUNTER_PIN and hasattr(chip, "data_ready_edges"):
                function.wire_counter(pin, chip.data_ready_edges)  # the board's wire from DIO1
            self._usb_backend.attach(function)
            backend = self._usb_backend
        bridge = open_spi(url, mode=getattr(driver, "spi_mode", 0), sleep=self.clock.sleep, backend=backend)
        self._spi[key] = bridge
        return bridge

    def _open_serial(self, dev: DeviceConfig) -> SerialPort:
        driver = DRIVERS[dev.driver]
        url = dev.bus if not dev.bus.lower().startswith("sim:") else f"serial:sim-{dev.name}" + dev.bus[4:]
        parsed = parse_bus_url(url, ("serial",))
        self._claim(self._serial, parsed.target, dev)
        sim_url = None
        if self.simulate:
            from imustation.drivers.sim.serial_handlers import register

            chip, _plan = make_simulator(dev.driver, self.clock, dev.settings, dev.sim, self.device_seed(dev.name))
            name = f"{dev.name}-{id(self):x}"
            sim_url = register(name, chip)
            self._sim_names.append(name)
        port = SerialPort(url, baud_default=getattr(driver, "default_baud", 9600), sim_url=sim_url)
        self._serial[parsed.target] = port
        return port

    def close(self) -> None:
        for bus in self._i2c.values():
            bus.close()
        self._i2c.clear()
        self._sim_smbus.clear()
        for bridge in self._spi.values():
            bridge.close()
        self._spi.clear()
        for port in self._serial.values():
            port.close()
        self._serial.clear()
        if self._sim_names:
            from imustation.drivers.sim.serial_handlers import unregister

            for name in self._sim_names:
                unregister(name)
            self._sim_names.clear()
