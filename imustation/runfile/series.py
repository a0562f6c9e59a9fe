"""Rotated captures read as one run: ``week.001.h5``, ``week.002.h5``, ... as one record per channel.

``capture --rotate 6h -o week.h5`` writes complete run files ``week.001.h5``,
``week.002.h5``, ... that share ``run_id`` and ``started_utc``, so sample times
continue from one part to the next (docs/runfile.md, "Rotation"). A command names
such a series by its base name (``week.h5``: no file of that name exists, its parts
do), by a range of its parts (``week.002-004.h5``) or by listing the parts;
:func:`join_parts` turns a command's inputs into series names and
:func:`open_series` opens a name as a :class:`RunSeries`, which reads like one
:class:`~imustation.runfile.RunFile`: every device with the samples of all parts,
the events of all parts, reads across the hand-overs.

The parts are checked before anything is read: one ``run_id``, consecutive part
numbers, the same devices, channels and thermometers, sample times that go on
where the previous part stopped; anything else is one :class:`RunFileError` line.
Where a device's sample times jump at a hand-over and no logged gap accounts for
it, the series adds a ``gap`` event, so readers cut the record there as at any
logged gap.
"""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Iterator, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from imustation.errors import RunFileError
from imustation.runfile.breaks import locate_breaks
from imustation.runfile.reader import DeviceInfo, Event, RunFile, open_run
from imustation.runfile.schema import LOSS_KINDS, TIME

#: ``week.002.h5`` -> stem ``week``, part 2, extension ``.h5`` (part numbers have at least 3 digits)
_PART = re.compile(r"^(?P<stem>.+)\.(?P<part>\d{3,})(?P<ext>\.[^.]+)$")
#: ``week.002-004.h5``: parts 2 to 4 of ``week.h5``
_RANGE = re.compile(r"^(?P<stem>.+)\.(?P<lo>\d{3,})-(?P<hi>\d{3,})(?P<ext>\.[^.]+)$")
#: root attributes that describe one part, not the series
_PART_ATTRS = ("part", "previous_part", "next_part", "part_started_utc")


def part_path(output: str, part: int) -> str:
    """``run.h5``, part 3 -> ``run.003.h5`` (the name of a rotated capture's part)."""
    stem, ext = os.path.splitext(output)
    return f"{stem}.{part:03d}{ext or '.h5'}"


def base_of_part(path: str) -> tuple[str, int] | None:
    """``dir/week.002.h5`` -> (``dir/week.h5``, 2); None for a name that is not a part's."""
    m = _PART.match(path)
    return (m["stem"] + m["ext"], int(m["part"])) if m else None


def range_name(base: str, first: int, last: int) -> str:
    """The name of parts ``first``..``last`` of ``base``: ``week.h5``, 2, 4 -> ``week.002-004.h5``."""
    stem, ext = os.path.splitext(base)
    return f"{stem}.{first:03d}-{last:03d}{ext}"


def series_parts(base: str) -> list[str]:
    """The part files of ``base`` that exist, in part order (empty when there are none)."""
    stem, ext = os.path.splitext(base)
    found = []
    for p in glob.glob(f"{glob.escape(stem)}.[0-9][0-9][0-9]*{glob.escape(ext)}"):
        got = base_of_part(p)
        if got is not None and got[0] == base and os.path.isfile(p):
            found.append((got[1], p))
    return [p for _, p in sorted(found)]


def parts_of(name: str) -> list[str] | None:
    """The part files the series name ``name`` stands for, or None when it is no series name
    (an existing file is always itself; a base name without parts is just a missing file)."""
    if os.path.exists(name):
        return None
    m = _RANGE.match(name)
    if m:
        base, lo, hi = m["stem"] + m["ext"], int(m["lo"]), int(m["hi"])
        return [part_path(base, k) for k in range(lo, hi + 1)] if hi >= lo else None
    return series_parts(name) or None


def latest_part(name: str) -> str:
    """The newest part of a series name (the one a running capture writes), else ``name`` itself."""
    parts = parts_of(name)
    return parts[-1] if parts else name


