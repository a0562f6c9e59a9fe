"""Text logs (CSV, TSV, ``;``, whitespace) and ``.npy`` arrays: a time column, gyro and accel columns.

Columns and time unit come from the options or are auto-detected from the
header and the first rows (:func:`text_mapping`, rules in docs/import.md). A
log is read in blocks of rows (bounded memory); an array is memory-mapped.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from itertools import islice

import numpy as np

from imustation.acquisition.importers.messages import BLOCK_ROWS, Rows
from imustation.acquisition.importers.textcells import bad_utf8_line, time_exponent, to_ns
from imustation.acquisition.importers.units import ACCEL_UNITS, GYRO_UNITS, column_unit, comment_units, strip_unit
from imustation.errors import InputError
from imustation.units import TIME_UNITS

TEXT_EXTS = (".csv", ".tsv", ".txt", ".dat", ".log")


#: axis column names (normalised: lower case, units in brackets dropped, separators as ``_``):
#: a prefix naming the sensor, an optional separator, the axis. gx, wx, gyro_x, gyr_x, omega_x,
#: angular_velocity_x, rate_x; ax, acc_x, accel_x, linear_acceleration_x
_GYRO_NAME = re.compile(r"(?:g|w|gyr|gyro|gyroscope|omega|angular_velocity|angular_rate|ang_vel|rate)_?([xyz])")
_ACCEL_NAME = re.compile(r"(?:a|acc|accel|accelerometer|acceleration|linear_acceleration|lin_acc)_?([xyz])")
#: temperature column names (normalised as above)
_TEMP_NAMES = ("temp", "temperature", "temp_c", "temperature_c", "tempc", "t_c", "t_degc", "die_temp", "imu_temp")
#: substrings of a gyro / accel header when no column follows the axis naming (the columns then
#: take the axes x, y, z in order)
_GYRO_HINTS = ("gyr", "angular", "omega", "rate")
_ACCEL_HINTS = ("acc", "linear")
AXES = ("x", "y", "z")


@dataclass
class TextMapping:
    """Where the quantities are in a text log: 0-based columns, their axes, time unit, gyro unit factor.

    ``gyro_cols`` (1 to 3 columns) with ``gyro_axes`` (their axis names, e.g. ``("z",)`` for a
    single-axis fibre-optic gyro log); ``accel_cols``/``accel_axes`` likewise or None;
    ``temp_col`` a temperature column (°C) or None; ``auto`` says what was detected.
    """

    delimiter: str | None
    header: list[str] | None
    time_col: int
    gyro_cols: tuple[int, ...]
    accel_cols: tuple[int, ...] | None
    time_unit: str
    gyro_scale: float = 1.0
    auto: list[str] = field(default_factory=list)
    gyro_axes: tuple[str, ...] = AXES
    accel_axes: tuple[str, ...] = AXES
    temp_col: int | None = None
    ignored: tuple[int, ...] = ()
    #: the units the gyro / accel columns are in (keys of .units.GYRO_UNITS / ACCEL_UNITS) and where
    #: each was read ("column names", "header comment '# gyro: deg/s'", "--gyro-unit")
    gyro_unit: str = "rad/s"
    gyro_unit_from: str = ""
    accel_unit: str | None = None
    accel_unit_from: str = ""
    accel_scale: float = 1.0
    #: accel columns found but not read: no accel channel selected (``text_mapping(accel=False)``)
    accel_unread: tuple[int, ...] = ()

    def summary(self) -> str:
        """Which columns were taken: ``time 't' [s], gyro z <- 'gz', accel none, temperature none``."""

        def name(i: int) -> str:
            return f"{self.header[i]!r}" if self.header else f"#{i}"

        def axes(cols, names) -> str:
            return ", ".join(f"{a} <- {name(i)}" for a, i in zip(names, cols, strict=True))

        def unit(u, frm) -> str:
            return f" [{u}, from {frm}]" if frm else f" [{u}]"

        acc = axes(self.accel_cols, self.accel_axes) if self.accel_cols else "none"
        if self.accel_unread:
            acc = f"{', '.join(name(i) for i in self.accel_unread)} not read (no accel channel selected)"
        if self.accel_cols:
            acc += unit(self.accel_unit, self.accel_unit_from)
        temp = f"temperature {name(self.temp_col)} [°C]" if self.temp_col is not None else "temperature none"
        ign = f", ignored {', '.join(name(i) for i in self.ignored)}" if self.ignored else ""
        how = f" (auto-detected: {', '.join(self.auto)})" if self.auto else ""
        return (
            f"time {name(self.time_col)} [{self.time_unit}], gyro {axes(self.gyro_cols, self.gyro_axes)}"
            f"{unit(self.gyro_unit, self.gyro_unit_from)}, "
            f"accel {acc}, {temp}{ign}{how}"
        )


def _resolve(path: str, spec: str, header: list[str] | None, ncols: int) -> int:
    spec = spec.strip()
    if spec.lstrip("-").isdigit():
        i = int(spec)
    elif header and spec in header:
        i = header.index(spec)
    else:
        raise InputError(f"{path}: no column {spec!r} (columns: {', '.join(header) if header else ncols})")
    if not 0 <= i < ncols:
        raise InputError(f"{path}: column {spec} out of range (the log has {ncols} columns)")
    return i


def _normalise(name: str) -> str:
    """``"Gyro X [rad/s]"``, ``"gyro_x_dps"`` -> ``"gyro_x"``: lower case, bracketed units and unit
    suffixes dropped, separators as ``_``."""
    name = re.sub(r"[\[(\{].*?[\])\}]", "", name.lower())
    return strip_unit(re.sub(r"[^a-z0-9]+", "_", name).strip("_"))


def _named_axes(low: list[str], pattern: re.Pattern, skip: set[int]) -> dict[str, int]:
    """Axis -> first column whose normalised name matches ``pattern`` (``gx``, ``gyro_x``...)."""
    found: dict[str, int] = {}
    for i, h in enumerate(low):
        m = pattern.fullmatch(h)
        if m and i not in skip:
            found.setdefault(m.group(1), i)
    return found


def _guess_unit(path: str, col_name: str | None, dt: float) -> str:
    if col_name:
        m = re.search(r"(?:^|[^a-z])(ns|us|ms|s)(?:[^a-z]|$)", col_name.lower().replace("sec", "s"))
        if m:
            return m.group(1)
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f"{path}: cannot tell the time unit (no increasing stamps); give --time-unit")
    # IMU periods are 0.1 ms .. 1 s: pick the unit that puts the median step there
    if dt < 0.05:
        return "s"
    if dt < 50:
        return "ms"
    if dt < 5e4:
        return "us"
    return "ns"


def text_mapping(
    path: str,
    *,
    time_col: str | None = None,
    gyro_cols: str | None = None,
    accel_cols: str | None = None,
    time_unit: str | None = None,
    gyro_unit: str | None = None,
    accel_unit: str | None = None,
    accel: bool = True,
) -> TextMapping:
    """Column mapping of a text log from the options, the rest auto-detected from its first lines.

    ``accel`` False (``analyze --channel`` selecting no accel channel): accel columns the options do not
    name are not read, and their unit is not asked for (they are listed as not read in the mapping).

    Gyro and accel columns: the options (1 to 3 names or indices), else the headers named
    like an axis (``gx``, ``wx``, ``gyro_x``, ``omega_x``...; ``ax``, ``acc_x``, ``accel_x``...; units
    in brackets ignored), else the headers containing ``gyr``/``angular``/``omega``/``rate`` and
    ``acc``/``linear`` (axes x, y, z in order), else (no header) the columns after the time column:
    gyro x, y, z, accel x, y, z — one- and two-axis logs (``t,gz``) included. A column named
    ``temperature``/``temp`` is the temperature (°C).

    Units of the gyro and accel columns: ``gyro_unit``/``accel_unit`` (keys of
    :data:`.units.GYRO_UNITS`/:data:`.units.ACCEL_UNITS`), else the column names (``gyro_x_dps``,
    ``ax [g]``), else a header comment (``# gyro: deg/s``); a sensor column with no unit stated is
    refused (InputError naming ``--gyro-unit``/``--accel-unit``). Rules in docs/import.md.
    """
    try:
        with open(path, encoding="utf-8") as fh:
            head = list(islice(fh, 200))
    except UnicodeDecodeError:
        raise InputError(_not_utf8(path)) from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    lines = [ln for ln in head if ln.strip() and not ln.lstrip().startswith("#")]
    comments = [ln for ln in head if ln.lstrip().startswith("#")]
    if not lines:
        raise InputError(f"{path}: empty log")
    first = lines[0]
    delim = "\t" if "\t" in first else "," if "," in first else ";" if ";" in first else None
    cells = [c.strip() for c in (first.split(delim) if delim else first.split())]
    try:
        [float(c) for c in cells]
        header = None
        body = lines
    except ValueError:
        header = cells
        body = lines[1:]
    ncols = len(cells)
    low = [_normalise(h) for h in header] if header else []
    auto: list[str] = []

    if time_col is not None:
        tc = _resolve(path, time_col, header, ncols)
    else:
        raw = [h.lower() for h in header] if header else []
        cand = [i for i, h in enumerate(raw) if h in ("t", "time") or "stamp" in h or "time" in h]
        tc = cand[0] if cand else 0
        auto.append("time column")

    def columns(spec: str | None, pattern: re.Pattern, hints: tuple[str, ...], label: str, skip: set[int]):
        """(columns, axes) of ``label`` or None."""
        if spec is not None:
            cols = tuple(_resolve(path, s, header, ncols) for s in spec.split(","))
            if not 1 <= len(cols) <= 3 or len(set(cols)) != len(cols):
                raise InputError(f"{path}: --{label}-columns needs one to three different columns, got {spec!r}")
            named = [pattern.fullmatch(low[i]) for i in cols] if header else []
            if named and all(named) and len({m.group(1) for m in named}) == len(cols):
                return cols, tuple(m.group(1) for m in named)
            return cols, AXES[: len(cols)]
        if header:
            found = _named_axes(low, pattern, skip | {tc})
            if found:
                auto.append(f"{label} columns by name")
                axes = tuple(a for a in AXES if a in found)
                return tuple(found[a] for a in axes), axes
            cand = [i for i, h in enumerate(low) if i != tc and i not in skip and any(k in h for k in hints)][:3]
            if cand:
                auto.append(f"{label} columns by name (axes in order)")
                return tuple(cand), AXES[: len(cand)]
            return None
        rest = [i for i in range(ncols) if i != tc]
        off = 0 if label == "gyro" else 3
        cols = tuple(rest[off : off + 3])
        if cols:
            auto.append(f"{label} columns by position")
            return cols, AXES[: len(cols)]
        return None

    gyro = columns(gyro_cols, _GYRO_NAME, _GYRO_HINTS, "gyro", set())
    if gyro is None:
        raise InputError(
            f"{path}: no gyro columns found (columns: {', '.join(cells)}); name them gx/gy/gz, wx.., gyro_x.. "
            "or give --gyro-columns (plain rate columns without time: analyze --rate HZ)"
        )
    gc, g_axes = gyro
    found = columns(accel_cols, _ACCEL_NAME, _ACCEL_HINTS, "accel", set(gc))
    ac, a_axes = found if found is not None else (None, AXES)
    unread = ac if ac is not None and not accel and accel_cols is None else ()
    if unread:  # not selected: neither read nor asked a unit for
        ac = None
    used = {tc, *gc, *(ac or ())}
    temp = next((i for i, h in enumerate(low) if h in _TEMP_NAMES and i not in used), None) if header else None
    if temp is not None:
        auto.append("temperature column")
        used.add(temp)
    ignored = tuple(i for i in range(ncols) if i not in used and i not in unread)
    try:
        rows = [_split(ln, delim) for ln in body[:100]]
        tt = np.array([float(r[tc]) for r in rows])
    except (ValueError, IndexError) as exc:
        raise InputError(f"{path}: unparsable time column {cells[tc]!r} ({exc})") from None
    if time_unit is None:
        d = np.diff(tt)
        d = d[d > 0]
        time_unit = _guess_unit(path, header[tc] if header else None, float(np.median(d)) if len(d) else math.nan)
        auto.append("time unit")
    if time_unit not in TIME_UNITS:
        raise InputError(f"{path}: time unit {time_unit!r}: use one of {', '.join(TIME_UNITS)}")
    stated = comment_units(comments)
    g_unit, g_from = _unit(path, "gyro", gyro_unit, GYRO_UNITS, gc, header, stated)
    mp = TextMapping(delim, header, tc, gc, ac, time_unit, GYRO_UNITS[g_unit], auto, g_axes, a_axes, temp, ignored)
    mp.gyro_unit, mp.gyro_unit_from = g_unit, g_from
    mp.accel_unread = tuple(unread)
    if ac is not None:
        a_unit, a_from = _unit(path, "accel", accel_unit, ACCEL_UNITS, ac, header, stated)
        mp.accel_unit, mp.accel_unit_from, mp.accel_scale = a_unit, a_from, ACCEL_UNITS[a_unit]
    return mp


def _unit(
    path: str,
    label: str,
    given: str | None,
    table: dict[str, float],
    cols: tuple[int, ...],
    header: list[str] | None,
    stated: dict[str, tuple[str, str]],
) -> tuple[str, str]:
    """``(unit, where it was read)`` of the ``label`` columns ``cols``: the option, else the column
    names, else a header comment; InputError when none states it or the names disagree."""
    names = [header[i] for i in cols] if header else []
    said = {n: column_unit(n) for n in names}
    said = {n: u for n, u in said.items() if u is not None and u in table}
    if given is not None:
        if given not in table:
            raise InputError(f"{path}: --{label}-unit {given!r}: use one of {', '.join(table)}")
        others = sorted({u for u in said.values() if u != given})
        note = f" (the column names say {', '.join(others)})" if others else ""
        return given, f"--{label}-unit{note}"
    if said:
        units = set(said.values())
        if len(units) > 1 or len(said) < len(names):
            listing = ", ".join(f"{n!r}: {said.get(n, 'none')}" for n in names)
            raise InputError(f"{path}: the {label} columns state different units ({listing}); give --{label}-unit")
        return units.pop(), "column names"
    if label in stated:
        unit, line = stated[label]
        return unit, f"header comment {line!r}"
    cols_named = ", ".join(repr(n) for n in names) if names else f"columns {', '.join(str(i) for i in cols)}"
    raise InputError(
        f"{path}: no unit stated for the {label} ({cols_named}); name it in the header "
        f"({'gyro_x_dps, gx [rad/s]' if label == 'gyro' else 'acc_x_g, ax [m/s^2]'}) or give --{label}-unit "
        f"({'|'.join(table)})"
    )


def _not_utf8(path: str) -> str:
    where = bad_utf8_line(path)
    if where is None:
        return f"{path}: not UTF-8 text"
    line, at, byte = where
    return f"{path}: line {line}: byte 0x{byte:02x} at offset {at} is not UTF-8 text (save the log as UTF-8)"


def _split(line: str, delim: str | None) -> list[str]:
    return [c.strip() for c in (line.split(delim) if delim else line.split())]


def iter_text(path: str, mp: TextMapping, block: int = BLOCK_ROWS) -> Iterator[tuple[int, Rows, np.ndarray | None]]:
    """``(bytes read, block, temperature °C or None)`` of a text log, in file order.

    Stamps are read exactly (:func:`.textcells.to_ns`: an integer column as integers, a decimal
    one digit by digit); a byte that is not UTF-8 and a NaN are reported with their line number.
    """
    exp = time_exponent(TIME_UNITS[mp.time_unit])
    temp = [] if mp.temp_col is None else [mp.temp_col]
    cols = [*mp.gyro_cols, *(mp.accel_cols or ()), *temp]
    tc = mp.time_col
    ng, na = len(mp.gyro_cols), len(mp.accel_cols or ())
    try:
        with open(path, encoding="utf-8") as fh:
            yield from _blocks(path, fh, mp, block, exp, tc, cols, ng, na, bool(temp))
    except UnicodeDecodeError:
        raise InputError(_not_utf8(path)) from None


def _blocks(path, fh, mp: TextMapping, block: int, exp: int, tc: int, cols: list[int], ng: int, na: int, temp: bool):
    lineno = 0  # lines read so far: the comments and blank lines before the header count too
    if mp.header is not None:
        for ln in fh:
            lineno += 1
            if ln.strip() and not ln.lstrip().startswith("#"):
                break
    pos = 0
    while True:
        chunk = list(islice(fh, block))
        if not chunk:
            break
        pos += sum(len(c) for c in chunk)
        rows, stamps, lines = [], [], []
        for ln in chunk:
            lineno += 1
            if not ln.strip() or ln.lstrip().startswith("#"):
                continue
            cells = _split(ln, mp.delimiter)
            try:
                stamps.append(to_ns(cells[tc], exp))
                rows.append([float(cells[i]) for i in cols])
            except (ValueError, IndexError):
                if len(cells) > tc and cells[tc].strip().lower().lstrip("+-") in ("nan", "inf", "infinity"):
                    raise InputError(f"{path}: line {lineno}: NaN/infinite time stamp") from None
                raise InputError(f"{path}: line {lineno}: unparsable row {ln.strip()[:60]!r}") from None
            lines.append(lineno)
        if not rows:
            continue
        arr = np.asarray(rows, dtype=np.float64).reshape(len(rows), len(cols))
        finite = np.isfinite(arr).all(axis=1)
        if not finite.all():
            raise InputError(f"{path}: line {lines[int(np.argmin(finite))]}: NaN/infinite value")
        try:
            t_ns = np.array(stamps, dtype=np.int64)
        except OverflowError:
            raise InputError(f"{path}: a time stamp beyond the int64 ns range (year 2262) near line {lineno}") from None
        accel = arr[:, ng : ng + na] * mp.accel_scale if mp.accel_cols else None
        celsius = arr[:, ng + na] if temp else None
        yield pos, (t_ns, arr[:, :ng] * mp.gyro_scale, accel), celsius


def load_npy_log(path: str, time_unit: str | None = None) -> Rows:
    """An (n, 4) or (n, 7) array: time, gyro x,y,z[, accel x,y,z] (memory-mapped)."""
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(f"{path}: not a readable .npy array ({exc})") from None
    if not isinstance(arr, np.ndarray):
        raise InputError(f"{path}: a .npz archive, not a .npy array (save one array with numpy.save)")
    if arr.ndim != 2 or arr.shape[1] not in (4, 7) or arr.dtype.kind not in "iuf":
        raise InputError(f"{path}: array of shape {arr.shape}; import needs (n, 4) or (n, 7): time, gyro[, accel]")
    t = np.asarray(arr[:, 0], dtype=np.float64)
    if time_unit is None:
        d = np.diff(t[:1000])
        d = d[d > 0]
        time_unit = _guess_unit(path, None, float(np.median(d)) if len(d) else math.nan)
    data = np.asarray(arr[:, 1:], dtype=np.float64)
    if not (np.isfinite(data).all() and np.isfinite(t).all()):
        raise InputError(f"{path}: NaN/infinite values")
    if arr.dtype.kind in "iu":  # integer stamps stay integers (unix ns does not fit a float64's 53 bits)
        t_ns = np.asarray(arr[:, 0], dtype=np.int64) * (10 ** time_exponent(TIME_UNITS[time_unit]))
    else:
        t_ns = np.rint(t * TIME_UNITS[time_unit]).astype(np.int64)
    return (
        t_ns,
        data[:, :3],
        data[:, 3:6] if data.shape[1] == 6 else None,
    )
