"""Holes in a run file's records, found from the file alone, against the losses its events state.

A device's consecutive samples are one output period apart (``rate_hz``); where
samples are missing the step between two written ones is a whole number of
periods longer, and the device's sample counter, where it has one, skips
(docs/runfile.md, "Samples lost"). :func:`find_holes` finds them in arrays;
:func:`check_device` / :func:`check_run` find them in a run file and match
them with the ``lost`` of the device's events, so that *samples written +
logged losses = samples produced* is checked without trusting the capture:
a hole no event states is reported, as is a loss the data do not show.
``imustation inspect`` prints what they find; ``imustation analyze`` splits
its records at every hole found.

Thermometers (:func:`check_thermometer`) are checked the same way against the
poll rate their group stores (``rate_hz``; a file without it is not checked:
its thermometers are reported as such, never against a guessed rate). A
reading has no counter, so its holes come from the times alone, and the
station's polls are less regular than a chip's clock: a reading is dated when
it is taken, and a poll comes late when its bus or the host is busy (a stall,
a slow transaction; a reconnect waits one conversion, 30-250 ms, before its
reading). Neither scheduler gives up a late poll: on the virtual clock the
overdue polls are made at once, one after the other; on the host clock the
next poll keeps its time, or, a period late or more, follows at once. A late
reading is therefore followed by steps of half a period or less, and the
readings the polls called for are counted over the late step and those short
steps together (``late_polls``): a 3.5 s stall of a 4 Hz thermometer makes a
step of 15 periods and 14 steps of 0, nothing missed; nine failed polls and a
reconnect dated one conversion late make a step of 11 periods and one of 0,
nine missed. A missed reading alone (a failed poll, made on time) is a step of
two periods. The threshold stays 1.5 periods: a group of k steps is a hole
when it spans more than k + 0.5 periods.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from imustation.errors import RunFileError
from imustation.runfile.reader import Event, RunFile
from imustation.runfile.schema import COUNTER, IMPORT_DRIVER, TIME

#: a step longer than this many output periods between two samples is a hole
HOLE_STEPS = 1.5
#: rows read at a time
_ROWS = 1 << 22


@dataclass(frozen=True)
class Holes:
    """Holes of one record: ``at`` the row of the first sample after each hole, ``lost`` the samples missing
    there, ``t_before`` / ``t_after`` the times (ns) of the samples around it; ``short`` counts steps of
    at most half a period (times not advancing as the rate says: a record to distrust)."""

    at: np.ndarray
    lost: np.ndarray
    t_before: np.ndarray
    t_after: np.ndarray
    short: int = 0

    @property
    def samples(self) -> int:
        """Samples missing in all the holes."""
        return int(self.lost.sum())

    def __len__(self) -> int:
        return len(self.at)


def find_holes(
    t_ns: np.ndarray,
    period_ns: float,
    counter: np.ndarray | None = None,
    modulus: int = 0,
    first_row: int = 0,
    late_polls: bool = False,
) -> Holes:
    """The holes of one record (vectorised).

    Parameters
    ----------
    t_ns : sample times, ns (int64, increasing).
    period_ns : the output period, ns (1e9 / the configured rate).
    counter : the device's sample counter (int), or None: the holes then come from the times alone.
    modulus : where the counter wraps (0: it does not).
    first_row : row number of ``t_ns[0]`` (for a record read in pieces).
    late_polls : the times are of host polls that may come late and are then
        followed by polls on time (a thermometer, see the module docstring): a
        step and the steps of half a period or less after it are one group of k
        readings, a hole of ``rint(span / period) - k`` when it spans more than
        k + 0.5 periods.

    With a counter, a hole is a step of the counter above 1 and loses the samples it
    skipped; a counter that goes back or repeats (the device restarted) is read by
    the times instead. Without, a step longer than ``HOLE_STEPS`` periods loses the
    periods it spans, less one - unless a step next to it is half a period or less:
    times repeated or out of order (an imported log: a swapped pair makes steps of
    2, -1 and 2 periods) say nothing of holes there.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    steps = np.diff(t)
    by_time = np.rint(steps / period_ns).astype(np.int64) - 1
    short = steps <= 0.5 * period_ns
    beside_short = np.zeros_like(short)
    beside_short[1:] |= short[:-1]
    beside_short[:-1] |= short[1:]
    lost = np.where((steps > HOLE_STEPS * period_ns) & ~beside_short, by_time, 0)
    if late_polls and len(steps):
        starts = np.flatnonzero(~short)
        if not len(starts) or starts[0] != 0:
            starts = np.r_[0, starts]
        span = np.add.reduceat(steps, starts)
        k = np.diff(np.r_[starts, len(steps)])
        lost = np.zeros(len(steps), dtype=np.int64)
        lost[starts] = np.where(
            span > (k - 1 + HOLE_STEPS) * period_ns, np.rint(span / period_ns).astype(np.int64) - k, 0
        )
    if counter is not None:
        c = np.diff(np.asarray(counter, dtype=np.int64))
        if modulus:
            c %= modulus
        lost = np.where(c >= 1, c - 1, np.maximum(lost, 0))
    where = np.flatnonzero(lost > 0)
    return Holes(
        at=where + 1 + first_row,
        lost=lost[where],
        t_before=t[where],
        t_after=t[where + 1],
        short=int(np.count_nonzero(short)),
    )