def _part_identity(path: str) -> tuple[str, int] | None:
    """(run_id, part) of a readable rotated part; None for anything else (it is read as it is)."""
    if not path.lower().endswith((".h5", ".hdf5")) or not os.path.isfile(path):
        return None
    try:
        with open_run(path) as run:
            rid, part = run.attrs.get("run_id"), run.attrs.get("part")
    except RunFileError:
        return None  # the command that reads it reports the damage
    return (str(rid), int(part)) if rid and part is not None else None


def join_parts(paths: Sequence[str]) -> list[str]:
    """A command's inputs with the parts of each rotated capture joined into one series name.

    Two or more parts of one capture (same ``run_id``) become one name, at the place of
    the first: the base name when they are all its parts, else the range
    (``week.002-004.h5``). A single part stays a file of its own. Raises
    :class:`RunFileError` when the parts named are not consecutive or not named
    ``<base>.<NNN><ext>`` after their part numbers.
    """
    ids = {p: _part_identity(p) for p in dict.fromkeys(paths)}
    groups: dict[str, list[tuple[int, str]]] = {}
    for p, ident in ids.items():
        if ident is not None:
            groups.setdefault(ident[0], []).append((ident[1], p))
    names: dict[str, str] = {}
    for rid, members in groups.items():
        if len(members) < 2:
            continue
        members.sort()
        listed = ", ".join(os.path.basename(p) for _, p in members)
        twice = [k for (k, _), (k2, _) in zip(members, members[1:], strict=False) if k == k2]
        if twice:
            raise RunFileError(f"{listed}: part {twice[0]} of one rotated capture (run_id {rid}) is named twice")
        named = [base_of_part(os.path.normpath(p)) for _, p in members]
        base = named[0][0] if named[0] is not None else ""
        if any(b is None or b != (base, k) for b, (k, _) in zip(named, members, strict=True)):
            raise RunFileError(
                f"{listed}: parts of one rotated capture (run_id {rid}) must keep their names <base>.<part>.h5"
            )
        numbers = [k for k, _ in members]
        missing = sorted(set(range(numbers[0], numbers[-1] + 1)) - set(numbers))
        if missing:
            raise RunFileError(
                f"{listed}: parts of one rotated capture (run_id {rid}) with part {missing[0]} missing; "
                f"name every part from {numbers[0]} to {numbers[-1]}, or the base name {base}"
            )
        whole = [os.path.normpath(p) for p in series_parts(base)] == [os.path.normpath(p) for _, p in members]
        names[members[0][1]] = base if whole and not os.path.exists(base) else range_name(base, numbers[0], numbers[-1])
        names.update((p, "") for _, p in members[1:])  # joined into the first
    return [names.get(p, p) for p in paths if names.get(p, p)]


def open_series(name: str | os.PathLike, *, live: bool = False) -> RunFile | RunSeries:
    """Open a run file, or the parts a series name stands for as one :class:`RunSeries`.

    Raises :class:`RunFileError` with one line for a missing file or part, a damaged
    part, or parts that are not one capture's consecutive parts.
    """
    name = os.fspath(name)
    parts = parts_of(name)
    if parts is None:
        return open_run(name, live=live)
    return RunSeries.open(name, parts, live=live)


class _SeriesDataset:
    """One dataset of every part as one: length, dtype and slicing like an HDF5 dataset's."""

    def __init__(self, series: RunSeries, device: str, name: str):
        self._series, self._device, self._name = series, device, name
        first = series.parts[0].dataset(device, name)
        self.dtype = first.dtype
        self._counts = series._counts(device)  # rows per part, read once (binary searches index row by row)
        self.shape = (sum(self._counts), *first.shape[1:])

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key: Any) -> Any:
        rest: tuple[Any, ...] = ()
        if isinstance(key, tuple):
            key, rest = key[0], key[1:]
        if isinstance(key, slice):
            start, stop, step = key.indices(len(self))
            out = self._series._read(self._device, self._name, start, max(start, stop), self._counts)[::step]
            return out[(slice(None), *rest)] if rest else out
        i = int(key)
        i = i + len(self) if i < 0 else i
        if not 0 <= i < len(self):
            raise IndexError(f"row {key} of {len(self)}")
        row = self._series._read(self._device, self._name, i, i + 1, self._counts)[0]
        return row[rest] if rest else row


