"""Load rate channels from run files and plain arrays (.npy, .csv).

A :class:`Channel` keeps raw integer counts and their scale where the source
has them, so estimators can integrate exactly.
"""

from __future__ import annotations

import fnmatch
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from imustation.errors import InputError
from imustation.runfile import open_run

#: run-file channels the analysis treats as rate signals
RATE_CHANNELS = ("gyro", "accel")


@dataclass
class Channel:
    """One axis of rate samples.

    ``data`` holds integer counts (with ``scale`` units per count) or floats in
    ``units`` (``scale`` = 1). ``gaps`` counts logged gap/overrun events of the
    device (their samples are missing from ``data``).
    """

    id: str
    fs_hz: float
    units: str
    data: np.ndarray
    scale: float = 1.0
    source: str = ""
    gaps: int = 0
    meta: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.data)

    def rate(self) -> np.ndarray:
        """Samples in SI units (float64)."""
        return self.data.astype(np.float64) * self.scale


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
    out = []
    with open_run(path) as run:
        gaps_by_dev: dict[str, int] = {}
        for ev in run.events():
            if ev.kind in ("gap", "overrun"):
                gaps_by_dev[ev.source] = gaps_by_dev.get(ev.source, 0) + 1
        for dev in run.devices.values():
            for cname, ch in dev.channels.items():
                if cname not in RATE_CHANNELS or not ch.axes:
                    continue
                for j, axis in enumerate(ch.axes):
                    cid = f"{dev.name}/{cname}/{axis}"
                    if globs and not any(fnmatch.fnmatchcase(cid, g) for g in globs):
                        continue
                    data = run.dataset(dev.name, cname)[:, j]
                    if data.size == 0:
                        raise InputError(f"{path}: channel {cid} has no samples")
                    out.append(
                        Channel(
                            cid,
                            dev.rate_hz,
                            ch.units,
                            data,
                            ch.scale,
                            source=path,
                            gaps=gaps_by_dev.get(dev.name, 0),
                            meta={"device": dev.name, "driver": dev.driver, "settings": dev.settings},
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
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable .npy array ({exc})") from None
    return _array_channels(path, arr, fs_hz)


def load_csv(path: str, fs_hz: float | None) -> list[Channel]:
    try:
        with open(path, encoding="utf-8") as fh:
            first = fh.readline()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
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
    """Every selected channel of every input, in order."""
    channels: list[Channel] = []
    for path in paths:
        if not os.path.exists(path):
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
        raise InputError(f"no channels{sel} in {', '.join(paths)}")
    return channels
