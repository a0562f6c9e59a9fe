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
#: rad/s -> deg/h
RADPS_TO_DPH = 1.0 / DPH2RADPS
#: m/s^2 -> micro-g
MPS2_TO_UG = 1e6 / G0
#: sqrt(s) per sqrt(h): a figure per sqrt(s) times this is per sqrt(h)
SQRT_S_PER_SQRT_H = 60.0
#: time units of text logs -> nanoseconds (``import``/``analyze --time-unit``, acquisition/importers/logs.py)
TIME_UNITS = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}

#: SI unit of a channel's samples (run-file ``units``) -> its sensor kind
SENSOR_KINDS = {"rad/s": "gyro", "m/s^2": "accel"}
#: dimension classes of noise figures: ``density`` (unit/sqrt(Hz): sigma_w, N), ``drift``
#: (unit/s/sqrt(Hz): sigma_b, K), ``rate`` (the channel unit: B, ADEV, b_on), ``angle`` (unit x s:
#: white angle noise, Q, integrated rate), ``ramp`` (unit/s: R), ``time`` (s: tau_b)
DIMENSIONS = ("density", "drift", "rate", "angle", "ramp", "time")
#: (sensor kind, dimension) -> (SI unit, display unit, SI -> display factor); display units are
#: those of the paper's Table IV (deg/h/sqrt(Hz) for gyros, micro-g/sqrt(Hz) for accelerometers)
_DISPLAY: dict[tuple[str | None, str], tuple[str, str, float]] = {
    ("gyro", "density"): ("rad/s/√Hz", "°/h/√Hz", RADPS_TO_DPH),
    ("gyro", "drift"): ("rad/s²/√Hz", "°/h/√h", RADPS_TO_DPH * SQRT_S_PER_SQRT_H),
    ("gyro", "rate"): ("rad/s", "°/h", RADPS_TO_DPH),
    ("accel", "density"): ("m/s²/√Hz", "µg/√Hz", MPS2_TO_UG),
    ("accel", "drift"): ("m/s³/√Hz", "µg/√s", MPS2_TO_UG),
    ("accel", "rate"): ("m/s²", "µg", MPS2_TO_UG),
    ("gyro", "angle"): ("rad", "°", RAD2DEG),
    ("accel", "angle"): ("m/s", "m/s", 1.0),
    ("gyro", "ramp"): ("rad/s²", "°/h²", RADPS_TO_DPH * 3600.0),
    ("accel", "ramp"): ("m/s³", "µg/s", MPS2_TO_UG),
    # a channel of unknown kind (a plain array): its own unit, no display conversion
    (None, "density"): ("unit/√Hz", "unit/√Hz", 1.0),
    (None, "drift"): ("unit/s/√Hz", "unit/s/√Hz", 1.0),
    (None, "rate"): ("unit", "unit", 1.0),
    (None, "angle"): ("unit·s", "unit·s", 1.0),
    (None, "ramp"): ("unit/s", "unit/s", 1.0),
}
for _kind in ("gyro", "accel", None):
    _DISPLAY[(_kind, "time")] = ("s", "s", 1.0)


def sensor_kind(units: str, channel_id: str = "") -> str | None:
    """``"gyro"``, ``"accel"`` or None (unknown) of a channel: from a ``device/gyro|accel/axis``
    id, else from its SI ``units`` (``rad/s``, ``m/s^2``)."""
    parts = channel_id.split("/")
    if len(parts) >= 3 and parts[-2] in ("gyro", "accel"):
        return parts[-2]
    return SENSOR_KINDS.get(units)


def display_units(kind: str | None, dimension: str) -> tuple[str, str, float]:
    """(SI unit, display unit, SI -> display factor) of a noise figure of ``dimension``
    (:data:`DIMENSIONS`) on a ``gyro``/``accel`` channel (None: unknown kind, no conversion).

    The one place the display units are defined: text tables, reports, plots, fleet
    tables and the monitor all ask here, so every number carries its own channel's unit.
    """
    try:
        return _DISPLAY[(kind, dimension)]
    except KeyError:
        raise ValueError(f"no units for a {dimension!r} figure of a {kind!r} channel") from None


# longest unit first: with "m" before "min"/"ms" the alternation stopped at "m" and 90min, 500ms failed
_DURATION_RE = re.compile(r"(\d+(?:\.\d*)?|\.\d+)\s*(min|ms|d|h|m|s)?", re.IGNORECASE)
_UNIT_S = {"d": 86400.0, "h": 3600.0, "m": 60.0, "min": 60.0, "s": 1.0, "ms": 1e-3}
#: the units a duration takes, for messages
DURATION_UNITS = "ms, s, m or min, h, d"


def parse_duration(text: str | float | int, what: str = "duration") -> float:
    """Parse ``"12h"``, ``"1h30m"``, ``"90min"``, ``"500ms"``, ``"2.5h"``, ``"2 h"`` into seconds.

    Every number needs its unit (:data:`DURATION_UNITS`): a bare ``"12"`` is refused, since
    someone meaning 12 h would otherwise record 12 s. Spaces are allowed anywhere. A Python
    number (not text) is already seconds. Raises :class:`InputError` naming ``what`` (the option,
    e.g. ``"--duration"``), the text and the accepted forms.
    """
    if isinstance(text, (int, float)):
        seconds = float(text)
    else:
        s = "".join(text.split())
        if not s:
            raise InputError(f"{what} is empty: use a number with a unit ({DURATION_UNITS}), e.g. 2h, 90m, 45s")
        if s.startswith("-"):
            try:
                parse_duration(s[1:], what)
            except InputError:
                raise InputError(
                    f"{what} {text!r}: use a positive number with a unit ({DURATION_UNITS}), e.g. 2h, 90m, 45s"
                ) from None
            raise InputError(f"{what} {text!r} must be positive")
        pos, seconds = 0, 0.0
        while pos < len(s):
            match = _DURATION_RE.match(s, pos)
            if not match:
                raise InputError(
                    f"{what} {text!r}: use numbers with units ({DURATION_UNITS}), e.g. 2h, 90m, 1h30m, 45s"
                )
            if match.group(2) is None:
                n = match.group(1)
                raise InputError(f"{what} {text!r}: {n} needs a unit ({DURATION_UNITS}), e.g. {n}s, {n}m or {n}h")
            seconds += float(match.group(1)) * _UNIT_S[match.group(2).lower()]
            pos = match.end()
    if not math.isfinite(seconds) or seconds <= 0:
        raise InputError(f"{what} {text!r} must be positive")
    return seconds


def format_duration(seconds: float) -> str:
    """``3725.0`` -> ``"1h02m05s"``; short durations keep decimals."""
    if seconds < 60:
        return f"{seconds:.3g}s"
    h, rem = divmod(int(round(seconds)), 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s"