class RunSeries:
    """The parts of one rotated capture, read as one run (read-only). Use :func:`open_series`.

    Offers what :class:`~imustation.runfile.RunFile` offers to readers: ``path`` (the
    series name), ``attrs`` (the first part's, with ``ended_utc`` and ``stopped`` of the
    last and no per-part attributes), ``complete``, ``devices``, ``thermometers``,
    ``events()``, ``dataset()``, ``rows()``, ``read()``, ``iter_chunks()``,
    ``temperatures()``, ``refresh()``, ``close()``; ``parts`` the open parts in order.
    """

    def __init__(self, name: str, parts: Sequence[RunFile]):
        self.path = name
        self.parts = list(parts)
        self._check()
        self.attrs = {
            k: v for k, v in self.parts[0].attrs.items() if k not in _PART_ATTRS and k not in ("ended_utc", "stopped")
        }
        last = self.parts[-1].attrs
        for key in ("ended_utc", "stopped"):
            if key in last:
                self.attrs[key] = last[key]
        self._events: list[Event] | None = None

    @classmethod
    def open(cls, name: str, paths: Sequence[str], *, live: bool = False) -> RunSeries:
        opened: list[RunFile] = []
        try:
            for p in paths:
                if not os.path.exists(p):
                    raise RunFileError(f"{name}: part {os.path.basename(p)} is missing (no such file)")
                opened.append(open_run(p, live=live))
            return cls(name, opened)
        except BaseException:
            for run in opened:
                run.close()
            raise

    # -- checks ----------------------------------------------------------------------
    def _check(self) -> None:
        first = self.parts[0]
        rid = first.attrs.get("run_id")
        numbers = []
        for run in self.parts:
            where = os.path.basename(run.path)
            if run.attrs.get("part") is None or not run.attrs.get("run_id"):
                raise RunFileError(f"{self.path}: {where} is not a part of a rotated capture (no part and run_id)")
            if run.attrs["run_id"] != rid:
                raise RunFileError(
                    f"{self.path}: {where} belongs to capture {run.attrs['run_id']}, "
                    f"not {rid} like {os.path.basename(first.path)}"
                )
            numbers.append(int(run.attrs["part"]))
        if numbers != list(range(numbers[0], numbers[0] + len(numbers))):
            raise RunFileError(f"{self.path}: parts {', '.join(map(str, numbers))} are not consecutive")
        shape = _layout(first)
        for run in self.parts[1:]:
            if _layout(run) != shape:
                raise RunFileError(
                    f"{self.path}: {os.path.basename(run.path)} records other devices, channels or thermometers "
                    f"than {os.path.basename(first.path)}"
                )
        for prev, run in zip(self.parts[:-1], self.parts[1:], strict=True):
            for name, info in run.devices.items():
                before = prev.devices[name]
                if (
                    info.n
                    and before.n
                    and int(run.read(name, TIME, 0, 1)[0]) < int(prev.read(name, TIME, before.n - 1)[0])
                ):
                    raise RunFileError(
                        f"{self.path}: {os.path.basename(run.path)} starts ({name}) before "
                        f"{os.path.basename(prev.path)} ends"
                    )

    # -- what RunFile offers -----------------------------------------------------------
    @property
    def complete(self) -> bool:
        """The last part was closed cleanly (``ended_utc``)."""
        return self.parts[-1].complete

    @property
    def numbers(self) -> list[int]:
        """The part numbers, in order."""
        return [int(run.attrs["part"]) for run in self.parts]

    def _counts(self, device: str) -> list[int]:
        return [run.rows(device) for run in self.parts]

    @property
    def devices(self) -> dict[str, DeviceInfo]:
        """Every device with the rows of all parts (a torn last block is the last part's)."""
        per_part = [run.devices for run in self.parts]
        out = {}
        for name, last in per_part[-1].items():
            before = sum(p[name].n for p in per_part[:-1])
            channels = {c: replace(ch, n=before + ch.n) for c, ch in last.channels.items()}
            rows = {k: before + r for k, r in last.rows.items()}
            out[name] = replace(per_part[0][name], channels=channels, n=before + last.n, rows=rows)
        return out

    @property
    def thermometers(self) -> list[str]:
        return self.parts[0].thermometers

    def rows(self, device: str) -> int:
        return sum(self._counts(device))

    def dataset(self, device: str, name: str) -> _SeriesDataset:
        return _SeriesDataset(self, device, name)

    def read(self, device: str, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Raw rows ``start:stop`` of ``devices/<device>/<name>`` over all parts."""
        return self._read(device, name, start, stop, self._counts(device))

    def _read(self, device: str, name: str, start: int, stop: int | None, counts: Sequence[int]) -> np.ndarray:
        start, stop, _ = slice(start, stop).indices(sum(counts))
        pieces = []
        offset = 0
        for run, n in zip(self.parts, counts, strict=True):
            a, b = max(start, offset), min(stop, offset + n)
            if b > a:
                pieces.append(run.read(device, name, a - offset, b - offset))
            offset += n
        if not pieces:
            return self.parts[0].read(device, name, 0, 0)
        return pieces[0] if len(pieces) == 1 else np.concatenate(pieces)

    def iter_chunks(self, device: str, name: str, rows: int = 1 << 22, stop: int | None = None) -> Iterator[np.ndarray]:
        n = self.rows(device) if stop is None else min(stop, self.rows(device))
        for i in range(0, n, rows):
            yield self.read(device, name, i, min(i + rows, n))

    def thermometer_rate_hz(self, name: str) -> float | None:
        return self.parts[0].thermometer_rate_hz(name)

    def temperatures(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        got = [run.temperatures(name) for run in self.parts]
        return np.concatenate([t for t, _ in got]), np.concatenate([c for _, c in got])

    def events(self) -> list[Event]:
        """The events of every part, plus a ``gap`` for each unexplained jump at a hand-over, by time."""
        if self._events is None:
            events = [ev for run in self.parts for ev in run.events()]
            events += self._handover_gaps(events)
            self._events = sorted(events, key=lambda ev: ev.t_ns)
        return list(self._events)

    def _handover_gaps(self, events: list[Event]) -> list[Event]:
        added = []
        for name, info in self.parts[0].devices.items():
            period_ns = 1e9 / info.rate_hz if info.rate_hz > 0 else float("inf")
            counts = self._counts(name)
            t = self.dataset(name, TIME)
            logged = None
            offset = counts[0]
            for k in range(1, len(self.parts)):
                j = offset
                offset += counts[k]
                if counts[k] == 0 or j == 0:
                    continue
                t_last, t_first = int(t[j - 1]), int(t[j])
                if t_first - t_last <= 1.5 * period_ns:
                    continue
                if logged is None:
                    own = [ev for ev in events if ev.source == name and ev.kind in LOSS_KINDS]
                    logged = set(locate_breaks(t, own, info.rate_hz)) if own else set()
                if j in logged:
                    continue  # the station logged this loss itself
                prev, nxt = (os.path.basename(self.parts[i].path) for i in (k - 1, k))
                added.append(
                    Event(
                        t_first,
                        name,
                        "gap",
                        max(0, round((t_first - t_last) / period_ns) - 1),
                        f"no samples for {(t_first - t_last) * 1e-9:.3f} s between {prev} and {nxt} (series reader)",
                    )
                )
        return added

    def refresh(self) -> None:
        for run in self.parts:
            run.refresh()
        self._events = None

    def close(self) -> None:
        for run in self.parts:
            run.close()

    def __enter__(self) -> RunSeries:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _layout(run: RunFile) -> tuple:
    """What must be equal in every part: devices with their rates and channels, thermometers with their rates."""
    devices = tuple(
        (
            name,
            info.driver,
            info.rate_hz,
            tuple((c, str(ch.dtype), ch.scale, ch.offset, ch.axes) for c, ch in info.channels.items()),
        )
        for name, info in sorted(run.devices.items())
    )
    return devices, tuple((name, run.thermometer_rate_hz(name)) for name in sorted(run.thermometers))
