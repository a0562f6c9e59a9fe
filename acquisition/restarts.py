"""A reader process lost mid-run, the main process's side: when it is started again, and what its
devices lost meanwhile (docs/capture.md, "A reader process that dies").

* the back-off (:func:`restart_delay`; the state: :class:`Restarts`): 1 s, doubled for each
  restart of that reader in the last hour, at most 60 s; at most 10 restarts an hour (the
  eleventh waits until the first is an hour old); ``RESTARTS_PER_HOUR = 0``: a dead reader is
  not started again;
* its devices' counts (:func:`failed_counts`, :func:`carried`): failed with one fault more while it
  is gone, going on from those it reached once a successor runs;
* the events: a ``fault`` per device when it is lost (:func:`fault_detail`), a ``reconnect`` when a
  successor has re-opened them (:func:`reconnect_detail`), and one ``gap`` per device for the outage
  (:class:`OutageLog`, counted as the run file's hole finder counts it: :func:`outage_loss`,
  :func:`file_period_ns`), or to the end of the capture (:func:`lost_to_end`).

The processes themselves (spawning, killing, pipes) are :class:`~imustation.acquisition.workers.Worker`'s.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from imustation.acquisition.sinks import APPEND, EVENT, TEMPERATURE, Sink
from imustation.runfile.checks import RATE_PROBE_ROWS
from imustation.runfile.holes import find_holes
from imustation.runfile.rate import capture_rate
from imustation.status import DeviceStatus, ThermometerStatus

#: a dead reader process is started again after this back-off, s, doubled for each restart of it in
#: the last hour, up to RESTART_MAX_S; at most RESTARTS_PER_HOUR restarts an hour (0: none)
RESTART_FIRST_S = 1.0
RESTART_MAX_S = 60.0
RESTARTS_PER_HOUR = 10
HOUR_S = 3600.0


class Restarts:
    """When a lost reader process is started again: its back-off, and its successor opening its devices.

    Times are monotonic seconds. :meth:`lost` (the reader is gone, or its successor failed to open)
    backs off by :func:`restart_delay`; :meth:`due` says when to start a successor, which
    :meth:`started` records; :meth:`reopened` ends the attempt (returning how many it took);
    :meth:`opening_too_long` says a successor has had ``OPEN_TIMEOUT_S`` to open and has not.
    """

    def __init__(self, open_timeout_s: float):
        self.open_timeout_s = open_timeout_s
        #: when the next successor is started (None: not waiting)
        self.restart_at: float | None = None
        #: a successor is opening its devices (since ``_opening_since``)
        self.reopening = False
        self._opening_since = 0.0
        #: when it was started again (pruned to the last hour by restart_delay)
        self.times: list[float] = []
        self.attempts = 0

    @property
    def pending(self) -> bool:
        """Waiting to start a successor, or a successor opening its devices."""
        return self.restart_at is not None or self.reopening

    def lost(self, now: float) -> float | None:
        """The reader (or the successor opening) is gone at ``now``: the back-off before the next attempt,
        s, or None when it is not started again."""
        self.reopening = False
        delay = restart_delay(self.times, now)
        self.restart_at = None if delay is None else now + delay
        return delay

    def due(self, now: float) -> bool:
        """Time to start a successor."""
        return self.restart_at is not None and now >= self.restart_at

    def started(self, now: float) -> None:
        """A successor was spawned at ``now``; it opens its devices."""
        self.restart_at = None
        self.times.append(now)
        self.attempts += 1
        self.reopening, self._opening_since = True, now

    def opening_too_long(self, now: float) -> bool:
        return now - self._opening_since > self.open_timeout_s

    def reopened(self) -> int:
        """The successor opened its devices and records: the attempts it took (counted from 0 again)."""
        self.reopening = False
        attempts, self.attempts = self.attempts, 0
        return attempts

    def cancel(self) -> None:
        """No more attempts (the run is over, or stopped)."""
        self.restart_at, self.reopening = None, False


def fault_detail(what: str, why: str, delay: float | None) -> str:
    """The ``fault`` event of each device of a reader process lost mid-run."""
    then = "not read for the rest of the capture" if delay is None else f"starting it again in {delay:.0f} s"
    return f"{what} ended during the run ({why}); {then}"


def reconnect_detail(what: str, attempts: int) -> str:
    """The ``reconnect`` event of each device once a successor has re-opened them."""
    return f"{what} started again after {attempts} attempt(s); re-opened with the same settings"


def failed_counts(counts: tuple, rates: dict[str, float], names: list[str]) -> tuple:
    """A lost reader's last counts (devices, thermometers), each failed with one fault more; ``rates``:
    its devices' output rates, Hz (the others of ``names`` are thermometers)."""
    devices, thermometers = counts
    return (
        {n: _failed(devices.get(n) or DeviceStatus(rate_cfg_hz=r)) for n, r in rates.items()},
        {n: _failed(thermometers.get(n) or ThermometerStatus()) for n in names if n not in rates},
    )


