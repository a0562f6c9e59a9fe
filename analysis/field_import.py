"""Import field recordings into run-file format v1: ROS bags, MCAP, text logs, arrays.

Sources (see docs/import.md):

* ROS 1 ``.bag`` (streamed by :mod:`.rosbag1_stream`), ROS 2 bag folders (sqlite3
  or mcap storage) and bare ``.mcap`` files (the pure-Python ``rosbags`` library):
  every ``sensor_msgs/Imu`` topic (or the one given) becomes a device; ``t`` is the
  message's ``header.stamp``. ``sensor_msgs/Temperature`` topics become thermometers.
* Text logs (CSV, TSV, whitespace) with a time column; columns and time unit
  from options or auto-detected from the header (:func:`text_mapping`).
* ``.npy`` arrays of shape (n, 4) or (n, 7): time, gyro x,y,z[, accel x,y,z].

Readers yield blocks ``(t_ns int64 (k,), gyro float64 (k, 3), accel float64 (k, 3) | None)``
so a multi-GB bag is converted in bounded memory. Samples are written in file
order, never dropped or reordered; :class:`~.timestamps.StampChecker` measures
the stamps and every gap (and a summary of backward / duplicated stamps)
becomes an ``/events`` row, so the analysis splits the record at the gaps.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import re
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path

import numpy as np

from imustation.analysis.choices import TIME_UNITS
from imustation.analysis.imu_decode import IMU_MD5, decode_imu_cdr
from imustation.analysis.sample_checks import refuse_impossible
from imustation.analysis.timestamps import StampChecker, StampReport
from imustation.errors import InputError
from imustation.runfile import ChannelSpec, DeviceSpec, RunWriter

Block = tuple[np.ndarray, np.ndarray, np.ndarray | None]
#: rows per block written (and held per topic while reading)
BLOCK_ROWS = 8192
#: rows queued (all devices) before the run writer flushes: 2^16 rows = 3.7 MB (its default, 2^20, is 59 MB)
WRITE_ROWS = 1 << 16
#: samples read ahead to estimate a topic's nominal rate (the device's rate_hz)
RATE_PROBE = 2048
IMU_TYPES = ("sensor_msgs/msg/Imu", "sensor_msgs/Imu")
TEMP_TYPES = ("sensor_msgs/msg/Temperature", "sensor_msgs/Temperature")
BAG_EXTS = (".bag", ".mcap")
TEXT_EXTS = (".csv", ".tsv", ".txt", ".dat", ".log")

Progress = Callable[[int, int], None]


def source_kind(path: str) -> str:
    """``"bag"``, ``"text"`` or ``"npy"``; InputError for anything else."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{path}: no such file or folder")
    ext = p.suffix.lower()
    if p.is_dir():
        if (p / "metadata.yaml").exists() or any(p.glob("*.mcap")) or any(p.glob("*.db3")):
            return "bag"
        raise InputError(f"{path}: a folder that is not a ROS 2 bag (no metadata.yaml, .db3 or .mcap)")
    if ext in BAG_EXTS:
        return "bag"
    if ext in TEXT_EXTS:
        return "text"
    if ext == ".npy":
        return "npy"
    raise InputError(
        f"{path}: unknown input type {ext!r} (ROS .bag, ROS 2 bag folder, .mcap, CSV/TSV/text log or .npy)"
    )


def is_field_input(path: str) -> bool:
    """Inputs only the importer reads (bags, MCAP, bag folders, .tsv and other text logs)."""
    p = Path(path)
    return p.is_dir() or p.suffix.lower() in (*BAG_EXTS, ".tsv", ".dat", ".log")


# --- ROS bags ----------------------------------------------------------------


def _stamp_ns(msg) -> int:
    st = msg.header.stamp
    return int(st.sec) * 1_000_000_000 + int(st.nanosec)


def _open_bag(path: str):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    try:
        reader = AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises several reader errors; all mean "not a readable bag"
        raise InputError(f"{path}: not a readable ROS bag / MCAP file ({exc})") from None
    return reader


def _streaming(path: str, reader: str) -> bool:
    """Read with :mod:`.rosbag1_stream` (ROS 1 ``.bag`` files unless ``reader == "old"``)."""
    if reader not in ("new", "old"):
        raise ValueError(f"bag reader {reader!r}: 'new' or 'old'")
    return reader == "new" and Path(path).is_file() and path.lower().endswith(".bag")


