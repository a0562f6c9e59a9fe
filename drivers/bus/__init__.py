"""Buses, opened from URL strings.

``i2c:N``  - Linux ``/dev/i2c-N`` through smbus2 (:mod:`.i2c`).
``sim:``   - a simulated bus; the station attaches chip simulators to it.

Real and simulated buses share one class per bus kind; only the lowest seam
(the smbus2 object, the pyusb backend, the pyserial port) differs.
"""

from imustation.drivers.bus.base import RegisterDevice
from imustation.drivers.bus.i2c import I2CBus, I2CDevice, open_i2c
from imustation.drivers.bus.url import BusURL, parse_bus_url

__all__ = ["RegisterDevice", "I2CBus", "I2CDevice", "open_i2c", "BusURL", "parse_bus_url"]
