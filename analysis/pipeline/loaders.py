"""Load rate channels from run files and plain arrays (.npy, .csv).

A :class:`Channel` keeps raw integer counts and their scale where the source
has them, so estimators can integrate exactly.
"""

from __future__ import annotations

import fnmatch
import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imustation.errors import InputError
from imustation.runfile import join_parts, open_series, parts_of
from imustation.runfile.breaks import locate_breaks
from imustation.runfile.holes import find_holes, holes_in_run
from imustation.sample_checks import refuse_impossible


class NoChannelsError(InputError):
    """No channel of the inputs matches the ``--channel`` globs (or the inputs hold none)."""


#: run-file channels the analysis treats as rate signals
RATE_CHANNELS = ("gyro", "accel")


@dataclass(eq=False)
class Channel:
    """One axis of rate samples.

    ``data`` holds integer counts (with ``scale`` units per count) or floats in
    ``units`` (``scale`` = 1). Run-file channels are lazy: the counts are read
    (in blocks, into one compact array of the stored integer type) on the first
    access of ``data`` and can be dropped again with :meth:`release`;
    :meth:`iter_raw` streams them without keeping them. ``gaps`` counts logged
    gap/overrun events of the device; ``segments`` are the ``[start, stop)``
    sample ranges of contiguous data between the holes (:func:`record_breaks`:
    those the timestamps and counter show, and those the events locate),
    default ``[(0, n)]``.
    """

    id: str
    fs_hz: float
    units: str
    _data: np.ndarray | None = field(default=None, repr=False)
    scale: float = 1.0
    source: str = ""
    gaps: int = 0
    meta: dict = field(default_factory=dict)
    segments: list[tuple[int, int]] = field(default_factory=list)
    #: where a lazy run-file channel lives: (path, device, channel name, column, rows)
    ref: tuple[str, str, str, int, int] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self._data is None and self.ref is None:
            raise ValueError(f"channel {self.id}: give data or a run-file reference")
        if not self.segments:
            self.segments = [(0, self.n)]

    @property
    def n(self) -> int:
        return len(self._data) if self._data is not None else self.ref[4]

    @property
    def data(self) -> np.ndarray:
        if self._data is None:
            out = None
            pos = 0
            for block in self.iter_raw():
                if out is None:
                    out = np.empty(self.n, dtype=block.dtype)
                out[pos : pos + len(block)] = block
                pos += len(block)
            self._data = out
        return self._data

    @data.setter
    def data(self, value: np.ndarray) -> None:
        self._data = value

    def release(self) -> None:
        """Drop the cached samples of a run-file channel (read again on the next access)."""
        if self.ref is not None:
            self._data = None

    def iter_raw(self, rows: int = 1 << 22) -> Iterator[np.ndarray]:
        """The raw samples (counts or floats) in blocks of ``rows``, without loading them all."""
        if self._data is not None or self.ref is None:
            for i in range(0, self.n, rows):
                yield self._data[i : i + rows]
            return
        path, device, name, column, n = self.ref
        with open_series(path) as run:
            ds = run.dataset(device, name)
            for i in range(0, n, rows):
                block = ds[i : min(i + rows, n), column]
                if block.dtype.kind == "f":  # integer counts are bounded by the chip's range
                    refuse_impossible(f"{path}: {self.id}", block * self.scale, self.units, i)
                yield block

    def rate(self) -> np.ndarray:
        """Samples in SI units (float64)."""
        return self.data.astype(np.float64) * self.scale


def record_breaks(t_ns: np.ndarray, events, rate_hz: float, counter: np.ndarray | None = None) -> list[int]:
    """Sample indices where a record breaks: every hole, logged or not.

    The holes the timestamps show against the rate (or the counter, where given:
    :func:`imustation.runfile.holes.find_holes`) and those the loss events locate
    (:func:`locate_breaks`). Returns sorted unique indices ``j``: samples ``j-1``
    and ``j`` are not neighbours.
    """
    found = find_holes(t_ns, 1e9 / rate_hz, counter).at.tolist() if len(t_ns) > 1 else []
    logged = locate_breaks(t_ns, events, rate_hz) if events else []
    return sorted(set(found) | set(logged))


def segments_from_breaks(breaks: Sequence[int], n: int) -> list[tuple[int, int]]:
    """Contiguous ``[start, stop)`` ranges of ``n`` samples split at ``breaks``."""
    edges = [0, *sorted(set(breaks)), n]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def _check_values(path: str, label: str, data: np.ndarray) -> None:
    if data.size == 0:
        raise InputError(f"{path}: {label} is empty")
    if data.dtype.kind not in "iuf":
        raise InputError(f"{path}: {label} has dtype {data.dtype}, expected numbers")
    if data.dtype.kind == "f":
        bad = int(np.count_nonzero(~np.isfinite(data)))
        if bad:
            raise InputError(f"{path}: {label} holds {bad} NaN/infinite values")


