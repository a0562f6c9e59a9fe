"""The host clock's synchronisation state, and steps of the wall clock during a capture.

Sample times are ns on the host's monotonic clock since the run's start
(docs/runfile.md); only ``started_utc`` comes from the wall clock. Whether that
wall clock was synchronised, and how far off the kernel thinks it may be, is
read once at the start with ``adjtimex(2)`` (read-only, ``modes = 0``) through
ctypes - no ``timedatectl``, no daemon to ask - and stored as root attributes
(:meth:`SyncState.attrs`). During the capture :class:`StepWatch` compares
``CLOCK_REALTIME - CLOCK_MONOTONIC`` between checks: NTP slews the wall clock
by at most 500 ppm, so a change larger than :data:`STEP_THRESHOLD_S` between two
checks a second apart is a step (NTP/chrony stepping a large offset, a manual
``date -s``), logged as a ``note`` event. The sample times do not move: they are
monotonic.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

#: adjtimex status bit: the clock is not synchronised (``include/uapi/linux/timex.h``)
STA_UNSYNC = 0x0040
#: adjtimex return value: clock not synchronised (``TIME_ERROR``)
TIME_ERROR = 5
#: a change of REALTIME - MONOTONIC between two checks larger than this is a step, s
STEP_THRESHOLD_S = 0.05
#: station time between two checks of the wall clock, ns
CHECK_INTERVAL_NS = 1_000_000_000


class _Timeval(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_usec", ctypes.c_long)]


class _Timex(ctypes.Structure):
    """``struct timex`` of ``<sys/timex.h>`` (glibc / musl), with its trailing padding."""

    _fields_ = [
        ("modes", ctypes.c_uint),
        ("offset", ctypes.c_long),
        ("freq", ctypes.c_long),
        ("maxerror", ctypes.c_long),
        ("esterror", ctypes.c_long),
        ("status", ctypes.c_int),
        ("constant", ctypes.c_long),
        ("precision", ctypes.c_long),
        ("tolerance", ctypes.c_long),
        ("time", _Timeval),
        ("tick", ctypes.c_long),
        ("ppsfreq", ctypes.c_long),
        ("jitter", ctypes.c_long),
        ("shift", ctypes.c_int),
        ("stabil", ctypes.c_long),
        ("jitcnt", ctypes.c_long),
        ("calcnt", ctypes.c_long),
        ("errcnt", ctypes.c_long),
        ("stbcnt", ctypes.c_long),
        ("tai", ctypes.c_int),
        ("_padding", ctypes.c_int * 11),
    ]


@dataclass(frozen=True)
class KernelTime:
    """What ``adjtimex`` reports: return value (clock state), ``status`` bits, errors in µs."""

    state: int
    status: int
    esterror_us: int
    maxerror_us: int


def kernel_adjtimex() -> KernelTime | None:
    """Read the kernel's time state (``adjtimex`` with ``modes = 0``); None where there is no such call."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name, use_errno=True)
        call = libc.adjtimex
    except (OSError, AttributeError, TypeError):
        return None
    tx = _Timex()
    state = call(ctypes.byref(tx))
    if state < 0:
        return None
    return KernelTime(int(state), int(tx.status), int(tx.esterror), int(tx.maxerror))