def _failed(counts: Any) -> Any:
    return dataclasses.replace(counts, state="failed", faults=counts.faults + 1)


def restart_delay(restarts: list[float], now: float) -> float | None:
    """Seconds from ``now`` (monotonic s) until a dead reader process is started again; None: never
    (``RESTARTS_PER_HOUR`` 0). ``restarts``: when it was started again before (monotonic s; pruned in
    place to the last hour). A reader that dies at once backs off 1, 2, 4 ... 60 s and, once it has been
    started ``RESTARTS_PER_HOUR`` times within an hour, waits for the oldest of those to be an hour old."""
    if RESTARTS_PER_HOUR <= 0:
        return None
    restarts[:] = [t for t in restarts if now - t < HOUR_S]
    delay = min(RESTART_MAX_S, RESTART_FIRST_S * 2.0 ** len(restarts))
    if len(restarts) >= RESTARTS_PER_HOUR:
        delay = max(delay, restarts[-RESTARTS_PER_HOUR] + HOUR_S - now)
    return delay


def carried(base: tuple, counts: tuple) -> tuple:
    """A restarted reader's counts (devices, thermometers) on top of ``base``, what its predecessors
    reached: samples, readings, losses and faults go on counting; the state is the new reader's."""
    base_dev, base_th = base
    devices, thermometers = counts
    out_dev = dict(base_dev)
    for n, c in devices.items():
        b = base_dev.get(n)
        out_dev[n] = c if b is None else dataclasses.replace(
            c, samples=b.samples + c.samples, gaps=b.gaps + c.gaps, lost=b.lost + c.lost, faults=b.faults + c.faults
        )  # fmt: skip
    out_th = dict(base_th)
    for n, c in thermometers.items():
        b = base_th.get(n)
        out_th[n] = c if b is None else dataclasses.replace(
            c, readings=b.readings + c.readings, lost=b.lost + c.lost, faults=b.faults + c.faults
        )  # fmt: skip
    return out_dev, out_th