def holes_in_run(run: RunFile, device: str, rows: int = _ROWS) -> Holes:
    """The holes of ``device``'s record in ``run``, read ``rows`` at a time (memory stays bounded)."""
    info = run.devices[device]
    period = 1e9 / info.rate_hz
    modulus = int(info.settings.get("counter_modulus", 0) or 0)
    n = info.n
    t_ds = run.dataset(device, TIME)
    c_ds = run.dataset(device, COUNTER) if info.has_counter else None
    # an import keeps its source's stamps in file order (and notes those that step back); a capture's increase
    monotonic = info.driver != IMPORT_DRIVER
    fields: dict[str, list[np.ndarray]] = {f: [] for f in ("at", "lost", "t_before", "t_after")}
    short = 0
    for i in range(0, max(n - 1, 0), rows):
        # steps i .. i+rows-1 are this piece's; one more step either side tells whether they are regular
        lo, hi = max(0, i - 1), min(n, i + rows + 2)
        piece = find_holes(t_ds[lo:hi], period, c_ds[lo:hi] if c_ds is not None else None, modulus, lo)
        mine = (piece.at > i) & (piece.at <= i + rows)
        for f, values in fields.items():
            values.append(getattr(piece, f)[mine])
        steps = np.diff(np.asarray(t_ds[i : min(n, i + rows + 1)], dtype=np.int64))
        if monotonic and (steps < 0).any():
            j = i + 1 + int(np.argmax(steps < 0))
            raise RunFileError(f"{run.path}: devices/{device}/t steps back at row {j}; a capture's times only increase")
        short += int(np.count_nonzero(steps <= 0.5 * period))
    if not fields["at"]:
        empty = np.zeros(0, dtype=np.int64)
        return Holes(empty, empty, empty, empty)
    return Holes(*(np.concatenate(fields[f]) for f in ("at", "lost", "t_before", "t_after")), short=short)


@dataclass(frozen=True)
class UnloggedHole:
    """A hole whose loss the events do not state (or state as another count)."""

    row: int
    t_ns: int
    lost: int
    logged: int


