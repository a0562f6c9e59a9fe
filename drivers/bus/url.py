"""Bus URL grammar, in one place (documented in ``docs/buses.md``).

``scheme:target?key=value&key=value`` - for example ``i2c:1``,
``serial:/dev/ttyUSB0?baud=38400``, ``cp2130:``, ``mcp2210:04D8:00DE/0001234?cs=1``, ``sim:``.

USB bridge targets are ``[VID:PID][/SERIAL]`` (hex VID/PID, the USB serial-number
string); an empty target means the bridge's default VID:PID, first device found.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from urllib.parse import parse_qsl

from imustation.errors import InputError

KNOWN_SCHEMES = ("i2c", "sim", "cp2130", "mcp2210", "serial")

#: schemes of SPI-over-USB bridges (``drivers/bus/spi_*.py``)
SPI_SCHEMES = ("cp2130", "mcp2210")


@dataclass(frozen=True)
class BusURL:
    scheme: str
    target: str
    params: dict[str, str] = field(default_factory=dict)
    text: str = ""

    def __str__(self) -> str:
        return self.text

    def int_param(self, key: str, default: int, lo: int, hi: int) -> int:
        """An integer query parameter within ``lo..hi`` (decimal or 0x-hex)."""
        raw = self.params.get(key)
        if raw is None:
            return default
        try:
            value = int(raw, 0)
        except ValueError:
            raise InputError(f"bus {self.text!r}: {key}={raw!r} is not an integer") from None
        if not lo <= value <= hi:
            raise InputError(f"bus {self.text!r}: {key}={value} outside {lo}..{hi}")
        return value

    def check_params(self, allowed: tuple[str, ...]) -> None:
        for key in self.params:
            if key not in allowed:
                raise InputError(f"bus {self.text!r}: unknown parameter {key!r} (allowed: {', '.join(allowed)})")


def parse_bus_url(text: str, schemes: tuple[str, ...] = KNOWN_SCHEMES) -> BusURL:
    """Split a bus URL; an unknown scheme raises :class:`InputError` listing the known ones."""
    if ":" not in text:
        raise InputError(f"bus {text!r}: expected scheme:target, e.g. i2c:1 ({', '.join(schemes)})")
    scheme, rest = text.split(":", 1)
    scheme = scheme.lower()
    if scheme not in schemes:
        raise InputError(f"bus {text!r}: unknown scheme {scheme!r} (known: {', '.join(schemes)})")
    target, _, query = rest.partition("?")
    if target.startswith("//"):
        target = target[2:]
    return BusURL(scheme, target, dict(parse_qsl(query)), text)


@dataclass(frozen=True)
class USBTarget:
    """Which USB device a bridge URL selects."""

    vid: int
    pid: int
    serial: str | None = None

    def __str__(self) -> str:
        return f"{self.vid:04X}:{self.pid:04X}" + (f"/{self.serial}" if self.serial else "")


def parse_usb_target(url: BusURL, default_vid: int, default_pid: int) -> USBTarget:
    """``[VID:PID][/SERIAL]`` of a bridge URL (hex VID/PID)."""
    ids, _, serial = url.target.partition("/")
    vid, pid = default_vid, default_pid
    if ids:
        v, sep, p = ids.partition(":")
        try:
            if not sep:
                raise ValueError
            vid, pid = int(v, 16), int(p, 16)
        except ValueError:
            raise InputError(
                f"bus {url.text!r}: expected {url.scheme}:[VID:PID][/SERIAL] with hex VID:PID, e.g. "
                f"{url.scheme}:{default_vid:04X}:{default_pid:04X}"
            ) from None
        if not (0 <= vid <= 0xFFFF and 0 <= pid <= 0xFFFF):
            raise InputError(f"bus {url.text!r}: VID/PID must be 16-bit hex numbers")
    return USBTarget(vid, pid, serial or None)
