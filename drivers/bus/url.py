"""Bus URL grammar, in one place.

``scheme:target?key=value&key=value`` - for example ``i2c:1``,
``serial:/dev/ttyUSB0?baud=38400``, ``cp2130:``, ``sim:``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from urllib.parse import parse_qsl

from imustation.errors import InputError

KNOWN_SCHEMES = ("i2c", "sim")


@dataclass(frozen=True)
class BusURL:
    scheme: str
    target: str
    params: dict[str, str] = field(default_factory=dict)
    text: str = ""

    def __str__(self) -> str:
        return self.text


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