def outage_loss(
    last: tuple[int, int | None] | None, first: tuple[int, int | None], period_ns: float, modulus: int, reading: bool
) -> int:
    """Samples (or thermometer readings, ``reading``) missing between the last one a dead reader handed
    over and the first of the reader started after it, as the run file's hole finder counts them
    (:func:`~imustation.runfile.holes.find_holes`): ``last`` / ``first`` are (time ns, device counter or
    None); no ``last``: the reader died before its first sample, all from the run's start are missing.
    ``period_ns``: the output (or poll) period, ns; ``modulus``: where the counter wraps (0: never)."""
    if last is None:
        return max(0, int(first[0] // period_ns))
    t = np.array([last[0], first[0]], dtype=np.int64)
    counter = None if reading or last[1] is None or first[1] is None else np.array([last[1], first[1]])
    return find_holes(t, period_ns, counter, modulus, late_polls=reading).samples


#: the first sample times of a device a file reader checks its rate against (then uses for its holes)
PROBE_ROWS = RATE_PROBE_ROWS + 1


def file_period_ns(first_stamps: np.ndarray, rate_hz: float) -> float:
    """The output period the run file's reader will count a device's holes with, ns: ``1e9 / rate_hz``
    (Hz), or the rate its first ``PROBE_ROWS`` sample times show where they contradict it by the reader's
    rule (:func:`~imustation.runfile.rate.capture_rate`: a chip whose clock is 0.5 % fast makes 0.5 % more
    samples in an outage than its nominal rate says; a start-up transient is not a rate, docs/runfile.md)."""
    return 1e9 / capture_rate(first_stamps[:PROBE_ROWS], rate_hz)


def lost_to_end(sink: Sink, what: str, rates: dict[str, float], last_t: dict[str, int], end_ns: int) -> dict[str, int]:
    """Log for each device of a lost reader one ``gap`` after its last sample (``last_t``, station ns) with
    the samples its rate (Hz) fits from there to ``end_ns``; return them by device (written + logged
    losses = produced, as for every other loss)."""
    out = {}
    for name, rate in rates.items():
        period = 1e9 / rate
        last = last_t.get(name, -period)
        lost = int((end_ns - last) // period)
        if lost > 0:
            sink.event(int(last + period), name, "gap", f"{what} lost: not read to the end", lost=lost)
            out[name] = lost
    return out


class OutageLog:
    """What a reader process's devices handed over last, and the ``gap`` of each outage.

    :meth:`seen` follows every item the reader sends; after :meth:`restarted`, each
    device's (or thermometer's) first sample closes its outage: one ``gap`` of what it
    made meanwhile, less what the new reader logged before it, as the run file's hole
    finder counts it. For a device, the file's reader fits the rate over its first
    ``PROBE_ROWS`` samples (those after the outage too), so its gap waits for them (or
    the end: :meth:`flush`). ``on_gap(name, lost)`` adds each gap to the counts.
    """

    def __init__(self, what: str, on_gap: Callable[[str, int], None]):
        self.what = what
        self._on_gap = on_gap
        #: station time of each device's last sample handed over, ns; its counter there; each thermometer's
        #: last reading, ns; output rates, Hz; periods, ns; counter moduli
        self.last_t: dict[str, int] = {}
        self.last_c: dict[str, int | None] = {}
        self.last_reading: dict[str, int] = {}
        self.rates: dict[str, float] = {}
        self.periods: dict[str, float] = {}
        self.moduli: dict[str, int] = {}
        #: after a restart: the devices and thermometers whose first sample closes the outage, with the
        #: losses the new reader logged before it
        self._resync: dict[str, int] = {}
        #: each device's first sample times (what the file's reader checks its rate against)
        self._probe: dict[str, list[np.ndarray]] = {}
        #: outages closed by a first sample whose gap waits for the probe (last, first, logged, reading)
        self._deferred: dict[str, tuple] = {}

    def opened(self, devices: list, thermometers: dict[str, tuple[str, int]]) -> None:
        """The reader's opened devices and thermometers (identity, period ns): their rates and periods."""
        self.rates = {od.name: od.info.rate_hz for od in devices}
        self.periods = {od.name: 1e9 / od.info.rate_hz for od in devices}
        self.periods.update({name: float(period) for name, (_, period) in thermometers.items()})
        self.moduli = {od.name: int(od.info.settings.get("counter_modulus", 0) or 0) for od in devices}

    def restarted(self, names: list[str]) -> None:
        """A successor reader records from now: each of ``names``' next sample closes its outage."""
        self._resync = dict.fromkeys(names, 0)

    def lost(self, sink: Sink) -> None:
        """The reader is gone: the gaps waiting for their probe are logged now, the outages not yet
        closed are this one's."""
        for name in list(self._deferred):
            self.log(sink, name)
        self._resync = {}

    def seen(self, sink: Sink, item: tuple) -> None:
        """An item the reader sent (moved onto the run's origin), before it is delivered."""
        if self._resync:
            self._close(sink, item)
        if item[0] == APPEND and len(item[2]):
            self.last_t[item[1]] = int(item[2][-1])
            self.last_c[item[1]] = None if item[4] is None else int(item[4][-1])
            probe = self._probe.setdefault(item[1], [])
            if sum(map(len, probe)) < PROBE_ROWS:
                probe.append(item[2][:PROBE_ROWS])
                if item[1] in self._deferred and sum(map(len, probe)) >= PROBE_ROWS:
                    self.log(sink, item[1])
        elif item[0] == TEMPERATURE and len(item[2]):
            self.last_reading[item[1]] = int(item[2][-1])

    def _close(self, sink: Sink, item: tuple) -> None:
        """After a restart: the losses the new reader logs before a device's first sample are part of the
        outage; that first sample closes it with one ``gap`` of the rest, as the hole finder counts it."""
        name = item[2] if item[0] == EVENT else item[1]
        if name not in self._resync:
            return
        if item[0] == EVENT:
            self._resync[name] += max(0, int(item[5]))
            return
        if item[0] not in (APPEND, TEMPERATURE) or not len(item[2]):
            return
        logged = self._resync.pop(name)
        reading = item[0] == TEMPERATURE
        first = (int(item[2][0]), None if reading or item[4] is None else int(item[4][0]))
        prev = self.last_reading.get(name) if reading else self.last_t.get(name)
        last = None if prev is None else (prev, None if reading else self.last_c.get(name))
        self._deferred[name] = (last, first, logged, reading)
        if reading or sum(map(len, self._probe.get(name, ()))) >= PROBE_ROWS:
            self.log(sink, name)
        # else: the file's reader fits the device's rate over its first PROBE_ROWS samples, those
        # after the outage too: the gap is logged once they have come (or at the end)

    def log(self, sink: Sink, name: str) -> None:
        """Log the outage gap of ``name`` that waits (see :meth:`_close`)."""
        last, first, logged, reading = self._deferred.pop(name)
        period = self.periods[name]
        if not reading and self._probe.get(name):
            period = file_period_ns(np.concatenate(self._probe[name]), self.rates[name])
        lost = outage_loss(last, first, period, self.moduli.get(name, 0), reading) - logged
        if lost <= 0:
            return
        prev = None if last is None else last[0]
        at = int(prev + period) if prev is not None else 0
        sink.event(at, name, "gap", f"{self.what} was not running: samples not read", lost=lost)
        self._on_gap(name, lost)

    @property
    def pending(self) -> dict[str, int]:
        """After a restart: the devices and thermometers without a sample yet (with what the new reader
        logged lost before it)."""
        return self._resync

    def flush(self, sink: Sink) -> bool:
        """At the end: log the outage gaps still waiting for their devices' first ``PROBE_ROWS`` samples;
        True if any was."""
        if not self._deferred:
            return False
        for name in list(self._deferred):
            self.log(sink, name)
        return True