def load_run(path: str, globs: Sequence[str] = ()) -> list[Channel]:
    """Lazy channels of every selected rate axis of a run file or a rotated series
    (:func:`~imustation.runfile.open_series`), split at every hole: those its timestamps or counter
    show (:func:`imustation.runfile.holes.holes_in_run`) and those its loss events locate."""
    out = []
    with open_series(path) as run:
        events = [ev for ev in run.events() if ev.kind in ("gap", "overrun")]
        for dev in run.devices.values():
            dev_events = [ev for ev in events if ev.source == dev.name]
            segments = None
            for cname, ch in dev.channels.items():
                if cname not in RATE_CHANNELS or not ch.axes:
                    continue
                for j, axis in enumerate(ch.axes):
                    cid = f"{dev.name}/{cname}/{axis}"
                    if globs and not any(fnmatch.fnmatchcase(cid, g) for g in globs):
                        continue
                    if ch.n == 0:
                        raise InputError(f"{path}: channel {cid} has no samples")
                    if segments is None:
                        t_ds = run.dataset(dev.name, "t")
                        breaks = set(holes_in_run(run, dev.name).at.tolist())
                        breaks |= set(locate_breaks(t_ds, dev_events, dev.rate_hz) if dev_events else [])
                        segments = segments_from_breaks(sorted(breaks), ch.n)
                    out.append(
                        Channel(
                            cid,
                            dev.rate_hz,
                            ch.units,
                            None,
                            ch.scale,
                            source=path,
                            gaps=len(dev_events),
                            meta={
                                "device": dev.name,
                                "driver": dev.driver,
                                "model": dev.model,
                                "identity": dev.identity,
                                "station": str(run.attrs.get("station", "")),
                                "settings": dev.settings,
                            },
                            segments=list(segments),
                            ref=(path, dev.name, cname, j, ch.n),
                        )
                    )
    return out


def _array_channels(path: str, arr: np.ndarray, fs_hz: float | None) -> list[Channel]:
    stem = os.path.splitext(os.path.basename(path))[0]
    if fs_hz is None:
        raise InputError(f"{path}: plain arrays carry no sampling rate; give --rate HZ")
    if arr.ndim == 1:
        _check_values(path, "the array", arr)
        return [Channel(stem, fs_hz, "", np.asarray(arr), source=path)]
    if arr.ndim == 2:
        chans = []
        for j in range(arr.shape[1]):
            col = np.ascontiguousarray(arr[:, j])
            _check_values(path, f"column {j}", col)
            chans.append(Channel(f"{stem}/{j}", fs_hz, "", col, source=path))
        return chans
    raise InputError(f"{path}: array of shape {arr.shape}; expected (n,) or (n, k)")


def load_npy(path: str, fs_hz: float | None) -> list[Channel]:
    try:
        # memory-mapped first: a header claiming more rows than the file holds fails here
        # instead of allocating them
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(f"{path}: not a readable .npy array ({exc})") from None
    if not isinstance(arr, np.ndarray):
        raise InputError(f"{path}: a .npz archive, not a .npy array (save one array with numpy.save)")
    return _array_channels(path, np.array(arr), fs_hz)


def load_csv(path: str, fs_hz: float | None) -> list[Channel]:
    try:
        with open(path, encoding="utf-8") as fh:
            first = fh.readline()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text (byte {exc.start} of its first line)") from None
    delim = "," if "," in first else None
    try:
        [float(v) for v in first.replace(",", " ").split()]
        skip = 0
    except ValueError:
        skip = 1  # a header line
    try:
        arr = np.loadtxt(path, delimiter=delim, skiprows=skip, ndmin=1, comments="#")
    except ValueError as exc:
        raise InputError(f"{path}: not a numeric CSV ({exc})") from None
    return _array_channels(path, arr, fs_hz)


def load_inputs(paths: Sequence[str], globs: Sequence[str] = (), fs_hz: float | None = None) -> list[Channel]:
    """Every selected channel of every input, in order (the parts of a rotated capture as one input)."""
    channels: list[Channel] = []
    for path in join_parts(paths):
        if not os.path.exists(path) and parts_of(path) is None:
            raise InputError(f"{path}: no such file")
        ext = os.path.splitext(path)[1].lower()
        if ext in (".h5", ".hdf5"):
            channels += load_run(path, globs)
        elif ext == ".npy":
            channels += load_npy(path, fs_hz)
        elif ext in (".csv", ".txt"):
            channels += load_csv(path, fs_hz)
        else:
            raise InputError(f"{path}: unknown input type {ext!r} (run file .h5, .npy or .csv)")
    if not channels:
        sel = f" matching {', '.join(globs)}" if globs else ""
        raise NoChannelsError(f"no channels{sel} in {', '.join(paths)}")
    return channels


