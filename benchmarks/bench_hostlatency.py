"""How late this machine wakes even its most urgent thread: the floor under host-clock losses.

A thread at real-time priority, above the readers, sleeps to absolute deadlines
``--interval-us`` apart on one CPU (as a reader does between polls) and records how
late each wake-up came: time in which nothing inside this operating system ran it -
the hypervisor running other guests or throttling this one, firmware (SMIs), or a
kernel path that cannot be preempted. A reader process (acquisition/readers.py)
cannot be timelier than this: a wake-up later than a device's hold time (the
ADIS16448's 2.44 ms) costs its samples whatever the station does. (``cyclictest``
measures the same on a real-time kernel; this needs only Python, whose own
wake-up cost, some tens of us, is included.) It sleeps between wake-ups, so the
kernel's real-time throttling (``sched_rt_runtime_us``, 95 % of each second) never
applies, as it never applies to a reader.

Prints per CPU the latest wake-ups, how many were later than 1, 2.44 and 5 ms per
minute, and the hypervisor's steal time over the run.

    python benchmarks/bench_hostlatency.py --seconds 60          # every CPU in turn
    python benchmarks/bench_hostlatency.py --seconds 600 --cpu 1

Needs CAP_SYS_NICE (root) for SCHED_FIFO; without it the numbers include the
normal scheduler's delays, and the script says so. It keeps one CPU busy while it
runs: run it when nothing else is recording.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from imustation.acquisition.readers import steal_s

#: the probe's priority: above the readers (acquisition/realtime.py asks 40-49), below the kernel's threads
PROBE_PRIORITY = 50
HOLDS_MS = (1.0, 2.44, 5.0)


def probe(cpu: int, seconds: float, threshold_ns: int, interval_ns: int) -> tuple[np.ndarray, int, str]:
    """Wake-ups on ``cpu`` later than ``threshold_ns`` (ns late each), the wake-ups, and the scheduling had."""
    os.sched_setaffinity(0, {cpu})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PROBE_PRIORITY))
        how = f"SCHED_FIFO {PROBE_PRIORITY}"
    except PermissionError:
        how = "normal scheduling (SCHED_FIFO not permitted: the steps include other processes' turns)"
    now, sleep = time.monotonic_ns, time.sleep
    late: list[int] = []
    n = 0
    try:
        due = now()
        t_end = due + int(seconds * 1e9)
        while due < t_end:
            due += interval_ns
            wait = due - now()
            if wait > 0:
                sleep(wait / 1e9)
            t = now()
            n += 1
            if t - due > threshold_ns:
                late.append(t - due)
                due = t  # a late wake-up is not made up for, as a reader's poll is not
    finally:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return np.array(late, dtype=np.int64), n, how


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="per CPU (default 30)")
    ap.add_argument("--cpu", type=int, default=None, help="one CPU only (default: each in turn)")
    ap.add_argument("--threshold-us", type=float, default=200.0, help="record wake-ups later than this (default 200)")
    ap.add_argument("--interval-us", type=float, default=1000.0, help="between wake-ups (default 1000)")
    args = ap.parse_args()
    cpus = [args.cpu] if args.cpu is not None else sorted(os.sched_getaffinity(0))
    print(f"{os.cpu_count()} CPUs; load {os.getloadavg()[0]:.2f}; {args.seconds:g} s per CPU")
    for cpu in cpus:
        steal0 = steal_s()
        steps, n, how = probe(cpu, args.seconds, int(args.threshold_us * 1000), int(args.interval_us * 1000))
        steal = steal_s() - steal0
        per_min = 60.0 / args.seconds
        counts = ", ".join(f"> {h:g} ms: {per_min * np.count_nonzero(steps > h * 1e6):.1f}" for h in HOLDS_MS)
        worst = ", ".join(f"{v / 1e6:.2f}" for v in np.sort(steps)[::-1][:8])
        print(f"CPU {cpu} ({how}): {len(steps)} of {n} wake-ups > {args.threshold_us:g} us late; per minute {counts}")
        print(f"  latest (ms): {worst or '-'}; steal over the run {steal:.2f} s")


if __name__ == "__main__":
    main()
