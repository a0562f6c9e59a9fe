"""Fault injection for simulated buses and chips, on the station clock.

A :class:`FaultPlan` holds fault specs from a ``[device.sim]`` table::

    faults = [
      {kind = "nack", every_s = 600},                      # Poisson, mean interval 600 s
      {kind = "disconnect", at_s = 3600, duration_s = 5},  # cable pulled at 1 h for 5 s
      {kind = "reset", at_s = 7200},                       # chip power-on reset at 2 h
      {kind = "slow", at_s = 600, duration_s = 5, delay_s = 0.004},  # 5 s of 4 ms transactions
    ]

A burst of NACKs is several ``nack`` entries at one ``at_s``: that many consecutive
transactions are not acknowledged (the bus retries absorb a short burst).

Buses and chip simulators ask ``plan.fire(kind)`` (an event of that kind has become
due since the last ask: consume it) or ``plan.active(kind)`` (inside an event's
duration). What a kind does is up to the bus or chip (see ``FAULT_KINDS``). Every
injected event is appended to ``plan.sim_log`` so tests can match it with the
run file's event log.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from imustation.clock import Clock
from imustation.errors import SettingError

#: kind -> what the simulated bus or chip does when it fires
FAULT_KINDS = {
    "nack": "one transaction is not acknowledged (I2C NACK / no answer); a retry succeeds",
    "short_read": "one read returns fewer bytes than asked (bus reports EIO)",
    "corrupt": "one byte of one read has a bit flipped (checksummed protocols detect it)",
    "checksum": "one frame/burst carries a wrong checksum or CRC",
    "stuck_fifo": "the FIFO stops filling for duration_s (data-ready never comes)",
    "reset": "the chip performs a power-on reset (settings lost, must be re-initialised)",
    "disconnect": "the device is gone for duration_s (every transaction fails), then returns",
    "stall": "one transaction hangs for duration_s (clock stretching, a stalled bridge or host); FIFOs fill meanwhile",
    "slow": "for duration_s every transaction takes delay_s longer (a slow or congested bus, a busy host)",
}
_SPEC_KEYS = ("kind", "at_s", "every_s", "duration_s", "delay_s")
#: the extra time of each transaction of a ``slow`` window when ``delay_s`` is not given, s
DEFAULT_SLOW_DELAY_S = 0.002
#: shortest mean interval between faults, s: a plan draws every fault of the capture, and
#: every_s = 1e-300 never finished drawing them
MIN_EVERY_S = 0.01


@dataclass(frozen=True)
class FaultSpec:
    """One fault: at a fixed time ``at_s`` and/or as a Poisson process of mean interval ``every_s``."""

    kind: str
    at_s: float | None = None
    every_s: float | None = None
    duration_s: float = 0.0
    #: ``slow`` only: extra time of each transaction in the window, s
    delay_s: float = 0.0


def parse_faults(entries: Sequence[Mapping[str, object]], where: str = "sim.faults") -> tuple[FaultSpec, ...]:
    """Validate a ``faults = [...]`` list from a config; one-line errors name the entry."""
    if not isinstance(entries, (list, tuple)):
        raise SettingError(f'{where}: expected a list of tables like {{kind = "nack", every_s = 600}}')
    specs = []
    for i, entry in enumerate(entries):
        w = f"{where}[{i}]"
        if not isinstance(entry, Mapping):
            raise SettingError(f"{w}: expected a table")
        for key in entry:
            if key not in _SPEC_KEYS:
                raise SettingError(f"{w}.{key}: unknown key (allowed: {', '.join(_SPEC_KEYS)})")
        kind = entry.get("kind")
        if kind not in FAULT_KINDS:
            raise SettingError(f"{w}.kind = {kind!r}: allowed {', '.join(FAULT_KINDS)}")
        nums = {}
        for key in ("at_s", "every_s", "duration_s", "delay_s"):
            value = entry.get(key)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < math.inf:
                raise SettingError(f"{w}.{key} = {value!r}: a finite, non-negative number of seconds")
            nums[key] = float(value)
        if "at_s" not in nums and "every_s" not in nums:
            raise SettingError(f"{w}: give at_s (one event) or every_s (mean interval), or both")
        if nums.get("every_s", MIN_EVERY_S) < MIN_EVERY_S:
            raise SettingError(f"{w}.every_s = {nums['every_s']:g}: at least {MIN_EVERY_S:g} s between faults")
        if "delay_s" in nums and kind != "slow":
            raise SettingError(f"{w}.delay_s: only a 'slow' fault has a per-transaction delay")
        if kind == "slow" and not nums.get("duration_s"):
            raise SettingError(f"{w}: a 'slow' fault needs duration_s (the length of the slow window)")
        delay = nums.get("delay_s", DEFAULT_SLOW_DELAY_S) if kind == "slow" else 0.0
        specs.append(FaultSpec(kind, nums.get("at_s"), nums.get("every_s"), nums.get("duration_s", 0.0), delay))
    return tuple(specs)


class FaultPlan:
    """Scheduled fault events for one simulated device.

    Parameters
    ----------
    specs : the faults (see :func:`parse_faults`).
    clock : the station clock; times are seconds since ``clock.now_ns()`` at creation.
    seed : seed of the Poisson processes.
    """

    def __init__(self, specs: Sequence[FaultSpec], clock: Clock, seed: int = 0):
        self.specs = tuple(specs)
        #: kinds this plan can fire: a bus or chip asks for every kind it models on each
        #: transaction, and most plans hold one or two (answer the rest without work)
        self.kinds = frozenset(spec.kind for spec in self.specs)
        self.clock = clock
        self.t0_ns = clock.now_ns()
        self._rng = np.random.default_rng([seed, 0xFA17])
        # per spec: next pending event time (s) or None; plus active windows per kind
        self._next: list[float | None] = []
        for spec in self.specs:
            first = spec.at_s
            if first is None and spec.every_s is not None:
                first = float(self._rng.exponential(spec.every_s))
            self._next.append(first)
        # earliest pending event, ns on the clock: buses ask several times per
        # transaction, and almost always nothing is due (see _collect)
        self._due_ns = self._earliest_ns()
        self._windows: dict[str, list[tuple[float, float, float]]] = {}
        self._pending: dict[str, list[float]] = {}
        self.sim_log: list[tuple[int, str]] = []

    def _now_s(self) -> float:
        return (self.clock.now_ns() - self.t0_ns) / 1e9

    def _earliest_ns(self) -> float:
        pending = [t for t in self._next if t is not None]
        return self.t0_ns + min(pending) * 1e9 if pending else float("inf")

    def _collect(self) -> dict[str, int]:
        """Move every event due by now into the log; return counts per kind."""
        if self.clock.now_ns() < self._due_ns:
            return {}
        now = self._now_s()
        fired: dict[str, int] = {}
        for i, spec in enumerate(self.specs):
            t = self._next[i]
            while t is not None and t <= now:
                fired[spec.kind] = fired.get(spec.kind, 0) + 1
                self._pending.setdefault(spec.kind, []).append(spec.duration_s)
                self.sim_log.append((self.t0_ns + int(t * 1e9), spec.kind))
                if spec.duration_s > 0:
                    self._windows.setdefault(spec.kind, []).append((t, t + spec.duration_s, spec.delay_s))
                if spec.every_s is not None:
                    t = t + float(self._rng.exponential(spec.every_s))
                else:
                    t = None
            self._next[i] = t
        self._due_ns = self._earliest_ns()
        return fired

    def fire(self, kind: str) -> bool:
        """True once per event of ``kind`` that has become due (the event is consumed)."""
        return self.fire_duration(kind) is not None

    def fire_duration(self, kind: str) -> float | None:
        """Like :meth:`fire`, but give the consumed event's ``duration_s`` (None: no event due)."""
        if kind not in self.kinds:
            return None
        self._collect()
        pending = self._pending.get(kind)
        return pending.pop(0) if pending else None

    def active(self, kind: str) -> bool:
        """True while the clock is inside a window of an event of ``kind`` (``duration_s``)."""
        return bool(self._open_windows(kind))

    def delay_s(self, kind: str = "slow") -> float:
        """The extra time a transaction takes now: the largest ``delay_s`` of the open windows of ``kind``."""
        return max((delay for _, _, delay in self._open_windows(kind)), default=0.0)

    def _open_windows(self, kind: str) -> list[tuple[float, float, float]]:
        if kind not in self.kinds:
            return []
        self._collect()
        if not self._windows.get(kind):
            return []
        now = self._now_s()
        windows = [w for w in self._windows[kind] if w[1] > now]
        self._windows[kind] = windows
        return [w for w in windows if w[0] <= now]
