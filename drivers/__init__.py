"""Chip drivers and the buses they talk through (``imustation.drivers``).

A chip driver knows registers, not transports: it receives a register device
(:class:`imustation.drivers.bus.base.RegisterDevice`) and never opens a bus.
Buses are opened from URL strings (``i2c:1``, ``cp2130:``, ``mcp2210:``,
``serial:/dev/ttyUSB0?baud=38400``, ``sim:``); simulated buses carry
byte-level chip simulators from :mod:`imustation.drivers.sim`, so a test runs
the same driver code a real capture runs.

``DRIVERS`` maps the ``driver =`` name of a config to the driver class.
"""

from imustation.channels import DriverInfo
from imustation.drivers.adis16448 import ADIS16448
from imustation.drivers.base import Block, Driver
from imustation.drivers.bmx055 import BMX055Gyro
from imustation.drivers.bmx055_accel import BMX055Accel
from imustation.drivers.invensense import MPU6500Driver, MPU9150Driver
from imustation.drivers.kvh_dsp3000 import KVHDSP3000
from imustation.drivers.mcp9804 import MCP9804
from imustation.drivers.xsens_mti import XsensMTi

DRIVERS: dict[str, type[Driver]] = {
    "bmx055": BMX055Gyro,
    "bmx055_accel": BMX055Accel,
    "mpu9150": MPU9150Driver,
    "mpu6500": MPU6500Driver,
    "adis16448": ADIS16448,
    "mti": XsensMTi,
    "dsp3000": KVHDSP3000,
}

#: ``[[thermometer]]`` drivers (slow, polled; see the thermometer drivers)
THERMOMETER_DRIVERS: dict[str, type] = {
    "mcp9804": MCP9804,
}

__all__ = [
    "DRIVERS",
    "THERMOMETER_DRIVERS",
    "Block",
    "Driver",
    "DriverInfo",
    "BMX055Gyro",
    "BMX055Accel",
    "MPU9150Driver",
    "MPU6500Driver",
    "MCP9804",
    "ADIS16448",
    "XsensMTi",
    "KVHDSP3000",
]
