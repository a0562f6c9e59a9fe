"""Unit constants and parsers. SI inside the code; these convert at the edges."""

from __future__ import annotations

import math
import re

from imustation.errors import InputError

DEG2RAD = math.pi / 180.0
RAD2DEG = 180.0 / math.pi
G0 = 9.80665  # standard gravity, m/s^2 (CGPM 1901)
#: rad/s per degree/hour
DPH2RADPS = DEG2RAD / 3600.0
#: one sidereal day, s; earth rate = 2 pi / sidereal day
EARTH_RATE = 2.0 * math.pi / 86164.0905

# longest unit first: with "m" before "min"/"ms" the alternation stopped at "m" and 90min, 500ms failed
_DURATION_RE = re.compile(r"(\d+(?:\.\d*)?|\.\d+)\s*(min|ms|d|h|m|s)?", re.IGNORECASE)
_UNIT_S = {"d": 86400.0, "h": 3600.0, "m": 60.0, "min": 60.0, "s": 1.0, "ms": 1e-3, None: 1.0}


def parse_duration(text: str | float | int) -> float:
    """Parse ``"12h"``, ``"1h30m"``, ``"90min"``, ``"500ms"``, ``"2.5h"`` or plain seconds into seconds.

    Raises :class:`InputError` naming the text and the accepted forms.
    """
    if isinstance(text, (int, float)):
        seconds = float(text)
    else:
        s = text.strip().replace(" ", "")
        pos, seconds = 0, 0.0
        while pos < len(s):
            match = _DURATION_RE.match(s, pos)
            if not match:
                raise InputError(f"duration {text!r}: use a number with a unit, e.g. 2h, 90m, 1h30m, 45s")
            unit = match.group(2).lower() if match.group(2) else None
            seconds += float(match.group(1)) * _UNIT_S[unit]
            pos = match.end()
        if not s:
            raise InputError("duration is empty: use e.g. 2h, 90m, 45s")
    if not math.isfinite(seconds) or seconds <= 0:
        raise InputError(f"duration {text!r} must be positive")
    return seconds


def format_duration(seconds: float) -> str:
    """``3725.0`` -> ``"1h02m05s"``; short durations keep decimals."""
    if seconds < 60:
        return f"{seconds:.3g}s"
    h, rem = divmod(int(round(seconds)), 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s"
