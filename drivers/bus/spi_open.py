"""Opening a USB-SPI bridge by bus URL: the one place that knows every bridge class.

Kept out of :mod:`.spi` (the bridges' base class), which each bridge module imports: a factory
there would import the bridges back (a cycle).
"""

from __future__ import annotations

import time
from typing import Any

from imustation.drivers.bus.spi import USBSPIBridge
from imustation.drivers.bus.spi_cp2130 import CP2130
from imustation.drivers.bus.spi_mcp2210 import MCP2210
from imustation.drivers.bus.url import parse_bus_url


def open_spi(url: str, *, mode: int, sleep=time.sleep, backend: Any = None) -> USBSPIBridge:
    """Open the SPI bridge of a ``cp2130:`` or ``mcp2210:`` URL (not yet connected; see ``ensure_open``)."""
    parsed = parse_bus_url(url, ("cp2130", "mcp2210"))
    cls = CP2130 if parsed.scheme == "cp2130" else MCP2210
    return cls(parsed, mode=mode, sleep=sleep, backend=backend)


def counter_pin(scheme: str) -> str:
    """The input pin whose edges the bridge of a ``scheme:`` URL counts ("" for a bus without one)."""
    cls = {"cp2130": CP2130, "mcp2210": MCP2210}.get(scheme)
    return cls.COUNTER_PIN if cls is not None else ""
