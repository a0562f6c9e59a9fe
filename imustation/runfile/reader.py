"""Reading run files: :func:`open_run` validates the file and returns a :class:`RunFile`.

Every reader of the format (analysis, ``imustation inspect``, the monitor)
goes through here. A file cut off by a crash reads up to its last flush; a
device whose datasets differ in length (a torn last block) reads as its
shortest dataset.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import h5py
import numpy as np

from imustation.errors import RunFileError
from imustation.runfile.checks import CheckedDataset, check_structure, damaged_file, plain_value, read_events
from imustation.runfile.schema import CELSIUS, COUNTER, DEVICES, EVENTS, THERMOMETERS, TIME, Event
from imustation.runfile.swmr import open_swmr_reader


@dataclass(frozen=True)
class ChannelInfo:
    name: str
    dtype: np.dtype
    units: str
    scale: float
    offset: float
    axes: tuple[str, ...]
    n: int


@dataclass(frozen=True)
class DeviceInfo:
    name: str
    driver: str
    model: str
    bus: str
    identity: str
    rate_hz: float
    settings: dict[str, Any]
    channels: dict[str, ChannelInfo]
    #: rows every dataset of the device holds (the shortest one: see ``rows``)
    n: int
    has_counter: bool
    #: rows per dataset; they differ only in a file cut off while a flush was
    #: being written (a torn last block), and readers use the first ``n`` rows
    rows: dict[str, int] = field(default_factory=dict)

    @property
    def torn(self) -> bool:
        return any(r != self.n for r in self.rows.values())


_DEVICE_CORE_ATTRS = {"driver", "model", "bus", "identity"}


@dataclass
class RunFile:
    """An open run file (read-only). Use :func:`open_run`; close or use ``with``."""

    path: str
    h5: h5py.File
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        """True when the capture closed cleanly (``ended_utc`` present)."""
        return "ended_utc" in self.attrs

    @property
    def devices(self) -> dict[str, DeviceInfo]:
        out = {}
        for name, g in self.h5.get(DEVICES, {}).items():
            attrs = {k: plain_value(v) for k, v in g.attrs.items()}
            channels = {}
            for cname, ds in g.items():
                if cname in (TIME, COUNTER):
                    continue
                axes = plain_value(ds.attrs.get("axes", ""))
                channels[cname] = ChannelInfo(
                    name=cname,
                    dtype=ds.dtype,
                    units=plain_value(ds.attrs.get("units", "")),
                    scale=float(ds.attrs.get("scale", 1.0)),
                    offset=float(ds.attrs.get("offset", 0.0)),
                    axes=tuple(axes.split(",")) if axes else (),
                    n=ds.shape[0],
                )
            settings = {k: v for k, v in attrs.items() if k not in _DEVICE_CORE_ATTRS}
            out[name] = DeviceInfo(
                name=name,
                driver=attrs.get("driver", ""),
                model=attrs.get("model", ""),
                bus=attrs.get("bus", ""),
                identity=str(attrs.get("identity", "")),
                rate_hz=float(attrs.get("rate_hz", float("nan"))),
                settings=settings,
                channels=channels,
                n=min((ds.shape[0] for ds in g.values()), default=0),
                has_counter=COUNTER in g,
                rows={k: ds.shape[0] for k, ds in g.items()},
            )
        return out

    @property
    def thermometers(self) -> list[str]:
        return list(self.h5.get(THERMOMETERS, {}).keys())

    def thermometer_rate_hz(self, name: str) -> float | None:
        """Thermometer ``name``'s configured poll rate, Hz; None in a file that does not store it (written
        before it was stored, or imported from a log that has no configured rate)."""
        rate = self.h5[f"{THERMOMETERS}/{name}"].attrs.get("rate_hz")
        return None if rate is None else float(rate)

    def events(self) -> list[Event]:
        return read_events(self.path, self.h5)

    def dataset(self, device: str, name: str) -> h5py.Dataset:
        try:
            return CheckedDataset(self.h5[f"{DEVICES}/{device}/{name}"], self.path, f"{device}/{name}")
        except KeyError:
            raise RunFileError(f"{self.path}: no dataset {device}/{name}") from None

    def rows(self, device: str) -> int:
        """Rows every dataset of ``device`` holds (a torn last block is left out)."""
        g = self.h5.get(f"{DEVICES}/{device}")
        if g is None:
            raise RunFileError(f"{self.path}: no device {device}")
        return min((ds.shape[0] for ds in g.values()), default=0)

    def read(self, device: str, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Raw rows ``start:stop`` of ``devices/<device>/<name>`` (at most :meth:`rows`)."""
        n = self.rows(device)
        return self.dataset(device, name)[start : n if stop is None else min(stop, n)]

    def iter_chunks(self, device: str, name: str, rows: int = 1 << 22, stop: int | None = None) -> Iterator[np.ndarray]:
        """Read a dataset in blocks of ``rows`` so memory stays bounded."""
        ds = self.dataset(device, name)
        n = self.rows(device) if stop is None else min(stop, self.rows(device))
        for i in range(0, n, rows):
            yield ds[i : min(i + rows, n)]

    def temperatures(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Thermometer ``name``: times (ns) and readings (degC), equal lengths."""
        g = self.h5[f"{THERMOMETERS}/{name}"]
        n = min(g[TIME].shape[0], g[CELSIUS].shape[0])
        with damaged_file(self.path, f"thermometer {name}/t", g[TIME]):
            t = g[TIME][:n]
        with damaged_file(self.path, f"thermometer {name}/celsius", g[CELSIUS]):
            return t, g[CELSIUS][:n]

    def refresh(self) -> None:
        """SWMR reader: see what the writer flushed since the file was opened (or last refreshed).

        Refreshes every dataset's extent (devices, thermometers, events); a file
        opened without SWMR is left as it is.
        """
        if not self.h5.swmr_mode:
            return
        for gname in (DEVICES, THERMOMETERS):
            for g in self.h5.get(gname, {}).values():
                for ds in g.values():
                    ds.refresh()
        if EVENTS in self.h5:
            self.h5[EVENTS].refresh()

    def close(self) -> None:
        self.h5.close()

    def __enter__(self) -> RunFile:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_run(path: str | os.PathLike, *, live: bool = False) -> RunFile:
    """Open a run file read-only (also while it is being written).

    ``live=True`` (a reader kept beside a running capture, e.g. the monitor):
    SWMR read only, never the plain read-only fallback, which holds a shared
    file lock that would keep the capture from marking the file complete.

    Raises :class:`RunFileError` with a one-line reason for a missing file,
    a file that is not HDF5, not an imustation run, or of an unknown version.
    """
    p = os.fspath(path)
    if not os.path.exists(p):
        raise RunFileError(f"{p}: no such file")
    try:
        # a live reader takes no file lock at all: even the short one HDF5 holds while
        # opening could make the capture's final reopen (to set ended_utc) fail
        h5 = open_swmr_reader(p, locking=False if live else None)
    except OSError as first:
        if live:
            raise RunFileError(f"{p}: not a readable SWMR run file ({first.__class__.__name__})") from None
        try:  # a file written without SWMR (e.g. by another tool) still opens
            h5 = h5py.File(p, "r")
        except OSError as exc:
            raise RunFileError(f"{p}: not a readable HDF5 file ({exc.__class__.__name__})") from None
    try:
        attrs = check_structure(h5, p)
    except RunFileError:
        h5.close()
        raise
    return RunFile(path=p, h5=h5, attrs=attrs)
