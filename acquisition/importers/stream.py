"""A recording streamed into memory instead of a run file: the arrays ``analyze`` needs, no file written.

The same write loop as the import (:func:`.loop.feed`) writes into a target
that keeps what the run file would hold: per device the stamps (ns since the
first one), one float64 array per channel axis, and the device's events (the
gaps the analysis splits the record at). Thermometer readings are counted, not
kept (the analysis does not use them). Memory: the samples, 8 bytes per axis
and stamp, plus one axis while its array grows.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from imustation.acquisition.importers.loop import ImportResult, Progress, feed, fitted_rates
from imustation.acquisition.importers.messages import BLOCK_ROWS
from imustation.acquisition.importers.sources import open_recording
from imustation.runfile import DeviceSpec, Event

#: first capacity of an array, rows (it doubles when full)
COLUMN_ROWS = 1 << 16


@dataclass
class StreamedDevice:
    """One device of a streamed recording, as its run-file device would read back."""

    spec: DeviceSpec  # name, model (source format), identity, nominal rate_hz, settings, channels
    t_ns: np.ndarray  # int64 (n,): ns since the recording's first stamp (the run file's ``t``)
    columns: dict[str, tuple[np.ndarray, ...]]  # channel name -> one float64 (n,) array per axis, SI units
    events: list[Event]  # the device's events (gaps, notes) as the run file's /events would hold them


@dataclass
class StreamedRecording:
    """:func:`stream_recording`'s answer: the import summary (``result.path`` is "") and the devices."""

    result: ImportResult
    devices: dict[str, StreamedDevice]


class _Column:
    """A 1-D array filled block by block; its capacity doubles when full.

    Pages past the filled rows are never touched, so they take no memory; growing
    one column copies it once (amortised O(1) per row), so the peak is the samples
    plus one column, not twice the samples as joining a list of blocks would be.
    """

    def __init__(self, dtype):
        self._a = np.empty(COLUMN_ROWS, dtype)
        self.n = 0

    def append(self, x: np.ndarray) -> None:
        k = len(x)
        if self.n + k > len(self._a):
            grown = np.empty(max(2 * len(self._a), self.n + k), self._a.dtype)
            grown[: self.n] = self._a[: self.n]
            self._a = grown
        self._a[self.n : self.n + k] = x
        self.n += k

    def array(self) -> np.ndarray:
        return self._a[: self.n]


class _Memory:
    """A write target keeping the samples as per-axis arrays (the loop's RunWriter stand-in)."""

    def __init__(self, specs: list[DeviceSpec]):
        self.specs = {s.name: s for s in specs}
        self._t = {s.name: _Column(np.int64) for s in specs}
        self._cols = {(s.name, c.name): [_Column(c.dtype) for _ in c.axes] for s in specs for c in s.channels}
        self.events: list[Event] = []

    def append(self, device: str, t_ns: np.ndarray, channels: dict[str, np.ndarray]) -> None:
        self._t[device].append(t_ns)
        for ch in self.specs[device].channels:
            data = np.asarray(channels[ch.name], dtype=ch.dtype)  # as the run writer stores it
            for j, col in enumerate(self._cols[(device, ch.name)]):
                col.append(data[:, j])

    def append_temperature(self, name: str, t_ns: np.ndarray, celsius: np.ndarray) -> None:
        pass  # counted by the loop; not analysed

    def event(self, t_ns: int, source: str, kind: str, detail: str = "", lost: int = 0) -> None:
        self.events.append(Event(int(t_ns), source, kind, int(lost), detail))

    def devices(self) -> dict[str, StreamedDevice]:
        out = {}
        for name, spec in self.specs.items():
            columns = {c.name: tuple(col.array() for col in self._cols[(name, c.name)]) for c in spec.channels}
            events = [e for e in self.events if e.source == name]
            out[name] = StreamedDevice(spec, self._t[name].array(), columns, events)
        return out


def stream_recording(
    source: str,
    *,
    topic: str | None = None,
    text: dict | None = None,
    time_unit: str | None = None,
    progress: Progress | None = None,
    block: int = BLOCK_ROWS,
    bag_reader: str = "new",
) -> StreamedRecording:
    """``source`` read as :func:`.loop.import_recording` would import it (same options), into memory."""
    rec = open_recording(source, topic=topic, text=text, time_unit=time_unit, block=block, bag_reader=bag_reader)
    target = _Memory(list(rec.devices.values()))
    res = feed(rec, target, progress)
    # as the import stores it: the rate fitted over the whole record
    for name, hz in fitted_rates(res, rec.devices).items():
        target.specs[name] = replace(target.specs[name], rate_hz=hz)
    return StreamedRecording(res, target.devices())