def _ros1_index(path: str):
    from imustation.analysis.rosbag1_stream import BagFormatError, Ros1Bag

    try:
        with Ros1Bag(path) as bag:
            return bag.index()
    except (BagFormatError, OSError, struct.error) as exc:
        raise InputError(f"{path}: not a readable ROS bag / MCAP file ({exc})") from None


def bag_connections(path: str, reader: str = "new") -> list[tuple[str, str, int]]:
    """``(topic, msgtype, message count)`` of every connection of a bag."""
    if _streaming(path, reader):
        conns, counts = _ros1_index(path)
        return [(c.topic, c.msgtype, counts.get(c.id, 0)) for c in conns.values()]
    bag = _open_bag(path)
    try:
        return [(c.topic, c.msgtype, int(c.msgcount)) for c in bag.connections]
    finally:
        bag.close()


def bag_topics(path: str, topic: str | None = None, reader: str = "new") -> list[tuple[str, int]]:
    """``(topic, message count)`` of the Imu topics of a bag (only ``topic`` if given)."""
    return _imu_topics(path, topic, bag_connections(path, reader))


def _count(conns: list[tuple[str, str, int]], types: tuple[str, ...]) -> dict[str, int]:
    out: dict[str, int] = {}
    for tp, mt, n in conns:
        if mt in types:
            out[tp] = out.get(tp, 0) + n
    return out


def _imu_topics(path: str, topic: str | None, conns: list[tuple[str, str, int]]) -> list[tuple[str, int]]:
    """Imu topics and their message counts from ``(topic, msgtype, count)`` of every connection."""
    imu = _count(conns, IMU_TYPES)
    if topic is not None:
        if topic not in imu:
            have = ", ".join(sorted(imu)) or "none"
            raise InputError(f"{path}: no sensor_msgs/Imu topic {topic} (Imu topics: {have})")
        return [(topic, imu[topic])]
    if not imu:
        topics = ", ".join(sorted({c[0] for c in conns})) or "none"
        raise InputError(f"{path}: no sensor_msgs/Imu topic (topics: {topics})")
    return sorted(imu.items())


