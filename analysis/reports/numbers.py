"""How numbers a person reads are written: text output, tables, verdicts.

An estimate is shown with a few significant digits; a value that is not a measurement is
shown as what it is, never as a number that looks like one:

* an interval end that is infinite, or more than :data:`EXTREME_FACTOR` away from its
  estimate, is ``unbounded`` above and ``~0`` below (a profile-likelihood interval of a
  parameter the data do not pin down reaches its search range: ``[8.3e-32, 7.0e+17]`` said
  nothing but looked like a measurement);
* a spread factor (``hi / lo``) beyond :data:`EXTREME_FACTOR` is ``>1e6``, an infinite or
  undefined one ``unbounded`` (a factor 6.2e63 was printed in full);
* NaN is ``not identified`` where an estimate was expected (:func:`number`'s ``missing``);
* a p-value below the smallest one printed is ``<1e-4`` rather than ``0.0e+00``.

Machine-readable outputs (JSON, CSV) keep the numbers; these functions are for text only.
"""

from __future__ import annotations

import math

#: a value or interval end beyond this factor of its estimate is not a number worth printing
EXTREME_FACTOR = 1e6
#: what is printed instead
UNBOUNDED = "unbounded"
NEAR_ZERO = "~0"
NOT_IDENTIFIED = "not identified"
#: smallest p-value printed as a number
SMALLEST_P = 1e-4


def number(x: float | None, fmt: str = ".3g", *, missing: str = "-", infinite: str = "inf") -> str:
    """``x`` in ``fmt``; ``missing`` for None/NaN, ``infinite`` (signed) for +-inf."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return missing
    if math.isinf(x):
        return infinite if x > 0 else f"-{infinite}"
    return format(x, fmt)


def factor(ratio: float, fmt: str = ".2g") -> str:
    """A spread ``hi / lo`` (>= 1): ``"3.1"``, ``">1e6"`` beyond :data:`EXTREME_FACTOR`, ``"unbounded"`` when
    infinite or undefined."""
    if not math.isfinite(ratio) or ratio <= 0:
        return UNBOUNDED
    if ratio > EXTREME_FACTOR:
        return f">{EXTREME_FACTOR:.0e}".replace("e+0", "e")
    return format(ratio, fmt)


def interval(value: float, lo: float, hi: float, fmt: str = ".3g") -> str:
    """``"[lo, hi]"`` of an estimate ``value`` (a positive scale, rate or time): an end more than
    :data:`EXTREME_FACTOR` away from ``value`` (or infinite, or <= 0 below) is ``unbounded`` /
    ``~0``; ``"no interval"`` when an end is NaN."""
    if lo is None or hi is None or math.isnan(lo) or math.isnan(hi):
        return "no interval"
    ref = abs(value) if value is not None and math.isfinite(value) and value != 0 else math.nan
    if lo <= 0 or (math.isfinite(ref) and lo < ref / EXTREME_FACTOR):
        lo_s = NEAR_ZERO
    else:
        lo_s = number(lo, fmt, infinite=UNBOUNDED)
    if math.isinf(hi) or (math.isfinite(ref) and hi > ref * EXTREME_FACTOR):
        hi_s = UNBOUNDED
    else:
        hi_s = number(hi, fmt)
    return f"[{lo_s}, {hi_s}]"


def p_value(p: float) -> str:
    """A p-value: two digits, ``<1e-4`` below :data:`SMALLEST_P`, ``-`` when NaN."""
    if p is None or math.isnan(p):
        return "-"
    if p < SMALLEST_P:
        return f"<{SMALLEST_P:.0e}".replace("e-0", "e-")
    return f"{p:.2g}"
