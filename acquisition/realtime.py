"""Timely scheduling for the reader processes of a host-clock capture, asked of the operating system.

A device without a FIFO (the ADIS16448 at 409.6 Hz holds each sample 2.4 ms)
loses a sample whenever its reader is off the CPU for longer than that. Three
requests make that rare, each where it is permitted:

* real-time scheduling (``SCHED_FIFO``, :data:`READER_PRIORITY` and up): a reader
  that wakes up runs at once, ahead of every normal process (busy loops, compilers,
  the writer's compression); a reader sleeps between polls, so it takes little.
  Readers rank among themselves by their shortest hold time (rate-monotonic: the
  ADIS16448's 2.4 ms before FIFOs of a fifth of a second; :func:`reader_priority`),
  so a slow poll of a FIFO device never delays a device without one. When
  refused, a raised ``nice`` priority (-10), and when that is refused too, none.
  A reader drops its priority when it has finished polling (:func:`release_scheduling`);
  its shutdown then never holds up a reader still polling;
* memory locked (``mlockall``): a reader never waits for a page to come back from swap;
* CPU placement (``sched_setaffinity``), when asked for (``capture --reader-cpus``):
  the readers then share those CPUs (e.g. cores isolated for them with ``isolcpus``).
  Not by default: the kernel puts a woken real-time task on the CPU running the
  least important work, which did better than pinning on the 2-CPU virtual machine
  this was measured on (ADIS16448, 20 s at load 9: 3 samples lost unpinned, 10-12
  with every reader pinned to the second CPU), and a pinned normal-priority process
  cannot leave a CPU a busy loop holds.

:func:`request_scheduling` asks for all three in the calling process and returns
what it got as :class:`Scheduling`, whose ``missing`` line (one line, or "") says
what was refused and how to grant it (the systemd unit keys ``LimitRTPRIO=`` /
``LimitMEMLOCK=``, or the capabilities ``CAP_SYS_NICE`` / ``CAP_IPC_LOCK``).
Linux calls; on other systems every request is reported missing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import os
from dataclasses import dataclass

from imustation.errors import InputError

#: SCHED_FIFO priority of the readers (1..99): below 50, where PREEMPT_RT kernels run their
#: interrupt threads (the USB and I2C interrupts a reader's own transfers wait for)
READER_PRIORITY = 40
#: highest priority a reader gets (short hold times), still below the interrupt threads
READER_PRIORITY_MAX = 49
#: nice value asked for when real-time scheduling is refused
READER_NICE = -10
#: mlockall(2) flags (<sys/mman.h>): pages mapped now and in the future
MCL_CURRENT, MCL_FUTURE = 1, 2


@dataclass(frozen=True)
class Scheduling:
    """What one process obtained: its policy, priority, locked memory and CPUs."""

    policy: str  # "SCHED_FIFO", "nice -10" or "normal"
    memory_locked: bool
    cpus: tuple[int, ...] | None  # None: not pinned
    #: one line naming what was refused and how to grant it, or ""
    missing: str = ""

    def describe(self) -> str:
        """One line: ``SCHED_FIFO 40, memory locked, CPU 1``."""
        parts = [self.policy, "memory locked" if self.memory_locked else "memory not locked"]
        if self.cpus is not None:
            parts.append("CPU " + ",".join(map(str, self.cpus)))
        return ", ".join(parts)


def reader_priority(base: int, hold_s: float) -> int:
    """SCHED_FIFO priority of a reader whose shortest hold time is ``hold_s`` (s): ``base`` plus one step
    per halving of the hold below 1 s, at most READER_PRIORITY_MAX (``base`` 0: 0, nothing asked)."""
    if base <= 0:
        return 0
    steps = int(math.log2(1.0 / hold_s)) if 0 < hold_s < 1.0 else 0
    return min(READER_PRIORITY_MAX, base + steps)


def release_scheduling() -> None:
    """Back to normal scheduling (the reader has finished polling; what is left must not hold up others)."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass


def request_scheduling(*, priority: int = READER_PRIORITY, cpus: tuple[int, ...] | None = None) -> Scheduling:
    """Ask for real-time (else raised) priority, locked memory and the ``cpus`` given; report what held.

    ``priority``: SCHED_FIFO priority, 1..99; 0 asks for no priority and no locked memory
    and reports nothing missing. ``cpus``: the CPUs to run on (None: any).
    """
    placed = _place(cpus)
    if priority <= 0:
        return Scheduling("normal", False, placed)
    refused = []
    policy = "normal"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        policy = f"SCHED_FIFO {priority}"
    except (OSError, AttributeError):
        refused.append(f"real-time priority (LimitRTPRIO={priority} in the service unit, or CAP_SYS_NICE)")
        try:
            os.setpriority(os.PRIO_PROCESS, 0, READER_NICE)
            policy = f"nice {READER_NICE}"
        except (OSError, AttributeError):
            pass
    locked = _mlockall()
    if not locked:
        refused.append("locked memory (LimitMEMLOCK=infinity, or CAP_IPC_LOCK)")
    missing = ""
    if refused:
        missing = (
            f"reader processes run with {policy} scheduling: not permitted: {'; '.join(refused)}"
            " - samples of devices without a FIFO may be lost on a busy host (docs/capture.md)"
        )
    return Scheduling(policy, locked, placed, missing)


def _place(cpus: tuple[int, ...] | None) -> tuple[int, ...] | None:
    """Run on ``cpus`` (None: leave the placement to the kernel); raise a one-line error for CPUs not usable."""
    if cpus is None:
        return None
    try:
        os.sched_setaffinity(0, cpus)
    except (OSError, ValueError) as exc:
        usable = ",".join(map(str, sorted(os.sched_getaffinity(0))))
        raise InputError(
            f"--reader-cpus {','.join(map(str, cpus))}: not usable here (usable: {usable}): {exc}"
        ) from None
    return tuple(sorted(cpus))


def _mlockall() -> bool:
    """Lock this process's memory, now and as it grows; False where refused or unavailable."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        return libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0
    except (OSError, AttributeError):
        return False
