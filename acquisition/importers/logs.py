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
from imustation.analysis.pipeline.choices import TIME_UNITS
from imustation.errors import InputError

TEXT_EXTS = (".csv", ".tsv", ".txt", ".dat", ".log")


@dataclass
class TextMapping:
    """Where the quantities are in a text log: 0-based columns, time unit, gyro unit factor."""

    delimiter: str | None
    header: list[str] | None
    time_col: int
    gyro_cols: tuple[int, int, int]
    accel_cols: tuple[int, int, int] | None
    time_unit: str
    gyro_scale: float = 1.0
    auto: list[str] = field(default_factory=list)

    def summary(self) -> str:
        def name(i: int) -> str:
            return f"{self.header[i]!r}" if self.header else f"#{i}"

        acc = ", ".join(name(i) for i in self.accel_cols) if self.accel_cols else "none"
        how = f" (auto-detected: {', '.join(self.auto)})" if self.auto else ""
        return (
            f"time {name(self.time_col)} [{self.time_unit}], gyro {', '.join(name(i) for i in self.gyro_cols)}, "
            f"accel {acc}{how}"
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
    gyro_unit: str = "rad/s",
) -> TextMapping:
    """Column mapping of a text log from the options, the rest auto-detected from its first lines."""
    try:
        with open(path, encoding="utf-8") as fh:
            lines = [ln for ln in islice(fh, 200) if ln.strip() and not ln.lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
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
    low = [h.lower() for h in header] if header else []
    auto: list[str] = []

    if time_col is not None:
        tc = _resolve(path, time_col, header, ncols)
    else:
        cand = [i for i, h in enumerate(low) if h in ("t", "time") or "stamp" in h or "time" in h]
        tc = cand[0] if cand else 0
        auto.append("time column")

    def triple(spec: str | None, keys: tuple[str, ...], label: str) -> tuple[int, int, int] | None:
        if spec is not None:
            cols = tuple(_resolve(path, s, header, ncols) for s in spec.split(","))
            if len(cols) != 3:
                raise InputError(f"{path}: --{label}-columns needs three columns, got {spec!r}")
            return cols  # type: ignore[return-value]
        if header:
            cand = [i for i, h in enumerate(low) if i != tc and any(k in h for k in keys)]
            if len(cand) >= 3:
                auto.append(f"{label} columns")
                return tuple(cand[:3])  # type: ignore[return-value]
            return None
        rest = [i for i in range(ncols) if i != tc]
        off = 0 if label == "gyro" else 3
        if len(rest) >= off + 3:
            auto.append(f"{label} columns by position")
            return tuple(rest[off : off + 3])  # type: ignore[return-value]
        return None

    gc = triple(gyro_cols, ("gyr", "angular", "omega", "rate"), "gyro")
    if gc is None:
        raise InputError(
            f"{path}: no gyro columns found (columns: {', '.join(cells)}); give --gyro-columns"
            " (plain rate columns without time: analyze --rate HZ)"
        )
    ac = triple(accel_cols, ("acc", "linear"), "accel")
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
    scale = {"rad/s": 1.0, "deg/s": math.pi / 180.0}[gyro_unit]
    return TextMapping(delim, header, tc, gc, ac, time_unit, scale, auto)


def _split(line: str, delim: str | None) -> list[str]:
    return [c.strip() for c in (line.split(delim) if delim else line.split())]


def iter_text(path: str, mp: TextMapping, block: int = BLOCK_ROWS) -> Iterator[tuple[int, Rows]]:
    """``(bytes read, block)`` of a text log, in file order."""
    factor = TIME_UNITS[mp.time_unit]
    cols = [mp.time_col, *mp.gyro_cols, *(mp.accel_cols or ())]
    with open(path, encoding="utf-8") as fh:
        if mp.header is not None:
            for ln in fh:
                if ln.strip() and not ln.lstrip().startswith("#"):
                    break
        lineno = 1 if mp.header is not None else 0
        pos = 0
        while True:
            chunk = list(islice(fh, block))
            if not chunk:
                break
            pos += sum(len(c) for c in chunk)
            rows = []
            for ln in chunk:
                lineno += 1
                if not ln.strip() or ln.lstrip().startswith("#"):
                    continue
                cells = _split(ln, mp.delimiter)
                try:
                    rows.append([float(cells[i]) for i in cols])
                except (ValueError, IndexError):
                    raise InputError(f"{path}: line {lineno}: unparsable row {ln.strip()[:60]!r}") from None
            if not rows:
                continue
            arr = np.asarray(rows)
            if not np.isfinite(arr).all():
                raise InputError(f"{path}: NaN/infinite values near line {lineno}")
            t_ns = np.rint(arr[:, 0] * factor).astype(np.int64)
            accel = arr[:, 4:7] if mp.accel_cols else None
            yield pos, (t_ns, arr[:, 1:4] * mp.gyro_scale, accel)


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
    return (
        np.rint(t * TIME_UNITS[time_unit]).astype(np.int64),
        data[:, :3],
        data[:, 3:6] if data.shape[1] == 6 else None,
    )