def recording_channels(devices: Mapping[str, Any], path: str, globs: Sequence[str] = ()) -> list[Channel]:
    """The rate channels of a field recording streamed into memory, as :func:`load_run` gives them
    for the recording imported (ids, rates, units, samples, gap count, segments, metadata), except
    ``source``: ``path``, the recording.

    ``devices``: name -> streamed device (``spec``, ``t_ns``, ``columns``, ``events``, as
    :func:`imustation.acquisition.importers.stream_recording` returns them; duck-typed, so the
    analysis imports nothing from acquisition). Split at every hole, as :func:`load_run`:
    those the stamps show and those the loss events locate (:func:`record_breaks`).
    """
    out = []
    # devices and channels in the order a run file lists them (by name): the same table as the imported run's
    for name, dev in sorted(devices.items()):
        spec = dev.spec
        breaks = [ev for ev in dev.events if ev.kind in ("gap", "overrun")]
        segments = None
        for ch in sorted(spec.channels, key=lambda c: c.name):
            if ch.name not in RATE_CHANNELS or not ch.axes:
                continue
            for j, axis in enumerate(ch.axes):
                cid = f"{name}/{ch.name}/{axis}"
                if globs and not any(fnmatch.fnmatchcase(cid, g) for g in globs):
                    continue
                if segments is None:
                    at = record_breaks(dev.t_ns, breaks, spec.rate_hz)
                    segments = segments_from_breaks(at, len(dev.t_ns))
                meta = {
                    "device": name,
                    "driver": spec.driver,
                    "model": spec.model,
                    "identity": spec.identity,
                    "station": "import",
                    "settings": {"rate_hz": spec.rate_hz, **spec.settings},
                }
                data = dev.columns[ch.name][j]
                out.append(Channel(cid, spec.rate_hz, ch.units, data, ch.scale, source=path, gaps=len(breaks),
                                   meta=meta, segments=list(segments)))  # fmt: skip
    return out


#: readings per second kept when a device's temperature channel is read (block means)
TEMP_READ_HZ = 1.0


def _t0_ns(run) -> int:
    firsts = [int(run.dataset(d, "t")[0]) for d, info in run.devices.items() if info.n > 0]
    return min(firsts) if firsts else 0


@dataclass(frozen=True)
class TemperatureRecord:
    """A device's temperature: ``t_s`` (s from the run's first sample), ``temp_c`` (°C, block means
    at ~:data:`TEMP_READ_HZ`) and ``step_c``, the resolution of its raw readings (K,
    :func:`~imustation.analysis.estimators.classical.temperature.reading_step` of the unaveraged
    readings: the block means hide the quantisation)."""

    t_s: np.ndarray
    temp_c: np.ndarray
    step_c: float


def device_temperature_record(path: str, device: str) -> TemperatureRecord:
    """A device's ``temp`` channel as a :class:`TemperatureRecord`.

    Raises :class:`InputError` if the device has no temperature channel.
    """
    from imustation.analysis.estimators.classical.temperature import reading_step

    with open_series(path) as run:
        info = run.devices.get(device)
        if info is None or "temp" not in info.channels:
            raise InputError(f"{path}: device {device} has no temperature channel")
        ch = info.channels["temp"]
        n = run.rows(device)
        m = max(1, int(round(info.rate_hz / TEMP_READ_HZ)))
        k = n // m
        if k == 0:
            raise InputError(f"{path}: device {device} has fewer than {m} temperature samples")
        raw = run.read(device, "temp", 0, k * m).astype(np.float64)
        step = reading_step(raw.reshape(len(raw), -1)[:, 0]) * abs(ch.scale)
        raw = raw.reshape(k, m, -1).mean(axis=(1, 2)) if raw.ndim > 1 else raw.reshape(k, m).mean(axis=1)
        t = run.read(device, "t", 0, k * m).astype(np.int64).reshape(k, m)[:, m // 2]
        t0 = _t0_ns(run)
    return TemperatureRecord((t - t0) * 1e-9, raw * ch.scale + ch.offset, step)


def device_temperature(path: str, device: str) -> tuple[np.ndarray, np.ndarray]:
    """A device's ``temp`` channel: times (s from the run's first sample) and °C, block-averaged to ~1 Hz.

    Raises :class:`InputError` if the device has no temperature channel.
    """
    rec = device_temperature_record(path, device)
    return rec.t_s, rec.temp_c


def thermometer_temperature(path: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Thermometer ``name`` (e.g. MCP9804): times (s from the run's first sample) and °C."""
    with open_series(path) as run:
        if name not in run.thermometers:
            raise InputError(f"{path}: no thermometer {name} (have: {', '.join(run.thermometers) or 'none'})")
        t, c = run.temperatures(name)
        t0 = _t0_ns(run)
    return (np.asarray(t, dtype=np.int64) - t0) * 1e-9, np.asarray(c, dtype=np.float64)
