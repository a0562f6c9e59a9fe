"""What kind of field recording a path is, and each kind opened as one :class:`Recording`.

A :class:`Recording` is what the write loop (:mod:`.loop`) needs of any source:
the devices it holds (one per Imu topic of a bag, one ``imu`` for a log or an
array) with their nominal rates, the time origin, the thermometers, and the
blocks in file order. Opening reads just enough (a bag's index and the first
stamps of each topic; a log's first block) to tell those.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from itertools import chain
from pathlib import Path

import numpy as np

from imustation.acquisition.importers.bags import (
    BAG_EXTS,
    bag_connections,
    bag_format,
    imu_topics,
    iter_bag,
    temperature_topics,
)
from imustation.acquisition.importers.logs import AXES, TEXT_EXTS, iter_text, load_npy_log, text_mapping
from imustation.acquisition.importers.messages import BLOCK_ROWS, Rows
from imustation.acquisition.importers.timestamps import check_stamps
from imustation.errors import InputError
from imustation.runfile import ChannelSpec, DeviceSpec

#: samples read ahead to estimate a topic's nominal rate (the device's rate_hz until the record is read)
RATE_PROBE = 2048
#: the units of sensor_msgs/Imu (REP 103) and of an imported .npy (docs/import.md), with where they come from
ROS_UNITS = {"gyro": ("rad/s", "sensor_msgs/Imu (REP 103)"), "accel": ("m/s^2", "sensor_msgs/Imu (REP 103)")}
NPY_UNITS = {"gyro": ("rad/s", ".npy import (SI by definition)"), "accel": ("m/s^2", ".npy import (SI by definition)")}


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


@dataclass
class Recording:
    """An opened source: its devices, time origin and blocks (consumed once, by the write loop)."""

    source: str
    fmt: str  # device model: rosbag1, rosbag2, mcap, text, npy
    t0: int  # first stamp, ns: the run's time origin
    #: reader key (Imu topic; "" for a log or an array) -> device, in device order
    devices: dict[str, DeviceSpec]
    #: ``(reader key, progress position or None, block)`` in file order
    blocks: Iterator[tuple[str, int | None, Rows]]
    total: int  # progress total: messages (bags), bytes (logs) or rows (arrays)
    thermometers: dict[str, str] = field(default_factory=dict)  # Temperature topic -> thermometer name
    mapping: str = ""  # the column mapping of a log, as printed
    notes: list[str] = field(default_factory=list)  # filled by the reader as it goes


def open_recording(
    source: str,
    *,
    topic: str | None = None,
    text: dict | None = None,
    time_unit: str | None = None,
    block: int = BLOCK_ROWS,
    bag_reader: str = "new",
) -> Recording:
    """``source`` opened for the write loop; options as :func:`.loop.import_recording`'s."""
    kind = source_kind(source)
    if kind == "bag":
        return _open_bag(source, topic, block, bag_reader)
    if kind == "text":
        mp = text_mapping(source, time_unit=time_unit, **(text or {}))
        blocks: Iterator[tuple[int, Rows, np.ndarray | None]] = iter_text(source, mp, block)
        axes = (mp.gyro_axes, mp.accel_axes if mp.accel_cols is not None else None)
        units = {"gyro": (mp.gyro_unit, mp.gyro_unit_from)}
        if mp.accel_cols is not None:
            units["accel"] = (mp.accel_unit, mp.accel_unit_from)
        rec = _open_log(source, "text", mp.summary(), axes, blocks, os.path.getsize(source), mp.temp_col is not None,
                        units)  # fmt: skip
        rec.mapping = mp.summary()
        return rec
    t_all, g_all, a_all = load_npy_log(source, time_unit)
    total = len(t_all)
    blocks = ((min(i + block, total), (t_all[i : i + block], g_all[i : i + block],
               None if a_all is None else a_all[i : i + block]), None) for i in range(0, total, block))  # fmt: skip
    ident = "columns t, gyro x,y,z" + (", accel x,y,z" if a_all is not None else "")
    return _open_log(source, "npy", ident, (AXES, AXES if a_all is not None else None), blocks, total, False,
                     NPY_UNITS)  # fmt: skip


def _open_bag(source: str, topic: str | None, block: int, reader: str) -> Recording:
    conns = bag_connections(source, reader)
    topics = imu_topics(source, topic, conns)
    temps = temperature_topics(conns)  # sensor_msgs/Temperature -> /thermometers/<name>
    # first stamps of each topic: nominal rate (device rate_hz) and the common time origin
    probe: dict[str, list[np.ndarray]] = {t: [] for t, _ in topics}
    for t, (ts, _g, _a) in iter_bag(
        source, list(probe), block=RATE_PROBE, limit=RATE_PROBE * len(probe), reader=reader
    ):
        probe[t].append(ts)
    heads = {t: np.concatenate(v) if v else np.empty(0, np.int64) for t, v in probe.items()}
    notes: list[str] = []
    # a topic with no messages (or too few to tell a rate) beside good ones is skipped, and said so
    empty = {t: len(h) for t, h in heads.items() if _increasing(h) < 2}
    if empty and len(empty) < len(heads):
        for t, k in empty.items():
            del heads[t]
            notes.append(f"Imu topic {t} skipped: {k} message{'s' if k != 1 else ''}, too few to tell a sample rate")
    elif empty:
        listing = ", ".join(f"{t} ({k} messages)" for t, k in empty.items())
        raise InputError(f"{source}: no Imu topic with two increasing stamps: {listing}")
    fmt = bag_format(source)
    devices = {
        t: _device_spec(_device_name(t), _probe_rate(source, h), source, t, fmt, True, units=ROS_UNITS)
        for t, h in heads.items()
    }
    t0 = min(int(v.min()) for v in heads.values())
    thermometers = {t: _device_name(t) for t in temps}
    _refuse_shared_names(source, {**{t: d.name for t, d in devices.items()}, **thermometers})

    def blocks() -> Iterator[tuple[str, int | None, Rows]]:
        done = 0
        for t, blk in iter_bag(source, list(heads), block=block, reader=reader, temp_topics=temps, notes=notes):
            if t in thermometers:
                yield t, None, blk
                continue
            done += len(blk[0])
            yield t, done, blk

    total = sum(n for t, n in topics if t in heads)
    return Recording(source, fmt, t0, devices, blocks(), total, thermometers, notes=notes)