@dataclass(frozen=True)
class HoleCheck:
    """One device (or thermometer) of a run file: its holes against its logged losses.

    ``logged``: samples its events say were lost; ``edge``: of those, the ones
    logged before its first or after its last sample (the data cannot show
    them); ``unlocated``: logged inside the record where no hole is;
    ``unlogged``: holes the events do not state exactly.
    """

    device: str
    samples: int
    holes: Holes
    logged: int
    edge: int
    unlocated: int
    unlogged: tuple[UnloggedHole, ...]

    @property
    def produced(self) -> int:
        """Samples the device produced over the record, as the file shows them: written, in its holes, and
        logged before its first or after its last sample."""
        return self.samples + self.holes.samples + self.edge

    @property
    def consistent(self) -> bool:
        """Every hole logged, every logged loss in a hole: written + logged = produced."""
        return not self.unlogged and not self.unlocated and self.samples + self.logged == self.produced


def match_losses(holes: Holes, events: Iterable[Event], t_first: int | None, t_last: int | None) -> tuple:
    """Match a device's loss events with its holes: (logged, edge, unlocated, unlogged holes).

    An event is dated at the first sample it says is missing, so it lies between the
    two samples around its hole; files of earlier versions dated it at the read
    that found the loss, after its hole: such an event counts for the last hole
    before it.
    """
    logged = edge = unlocated = 0
    per_hole = np.zeros(len(holes), dtype=np.int64)
    for ev in events:
        if ev.lost <= 0:
            continue
        logged += ev.lost
        if t_first is None or ev.t_ns < t_first or ev.t_ns > t_last:
            edge += ev.lost
            continue
        inside = int(np.searchsorted(holes.t_after, ev.t_ns, side="right"))  # holes ending at or before it
        if inside < len(holes) and holes.t_before[inside] < ev.t_ns:
            per_hole[inside] += ev.lost  # between the samples around a hole
        elif inside > 0:
            per_hole[inside - 1] += ev.lost
        else:
            unlocated += ev.lost
    unlogged = tuple(
        UnloggedHole(int(holes.at[i]), int(holes.t_after[i]), int(holes.lost[i]), int(per_hole[i]))
        for i in np.flatnonzero(per_hole != holes.lost)
    )
    return logged, edge, unlocated, unlogged


def check_device(run: RunFile, device: str, events: list[Event] | None = None) -> HoleCheck:
    """The holes of ``device`` in ``run`` against the losses its events state."""
    info = run.devices[device]
    holes = holes_in_run(run, device)
    t_first = t_last = None
    if info.n:
        t_ds = run.dataset(device, TIME)
        t_first, t_last = int(t_ds[0]), int(t_ds[info.n - 1])
    mine = [e for e in (run.events() if events is None else events) if e.source == device]
    logged, edge, unlocated, unlogged = match_losses(holes, mine, t_first, t_last)
    return HoleCheck(device, info.n, holes, logged, edge, unlocated, unlogged)


def check_thermometer(run: RunFile, name: str, events: list[Event] | None = None) -> HoleCheck | None:
    """The holes of thermometer ``name`` (readings against its stored poll rate) against the readings its
    events say were missed; None when the file stores no poll rate (not checked). See the module docstring."""
    rate = run.thermometer_rate_hz(name)
    if rate is None:
        return None
    t, _ = run.temperatures(name)
    holes = find_holes(t, 1e9 / rate, late_polls=True)
    t_first, t_last = (int(t[0]), int(t[-1])) if len(t) else (None, None)
    mine = [e for e in (run.events() if events is None else events) if e.source == name]
    logged, edge, unlocated, unlogged = match_losses(holes, mine, t_first, t_last)
    return HoleCheck(name, len(t), holes, logged, edge, unlocated, unlogged)


def check_thermometers(run: RunFile, events: list[Event] | None = None) -> dict[str, HoleCheck | None]:
    """:func:`check_thermometer` for every thermometer of ``run``."""
    events = run.events() if events is None else events
    return {name: check_thermometer(run, name, events) for name in run.thermometers}


def check_run(run: RunFile) -> dict[str, HoleCheck]:
    """:func:`check_device` for every device of ``run``."""
    events = run.events()
    return {name: check_device(run, name, events) for name in run.devices}
