"""Cells of a text log read exactly: time stamps as integers of ns (no float64 rounding), and the line
of a byte that is not UTF-8.

A Unix time in ns (1.7e18) has 19 digits; float64 keeps 15-16, so ``float("1700000000123456789")``
is off by up to 128 ns, and ``1700000000.123456789`` s by as much. :func:`to_ns` reads an integer
cell as an integer and a decimal cell digit by digit, so a stamp keeps every digit down to 1 ns.
"""

from __future__ import annotations

import math


def time_exponent(factor_ns: float) -> int:
    """The power of ten of ns per unit (s -> 9, ms -> 6, us -> 3, ns -> 0)."""
    e = round(math.log10(factor_ns))
    if 10**e != factor_ns:
        raise ValueError(f"{factor_ns} ns per unit is not a power of ten")
    return e


def to_ns(cell: str, exp: int) -> int:
    """A time cell in a unit of ``10**exp`` ns as integer ns, exact to 1 ns (rounded half up beyond).

    Integers and plain decimals (``-12``, ``1700000000.0025``, ``.5``) are read digit by digit; a
    number in exponent notation through float64. ValueError for anything else or a non-finite value.
    """
    ip, dot, fp = cell.partition(".")
    if not dot:
        try:
            return int(cell) * 10**exp
        except ValueError:
            pass
    elif fp.isdigit() and fp.isascii() and len(fp) <= exp:  # the common case: a plain decimal, exact digits
        try:
            whole = int(ip) if ip.strip() not in ("", "-", "+") else 0
        except ValueError:
            whole = None
        if whole is not None and fp.strip() == fp:
            ns = abs(whole) * 10**exp + int(fp) * 10 ** (exp - len(fp))
            return -ns if ip.strip().startswith("-") else ns
    s = cell.strip()
    sign = -1 if s[:1] == "-" else 1
    body = s[1:] if s[:1] in "+-" else s
    ip, dot, fp = body.partition(".")
    if dot and (ip.isdigit() or not ip) and (fp.isdigit() or not fp) and (ip or fp) and ip.isascii():
        ns = int(ip or "0") * 10**exp + int((fp + "0" * exp)[:exp] or "0")
        if len(fp) > exp and fp[exp] >= "5":
            ns += 1
        return sign * ns
    v = float(s)  # exponent notation (1.7e9); ValueError for text
    if not math.isfinite(v):
        raise ValueError(f"non-finite time {s!r}")
    return round(v * 10**exp)


def bad_utf8_line(path: str) -> tuple[int, int, int] | None:
    """``(line number, byte offset in the file, byte value)`` of the first byte of ``path`` that is not
    UTF-8, None if all of it decodes. Reads the file line by line in binary."""
    offset = 0
    with open(path, "rb") as fh:
        for lineno, line in enumerate(fh, 1):
            try:
                line.decode("utf-8")
            except UnicodeDecodeError as exc:
                return lineno, offset + exc.start, line[exc.start]
            offset += len(line)
    return None