def _increasing(t_ns: np.ndarray) -> int:
    """Stamps of ``t_ns`` that a rate can be told from: 0 or 1 without an increasing step, else 2."""
    return 2 if len(t_ns) > 1 and bool((np.diff(t_ns) > 0).any()) else min(len(t_ns), 1)


#: reader key of a log's temperature column (its device's key is "")
LOG_TEMPERATURE = "temperature"


def _open_log(
    source: str,
    fmt: str,
    ident: str,
    axes: tuple[tuple[str, ...], tuple[str, ...] | None],
    blocks: Iterator[tuple[int, Rows, np.ndarray | None]],
    total: int,
    with_temperature: bool = False,
    units: dict[str, tuple[str, str]] | None = None,
) -> Recording:
    """A log or an array: one device ``imu`` with the gyro (and accel) ``axes`` (accel None: none);
    its first block gives the rate and the time origin. A temperature column becomes the
    thermometer ``imu_temperature`` (as a bag's Temperature topic does)."""
    first = next(blocks, None)
    if first is None:
        raise InputError(f"{source}: no samples")
    t = first[1][0]
    spec = _device_spec(
        "imu", _probe_rate(source, t[:RATE_PROBE]), source, ident, fmt, axes[1] is not None, axes, units
    )

    def keyed() -> Iterator[tuple[str, int | None, Rows]]:
        for pos, blk, celsius in chain([first], blocks):
            yield "", pos, blk
            if celsius is not None:
                yield LOG_TEMPERATURE, None, (blk[0], celsius, None)

    thermometers = {LOG_TEMPERATURE: "imu_temperature"} if with_temperature else {}
    return Recording(source, fmt, int(t.min()), {"": spec}, keyed(), total, thermometers)


def _refuse_shared_names(path: str, names: dict[str, str]) -> None:
    """Two topics whose names map to one device or thermometer name (/imu/a, /imu_a) cannot both be stored."""
    seen: dict[str, str] = {}
    for topic, name in names.items():
        if name in seen:
            raise InputError(
                f"{path}: topics {seen[name]} and {topic} both map to the name {name!r}; import one at a time (--topic)"
            )
        seen[name] = topic


def _device_name(topic: str) -> str:
    """A topic as a device (or thermometer) name: ``/imu/data`` -> ``imu_data``."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", topic.strip("/")) or "imu"


def _device_spec(
    name: str,
    rate_hz: float,
    source: str,
    ident: str,
    fmt: str,
    with_accel: bool,
    axes: tuple[tuple[str, ...], tuple[str, ...] | None] = (AXES, AXES),
    units: dict[str, tuple[str, str]] | None = None,
) -> DeviceSpec:
    """An imported device: ``gyro`` (and ``accel``) as float64 in SI units, ``driver = "import"``;
    ``axes``: the gyro's and accel's axis names (a single-axis log: ``("z",)``); ``units``: channel ->
    (unit of the source, where it was read), stored as the settings ``source_<channel>_unit`` and
    ``source_<channel>_unit_from`` (docs/runfile.md)."""
    chans = [ChannelSpec("gyro", "<f8", "rad/s", 1.0, axes=axes[0])]
    if with_accel:
        chans.append(ChannelSpec("accel", "<f8", "m/s^2", 1.0, axes=axes[1] or AXES))
    stated = {}
    for ch in chans:
        unit, frm = (units or {}).get(ch.name, (ch.units, ""))
        stated[f"source_{ch.name}_unit"] = unit
        stated[f"source_{ch.name}_unit_from"] = frm
    return DeviceSpec(
        name=name,
        driver="import",
        model=fmt,
        bus=os.path.abspath(source),
        identity=ident,
        rate_hz=rate_hz,
        settings={"source": os.path.abspath(source), "source_format": fmt, "source_stream": ident, **stated},
        channels=tuple(chans),
    )


def _probe_rate(path: str, t_ns: np.ndarray) -> float:
    """Nominal rate of the first stamps ``t_ns`` (ns), Hz: the least-squares fit over their regular steps
    (:func:`.timestamps.check_stamps`; never the median step). The write loop replaces it with the fit
    over the whole record when it ends (:func:`.loop.fitted_rates`); until then it sets the gap threshold."""
    rate = check_stamps(np.asarray(t_ns, dtype=np.int64)).true_rate_hz
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(f"{path}: fewer than two increasing stamps; cannot tell the sample rate")
    return rate
