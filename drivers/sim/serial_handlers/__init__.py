"""pyserial URL handlers for simulated serial devices (``imusim://<name>``).

``serial.serial_for_url("imusim://mti-1")`` finds :mod:`.protocol_imusim`
through ``serial.protocol_handler_packages`` (this package is appended by
:func:`register`) and connects to the device simulator registered under that
name, so :class:`imustation.drivers.bus.serial_port.SerialPort` opens a
simulated port exactly as it opens a tty.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from imustation.drivers.sim.serial_device import SerialDeviceSim

#: name -> device simulator reachable as imusim://name
DEVICES: dict[str, SerialDeviceSim] = {}
SCHEME = "imusim"


def register(name: str, device: SerialDeviceSim) -> str:
    """Make ``device`` reachable; return its pyserial URL."""
    import serial

    if __name__ not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(__name__)
    DEVICES[name] = device
    return f"{SCHEME}://{name}"


def unregister(name: str) -> None:
    DEVICES.pop(name, None)