def iter_bag(
    path: str,
    topics: list[str],
    block: int = BLOCK_ROWS,
    limit: int | None = None,
    reader: str = "new",
    temp_topics: tuple[str, ...] | list[str] = (),
    notes: list[str] | None = None,
) -> Iterator[tuple[str, Block]]:
    """``(topic, block)`` of the Imu messages of ``topics`` in file order, ``block`` rows per topic at most.

    ``temp_topics``: sensor_msgs/Temperature topics, yielded as ``(topic, (t_ns, celsius (k,), None))``.
    ``limit``: stop after that many Imu messages. ``notes``: what the reader has to say is appended (the
    unreadable tail of an unindexed ROS 1 bag).
    ``reader="new"``: ROS 1 bags are read with :mod:`.rosbag1_stream` (one chunk in memory, messages decoded
    with numpy), ROS 2 bags and MCAP with rosbags, a block of raw CDR messages decoded at once with numpy.
    ``reader="old"``: rosbags for every format, messages deserialised one by one (the import as it was).
    """
    if _streaming(path, reader):
        conns, _ = _ros1_index(path)
        if all(c.md5sum == IMU_MD5 for c in conns.values() if c.topic in topics and c.msgtype in IMU_TYPES):
            yield from _iter_ros1(path, topics, block, limit, tuple(temp_topics), notes)
            return
        # an Imu definition other than sensor_msgs/Imu's: let rosbags decode it from the bag's definition
    bag = _open_bag(path)
    try:
        conns = [c for c in bag.connections if c.topic in topics and c.msgtype in IMU_TYPES]
        tconns = [c for c in bag.connections if c.topic in temp_topics and c.msgtype in TEMP_TYPES]
        # ROS 2 / MCAP: the raw CDR messages of a block are decoded together with numpy (reader="new")
        cdr = reader == "new" and all(getattr(c.ext, "serialization_format", "") == "cdr" for c in conns)
        raws: dict[str, list] = {t: [] for t in topics}
        temps: dict[str, list] = {t: [] for t in temp_topics}
        bufs = {t: np.empty((block, 7)) for t in topics}
        fill = dict.fromkeys(topics, 0)
        stamps = {t: np.empty(block, dtype=np.int64) for t in topics}
        seen = 0
        for conn, _logtime, raw in bag.messages(connections=conns + tconns):
            t = conn.topic
            if conn.msgtype in TEMP_TYPES:
                try:
                    msg = bag.deserialize(raw, conn.msgtype)
                except Exception as exc:
                    raise InputError(f"{path}: topic {t}: undecodable Temperature message ({exc})") from None
                temps[t].append((_stamp_ns(msg), float(msg.temperature)))
                if len(temps[t]) == block:
                    yield t, _temp_block(temps[t])
                    temps[t] = []
                continue
            if cdr:
                raws[t].append(raw)
                if len(raws[t]) == block:
                    yield t, _decode_cdr(path, bag, t, raws[t])
                    raws[t] = []
            else:
                try:
                    msg = bag.deserialize(raw, conn.msgtype)
                except Exception as exc:
                    raise InputError(f"{path}: topic {conn.topic}: undecodable Imu message ({exc})") from None
                i = fill[t]
                w, a = msg.angular_velocity, msg.linear_acceleration
                stamps[t][i] = _stamp_ns(msg)
                bufs[t][i] = (0.0, w.x, w.y, w.z, a.x, a.y, a.z)
                fill[t] = i + 1
                if i + 1 == block:
                    yield t, (stamps[t].copy(), bufs[t][:, 1:4].copy(), bufs[t][:, 4:7].copy())
                    fill[t] = 0
            seen += 1
            if limit is not None and seen >= limit:
                break
        for t in topics:
            k = fill[t]
            if k:
                yield t, (stamps[t][:k].copy(), bufs[t][:k, 1:4].copy(), bufs[t][:k, 4:7].copy())
            if raws[t]:
                yield t, _decode_cdr(path, bag, t, raws[t])
        for t in temp_topics:
            if temps[t]:
                yield t, _temp_block(temps[t])
    finally:
        bag.close()


def _temp_block(rows: list[tuple[int, float]]) -> tuple[np.ndarray, np.ndarray, None]:
    return np.array([r[0] for r in rows], np.int64), np.array([r[1] for r in rows], np.float64), None


def _decode_cdr(path: str, bag, topic: str, raws: list) -> Block:
    """A block of CDR Imu messages: numpy when they have the standard layout, else rosbags' deserialiser."""
    try:
        return decode_imu_cdr(raws)
    except ValueError:
        pass
    k = len(raws)
    t, g, a = np.empty(k, np.int64), np.empty((k, 3)), np.empty((k, 3))
    for i, raw in enumerate(raws):
        try:
            msg = bag.deserialize(raw, "sensor_msgs/msg/Imu")
        except Exception as exc:
            raise InputError(f"{path}: topic {topic}: undecodable Imu message ({exc})") from None
        w, acc = msg.angular_velocity, msg.linear_acceleration
        t[i], g[i], a[i] = _stamp_ns(msg), (w.x, w.y, w.z), (acc.x, acc.y, acc.z)
    return t, g, a


