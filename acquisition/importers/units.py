"""The units of a text log's gyro and accel columns: from the column names, the header comments or the
options, never guessed (docs/import.md, "Units").

Logs state their units in many spellings: a suffix (``gyro_x_dps``, ``acc_x_g``, ``gx_rads``), a
bracketed unit (``Gyro X [deg/s]``, ``ax (m/s^2)``, ``az {mg}``) or a comment line before the data
(``# gyro: deg/s``, ``# units: rad/s, g``). :func:`column_unit` reads one column name,
:func:`comment_units` the comments; :data:`GYRO_UNITS` and :data:`ACCEL_UNITS` give the factor to SI
(rad/s, m/s^2). :func:`implausible_means` flags a record whose mean rate or acceleration no
static sensor shows in the unit taken (a deg/s log read as rad/s, g read as m/s^2).
"""

from __future__ import annotations

import math
import re

#: standard gravity, m/s^2 (CGPM 1901), the "g" of accelerometer data sheets
G0 = 9.80665

#: gyro units -> factor to rad/s
GYRO_UNITS = {
    "rad/s": 1.0,
    "deg/s": math.pi / 180.0,
    "mrad/s": 1e-3,
    "mdeg/s": math.pi / 180.0e3,
    "deg/h": math.pi / 180.0 / 3600.0,
}
#: accel units -> factor to m/s^2
ACCEL_UNITS = {"m/s^2": 1.0, "g": G0, "mg": G0 * 1e-3}

#: spellings (lower case, spaces removed) of each unit, as a whole bracketed unit or a name suffix
_SPELLINGS = {
    "rad/s": ("rad/s", "rad/sec", "rads", "rad_s", "radps", "radpersec", "rad.s-1", "rad*s^-1", "rad_per_s"),
    "deg/s": ("deg/s", "deg/sec", "°/s", "º/s", "dps", "degps", "deg_s", "degs", "degpersec", "deg_per_s"),
    "mrad/s": ("mrad/s", "mrads", "mrad_s"),
    "mdeg/s": ("mdeg/s", "mdps", "mdeg_s", "mdegs"),
    "deg/h": ("deg/h", "deg/hr", "°/h", "dph", "deg_h", "degph", "deg_per_h"),
    "m/s^2": ("m/s^2", "m/s2", "m/s²", "m/s/s", "m_s2", "m_s^2", "ms2", "ms^2", "mps2", "m*s^-2", "m.s-2", "ms-2"),
    "g": ("g", "gee", "g0"),
    "mg": ("mg", "milli_g", "millig"),
}
_BY_SPELLING = {s: unit for unit, spellings in _SPELLINGS.items() for s in spellings}
#: a bracketed part of a column name: ``[deg/s]``, ``(rad/s)``, ``{g}``
_BRACKETED = re.compile(r"[\[(\{]\s*([^\])\}]*?)\s*[\])\}]")
#: the suffixes a name may end in, longest first (``_mdps`` before ``_dps``)
_SUFFIXES = sorted(_BY_SPELLING, key=len, reverse=True)


def unit_of(text: str) -> str | None:
    """The unit a spelling names (``"dps"`` -> ``"deg/s"``), None for anything else."""
    return _BY_SPELLING.get(re.sub(r"\s+", "", text.lower()))


def column_unit(name: str) -> str | None:
    """The unit a column name states: bracketed (``Gyro X [deg/s]``) or a suffix after a separator
    (``gyro_x_dps``, ``acc-z-g``, ``gz_rad_s``). None when it states none."""
    for m in _BRACKETED.finditer(name):
        unit = unit_of(m.group(1))
        if unit:
            return unit
    low = re.sub(r"[\[(\{].*?[\])\}]", "", name.lower()).strip()
    for s in _SUFFIXES:
        # the unit must follow the axis: a separator before it and something before that
        m = re.fullmatch(rf"(.+?)[ _\-.]{re.escape(s)}", low)
        if m and m.group(1):
            return _BY_SPELLING[s]
    return None