@dataclass(frozen=True)
class SyncState:
    """The host clock at the start of a capture.

    ``synchronised``: True, False, or None when unknown; ``est_error_s`` and
    ``max_error_s``: the kernel's estimated and maximum error of the wall clock
    (s; None when unknown or when the clock is not synchronised, where the
    kernel's figures mean nothing).
    """

    synchronised: bool | None
    est_error_s: float | None = None
    max_error_s: float | None = None
    source: str = "adjtimex"

    @property
    def word(self) -> str:
        return {True: "synchronised", False: "unsynchronised", None: "unknown"}[self.synchronised]

    def describe(self) -> str:
        """One line: ``synchronised (estimated error 1.2 ms, at most 15.0 ms)``, or why not."""
        if self.synchronised is None:
            return "synchronisation unknown (no adjtimex on this system)"
        if not self.synchronised:
            return "NOT synchronised (no NTP/PTP/chrony lock): started_utc may be off; sample times are monotonic"
        extra = []
        if self.est_error_s is not None:
            extra.append(f"estimated error {self.est_error_s * 1e3:.1f} ms")
        if self.max_error_s is not None:
            extra.append(f"at most {self.max_error_s * 1e3:.1f} ms")
        return "synchronised" + (f" ({', '.join(extra)})" if extra else "")

    def attrs(self) -> dict[str, Any]:
        """The run file's root attributes (docs/runfile.md, "Host clock"): errors only where known."""
        out: dict[str, Any] = {"clock_sync": self.word, "clock_source": self.source}
        if self.est_error_s is not None:
            out["clock_est_error_s"] = float(self.est_error_s)
        if self.max_error_s is not None:
            out["clock_max_error_s"] = float(self.max_error_s)
        return out

    def status(self) -> dict[str, Any]:
        """The status document's ``clock`` entry (docs/capture.md)."""
        return {"sync": self.word, "est_error_s": self.est_error_s, "max_error_s": self.max_error_s}


def read_sync(adjtimex: Callable[[], KernelTime | None] = kernel_adjtimex) -> SyncState:
    """The host clock's synchronisation state (``adjtimex`` injectable for tests)."""
    kt = adjtimex()
    if kt is None:
        return SyncState(None, source="unavailable")
    if kt.status & STA_UNSYNC or kt.state == TIME_ERROR:
        return SyncState(False)
    return SyncState(True, kt.esterror_us * 1e-6, kt.maxerror_us * 1e-6)


@dataclass
class HostClocks:
    """The two host clocks :class:`StepWatch` compares (injectable: tests step a fake wall clock)."""

    realtime_ns: Callable[[], int] = time.time_ns
    monotonic_ns: Callable[[], int] = time.monotonic_ns

    def offset_ns(self) -> int:
        """``CLOCK_REALTIME - CLOCK_MONOTONIC``, ns: constant while nobody sets the wall clock."""
        return self.realtime_ns() - self.monotonic_ns()


class StepWatch:
    """Finds steps of the wall clock: call :meth:`check` with the station time between polls.

    Checks at most every :data:`CHECK_INTERVAL_NS` of station time; returns the
    note to log when ``REALTIME - MONOTONIC`` moved by more than ``threshold_s``
    since the last check.
    """

    def __init__(self, clocks: HostClocks | None = None, threshold_s: float = STEP_THRESHOLD_S):
        self.clocks = clocks or HostClocks()
        self.threshold_ns = int(threshold_s * 1e9)
        self._offset = self.clocks.offset_ns()
        self._next_ns = 0
        #: steps seen so far
        self.steps = 0

    def check(self, t_ns: int) -> str | None:
        if t_ns < self._next_ns:
            return None
        self._next_ns = t_ns + CHECK_INTERVAL_NS
        offset = self.clocks.offset_ns()
        step = offset - self._offset
        self._offset = offset
        if abs(step) <= self.threshold_ns:
            return None
        self.steps += 1
        return (
            f"host wall clock stepped by {step * 1e-9:+.3f} s (CLOCK_REALTIME - CLOCK_MONOTONIC changed); "
            "sample times are monotonic and unaffected"
        )


class ClockWatch:
    """The host clock seen by one capture: its state at each part's start, and the steps since.

    ``adjtimex`` and ``clocks`` are injectable (tests).
    """

    def __init__(
        self, adjtimex: Callable[[], KernelTime | None] = kernel_adjtimex, clocks: HostClocks | None = None
    ) -> None:
        self._adjtimex = adjtimex
        self.steps = StepWatch(clocks)
        self.state: SyncState | None = None

    def sync(self) -> SyncState:
        """Read the synchronisation state now (at the start of a part)."""
        self.state = read_sync(self._adjtimex)
        return self.state

    def check(self, t_ns: int) -> str | None:
        return self.steps.check(t_ns)

    def status(self) -> dict[str, Any]:
        """The status document's ``clock``: the last state read and the steps seen."""
        state = self.state or SyncState(None, source="unavailable")
        return {**state.status(), "steps": self.steps.steps}