def _iter_ros1(
    path: str,
    topics: list[str],
    block: int,
    limit: int | None,
    temp_topics: tuple[str, ...] = (),
    notes: list[str] | None = None,
) -> Iterator[tuple[str, Block]]:
    from imustation.analysis.imu_decode import decode_imu_ros1, decode_temperature_ros1
    from imustation.analysis.rosbag1_stream import BagFormatError, Ros1Bag

    names = [*topics, *temp_topics]
    pend: dict[str, list[tuple]] = {t: [] for t in names}
    have = dict.fromkeys(names, 0)
    seen = 0
    conns: dict = {}
    try:
        with Ros1Bag(path) as bag:
            for ch in bag.chunks(conns):
                ids = [i for i, c in conns.items() if c.topic in topics and c.msgtype in IMU_TYPES]
                tids = [i for i, c in conns.items() if c.topic in temp_topics and c.msgtype in TEMP_TYPES]
                sel = np.isin(ch.conn, ids)
                if limit is not None and seen + int(sel.sum()) > limit:
                    sel &= np.cumsum(sel) <= limit - seen
                seen += int(sel.sum())
                for t in names:
                    mine = [i for i in (ids if t in topics else tids) if conns[i].topic == t]
                    m = np.isin(ch.conn, mine) & (sel if t in topics else True)
                    if not m.any():
                        continue
                    what = "Imu" if t in topics else "Temperature"
                    decode = decode_imu_ros1 if t in topics else decode_temperature_ros1
                    try:
                        dec = decode(ch.buf, ch.start[m], ch.length[m])
                    except ValueError as exc:
                        raise InputError(f"{path}: topic {t}: undecodable {what} message ({exc})") from None
                    pend[t].append(dec)
                    have[t] += len(dec[0])
                    if have[t] >= block:
                        yield from _full_blocks(t, pend, have, block)
                if limit is not None and seen >= limit:
                    break
            if bag.unread_from is not None and notes is not None:
                notes.append(
                    f"unindexed bag (recording not closed): bytes {bag.unread_from}-{bag.size} unreadable, not imported"
                )
    except (BagFormatError, struct.error) as exc:
        raise InputError(f"{path}: not a readable ROS bag ({exc})") from None
    for t in names:
        if have[t]:
            cols = [np.concatenate(x) for x in zip(*pend[t], strict=True)]
            yield t, (cols[0], cols[1], cols[2] if len(cols) > 2 else None)