def _norm(s: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", s).strip("_")


def strip_unit(name: str) -> str:
    """A normalised column name without its unit suffix (``gyro_x_dps`` -> ``gyro_x``)."""
    for s in _SUFFIXES:
        s_norm = _norm(s)
        if s_norm and name.endswith("_" + s_norm) and len(name) > len(s_norm) + 1:
            return name[: -len(s_norm) - 1]
    return name


#: a comment naming the unit of the gyro or the accel: ``# gyro: deg/s``, ``# accel [g]``,
#: ``# angular velocity in rad/s``, ``# units: rad/s, m/s^2``
_COMMENT_QTY = {
    "gyro": re.compile(r"(?:gyr|angular|omega|rate)"),
    "accel": re.compile(r"(?:acc|linear|specific.force)"),
}
_UNIT_TOKEN = re.compile(r"[A-Za-z°º/^²*.0-9_-]+")


def comment_units(lines: list[str]) -> dict[str, tuple[str, str]]:
    """``{"gyro"|"accel": (unit, the comment)}`` from header comment lines (``#`` removed or not).

    A comment that names a quantity (``gyro``, ``angular``..., ``acc``, ``linear``...) and one unit of
    its kind states that unit; ``# units: rad/s, g`` (no quantity named) states each unit for the
    quantity it can belong to. A comment naming two different units of one kind states none.
    """
    out: dict[str, tuple[str, str]] = {}
    for raw in lines:
        text = raw.strip().lstrip("#").strip()
        if not text:
            continue
        units = [unit_of(tok) for tok in _UNIT_TOKEN.findall(text)]
        gyro = {u for u in units if u in GYRO_UNITS}
        accel = {u for u in units if u in ACCEL_UNITS and u != "g"} | (
            {"g"} if any(u == "g" for u in units) and _names_g(text) else set()
        )
        low = text.lower()
        for qty, found in (("gyro", gyro), ("accel", accel)):
            if len(found) != 1 or qty in out:
                continue
            named = _COMMENT_QTY[qty].search(low)
            other = _COMMENT_QTY["accel" if qty == "gyro" else "gyro"].search(low)
            if named or (not other and "unit" in low):
                out[qty] = (next(iter(found)), raw.strip()[:80])
    return out


def _names_g(text: str) -> bool:
    """A lone ``g`` is a unit only as a word of its own (``accel [g]``, ``units: rad/s, g``)."""
    return re.search(r"(?:^|[\s\[(:,=])g(?:$|[\s\])},;])", text) is not None


#: mean |gyro| (rad/s) no record of a sensor at rest or on a vehicle reaches (a deg/s bias of a few
#: tenths read as rad/s is below it; a 2 deg/s bias in mdeg/s read as deg/s... is 35 rad/s)
GYRO_MEAN_MAX = 3.0
#: |mean accel| (m/s^2) a record shows when it holds gravity: between these (a g log read as m/s^2
#: gives ~1, an mg log read as g ~9810)
ACCEL_MEAN_RANGE = (0.5 * G0, 1.5 * G0)


def implausible_means(gyro_mean: tuple[float, ...] | None, accel_mean: tuple[float, ...] | None) -> list[str]:
    """Reasons a record's means (SI) contradict its units: the gyro's mean rate magnitude beyond
    :data:`GYRO_MEAN_MAX` rad/s, the accel's mean magnitude outside :data:`ACCEL_MEAN_RANGE` (a record
    whose sensor sees gravity). Empty when plausible."""
    out = []
    if gyro_mean is not None and len(gyro_mean):
        w = math.sqrt(sum(x * x for x in gyro_mean))
        if w > GYRO_MEAN_MAX:
            out.append(
                f"mean gyro rate {w:.4g} rad/s ({math.degrees(w):.4g} deg/s): no sensor at rest or on a vehicle "
                f"averages more than {GYRO_MEAN_MAX:g} rad/s; is the gyro unit right (--gyro-unit)?"
            )
    if accel_mean is not None and len(accel_mean) == 3:
        a = math.sqrt(sum(x * x for x in accel_mean))
        lo, hi = ACCEL_MEAN_RANGE
        if not lo <= a <= hi:
            out.append(
                f"mean acceleration {a:.4g} m/s^2 ({a / G0:.4g} g): a record holding gravity averages "
                f"near {G0:.2f} m/s^2 (1 g); is the accel unit right (--accel-unit)?"
            )
    return out