def _full_blocks(t: str, pend: dict, have: dict, block: int) -> Iterator[tuple[str, Block]]:
    cols = [np.concatenate(x) for x in zip(*pend[t], strict=True)]
    n = len(cols[0])
    k = (n // block) * block
    for i in range(0, k, block):
        part = [c[i : i + block] for c in cols]
        yield t, (part[0], part[1], part[2] if len(part) > 2 else None)
    pend[t] = [tuple(c[k:] for c in cols)] if k < n else []
    have[t] = n - k


# --- text logs and arrays ----------------------------------------------------


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


def iter_text(path: str, mp: TextMapping, block: int = BLOCK_ROWS) -> Iterator[tuple[int, Block]]:
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


def load_npy_log(path: str, time_unit: str | None = None) -> Block:
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


# --- the import --------------------------------------------------------------


@dataclass
class ImportResult:
    """What was imported: the output run file and one stamp report per device."""

    path: str
    source: str
    source_format: str
    devices: dict[str, str]  # device name -> topic / column description
    reports: dict[str, StampReport]
    mapping: str = ""
    thermometers: dict[str, tuple[str, int]] = field(default_factory=dict)  # name -> (topic, readings)
    notes: list[str] = field(default_factory=list)  # reader notes (also /events notes)


def _device_name(topic: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", topic.strip("/")) or "imu"
    return name


def _refuse_shared_names(path: str, names: dict[str, str]) -> None:
    """Two topics whose names map to one device or thermometer name (/imu/a, /imu_a) cannot both be stored."""
    seen: dict[str, str] = {}
    for topic, name in names.items():
        if name in seen:
            raise InputError(
                f"{path}: topics {seen[name]} and {topic} both map to the name {name!r}; import one at a time (--topic)"
            )
        seen[name] = topic


def _iso(ns: int) -> str:
    if ns > 10**17:  # looks like a Unix epoch in ns
        return _dt.datetime.fromtimestamp(ns / 1e9, _dt.UTC).isoformat(timespec="milliseconds")
    return "1970-01-01T00:00:00.000+00:00"


def _device_spec(name: str, rate_hz: float, source: str, ident: str, fmt: str, with_accel: bool) -> DeviceSpec:
    chans = [ChannelSpec("gyro", "<f8", "rad/s", 1.0, axes=("x", "y", "z"))]
    if with_accel:
        chans.append(ChannelSpec("accel", "<f8", "m/s^2", 1.0, axes=("x", "y", "z")))
    return DeviceSpec(
        name=name,
        driver="import",
        model=fmt,
        bus=os.path.abspath(source),
        identity=ident,
        rate_hz=rate_hz,
        settings={"source": os.path.abspath(source), "source_format": fmt, "source_stream": ident},
        channels=tuple(chans),
    )


def _probe_rate(path: str, t_ns: np.ndarray) -> float:
    d = np.diff(np.asarray(t_ns, dtype=np.int64))
    d = d[d > 0]
    if len(d) == 0:
        raise InputError(f"{path}: fewer than two increasing stamps; cannot tell the sample rate")
    return 1e9 / float(np.median(d))


class _Sink:
    """Writes blocks of one device and logs the stamp problems as events."""

    def __init__(self, writer: RunWriter, name: str, t0: int, with_accel: bool, period_ns: float):
        self.w, self.name, self.t0, self.with_accel = writer, name, t0, with_accel
        self.check = StampChecker(period_ns=period_ns)
        self._logged = 0
        self._prev_last = 0

    def write(self, blk: Block) -> None:
        t, gyro, accel = blk
        start = self.check.r.n
        source = f"{self.w.devices[self.name].settings['source']}: {self.name}"
        refuse_impossible(f"{source} gyro", gyro, "rad/s", start)
        if accel is not None:
            refuse_impossible(f"{source} accel", accel, "m/s^2", start)
        rel = t - self.t0
        self.check.update(t)
        chans = {"gyro": gyro}
        if self.with_accel:
            chans["accel"] = accel if accel is not None else np.zeros_like(gyro)
        self.w.append(self.name, rel, chans)
        self._log_gaps(lambda i: int(rel[i - start]) if i >= start else self._prev_last)
        self._prev_last = int(rel[-1])

    def _log_gaps(self, stamp_of) -> None:
        for idx, dt, miss in self.check.r.gap_list[self._logged :]:
            self.w.event(stamp_of(idx), self.name, "gap", f"stamp gap {dt / 1e6:.3f} ms", lost=miss)
        self._logged = len(self.check.r.gap_list)

    def finish(self) -> StampReport:
        r = self.check.report()
        self._log_gaps(lambda i: self._prev_last)
        t_end = r.last_ns - self.t0
        if r.gaps > len(r.gap_list):
            self.w.event(t_end, self.name, "note", f"{r.gaps - len(r.gap_list)} further gaps not listed", r.missing)
        if r.backwards or r.duplicates:
            first = f"; first at sample {r.backward_list[0][0]}" if r.backward_list else ""
            self.w.event(
                t_end,
                self.name,
                "note",
                f"stamps kept in file order: {r.backwards} non-monotonic, {r.duplicates} duplicated{first}",
            )
        self.w.event(t_end, self.name, "note", "import: " + r.summary())
        return r


def import_recording(
    source: str,
    out: str,
    *,
    topic: str | None = None,
    text: dict | None = None,
    time_unit: str | None = None,
    overwrite: bool = False,
    progress: Progress | None = None,
    block: int = BLOCK_ROWS,
    bag_reader: str = "new",
) -> ImportResult:
    """Convert ``source`` into the run file ``out``; returns the stamp reports.

    ``topic``: the Imu topic of a bag (default: all). ``text``: keyword options of
    :func:`text_mapping` for text logs. ``progress(done, total)`` is called as
    the import advances (messages for bags, bytes for text, rows for arrays).
    ``bag_reader``: ``"new"`` (streaming, the default) or ``"old"`` (rosbags message by message, for
    comparison; see :func:`iter_bag`). sensor_msgs/Temperature topics of a bag become thermometers.
    """
    kind = source_kind(source)
    fsync = False  # an import is re-run from its source; no power-cut guarantee needed
    if kind == "bag":
        conns = bag_connections(source, bag_reader)
        topics = _imu_topics(source, topic, conns)
        temp_topics = sorted(_count(conns, TEMP_TYPES))  # sensor_msgs/Temperature -> /thermometers/<name>
        tnames = {t: _device_name(t) for t in temp_topics}
        treadings = dict.fromkeys(temp_topics, 0)
        total = sum(n for _, n in topics)
        # first stamps of each topic: nominal rate (device rate_hz) and the common time origin
        probe: dict[str, list[np.ndarray]] = {t: [] for t, _ in topics}
        for t, (ts, _g, _a) in iter_bag(
            source, list(probe), block=RATE_PROBE, limit=RATE_PROBE * len(probe), reader=bag_reader
        ):
            probe[t].append(ts)
        heads = {t: np.concatenate(v) if v else np.empty(0, np.int64) for t, v in probe.items()}
        t0 = min(int(v.min()) for v in heads.values() if len(v))
        names = {t: _device_name(t) for t in heads}
        _refuse_shared_names(source, {**names, **tnames})
        fmt = "mcap" if source.endswith(".mcap") else "rosbag1" if source.endswith(".bag") else "rosbag2"
        specs = [_device_spec(names[t], _probe_rate(source, heads[t]), source, t, fmt, True) for t in heads]
        writer = RunWriter(
            out, station="import", config_text="", simulated=False, devices=specs, thermometers=list(tnames.values()),
            overwrite=overwrite, started_utc=_iso(t0), fsync=fsync, ballast_bytes=0, max_buffer_rows=WRITE_ROWS,
        )  # fmt: skip
        try:
            sinks = {t: _Sink(writer, names[t], t0, True, 1e9 / s.rate_hz) for t, s in zip(heads, specs, strict=True)}
            writer.event(0, "station", "note", f"imported from {os.path.abspath(source)} ({fmt})"[:256])
            done = 0
            notes: list[str] = []
            for t, blk in iter_bag(
                source, list(heads), block=block, reader=bag_reader, temp_topics=temp_topics, notes=notes
            ):
                if t in tnames:
                    writer.append_temperature(tnames[t], blk[0] - t0, blk[1])
                    treadings[t] += len(blk[0])
                    continue
                sinks[t].write(blk)
                done += len(blk[0])
                if progress:
                    progress(done, total)
            reports = {names[t]: s.finish() for t, s in sinks.items()}
            for note in notes:
                writer.event(max(r.last_ns for r in reports.values()) - t0, "station", "note", note[:256])
        except BaseException:
            writer.abort()
            raise
        writer.close(attrs={"source": os.path.abspath(source), "source_format": fmt, "import_report": _rep(reports)})
        therm = {tnames[t]: (t, treadings[t]) for t in temp_topics}
        return ImportResult(out, source, fmt, {names[t]: t for t in heads}, reports, thermometers=therm, notes=notes)

    if kind == "text":
        mp = text_mapping(source, time_unit=time_unit, **(text or {}))
        total = os.path.getsize(source)
        blocks: Iterator = iter_text(source, mp, block)
        fmt, ident, mapping = "text", mp.summary(), mp.summary()
        with_accel = mp.accel_cols is not None
    else:
        t_all, g_all, a_all = load_npy_log(source, time_unit)
        total = len(t_all)
        blocks = ((min(i + block, total), (t_all[i : i + block], g_all[i : i + block],
                   None if a_all is None else a_all[i : i + block])) for i in range(0, total, block))  # fmt: skip
        fmt, ident, mapping = "npy", "columns t, gyro x,y,z" + (", accel x,y,z" if a_all is not None else ""), ""
        with_accel = a_all is not None
    first = next(blocks, None)
    if first is None:
        raise InputError(f"{source}: no samples")
    pos, blk = first
    t0 = int(blk[0].min())
    name = "imu"
    spec = _device_spec(name, _probe_rate(source, blk[0][:RATE_PROBE]), source, ident, fmt, with_accel)
    writer = RunWriter(
        out, station="import", config_text="", simulated=False, devices=[spec],
        overwrite=overwrite, started_utc=_iso(t0), fsync=fsync, ballast_bytes=0, max_buffer_rows=WRITE_ROWS,
    )  # fmt: skip
    try:
        sink = _Sink(writer, name, t0, with_accel, 1e9 / spec.rate_hz)
        writer.event(0, "station", "note", f"imported from {os.path.abspath(source)} ({fmt})"[:256])
        sink.write(blk)
        if progress:
            progress(pos, total)
        for pos, blk in blocks:
            sink.write(blk)
            if progress:
                progress(pos, total)
        reports = {name: sink.finish()}
    except BaseException:
        writer.abort()
        raise
    writer.close(attrs={"source": os.path.abspath(source), "source_format": fmt, "import_report": _rep(reports)})
    return ImportResult(out, source, fmt, {name: ident}, reports, mapping)


def _rep(reports: dict[str, StampReport]) -> str:
    return json.dumps({k: r.as_dict() for k, r in reports.items()})
