"""Host-clock capture: samples lost per device and CPU per sample, idle and beside busy loops.

Records the lab (``configs/lab-example.toml``) with its chips simulated at the bus
level on the host clock - the path a capture of real devices takes, with the
simulators' own cost inside each poll - for ``--duration`` seconds in each of:

* ``readers``: every bus in a reader process of its own (``capture --simulate
  --real-time``, acquisition/readers.py), scheduled as the OS permits;
* ``blind``: the same reader processes polling a device without a FIFO blind, twice
  a sample (before phase-locked polls, acquisition/pollphase.py);
* ``threads``: the same-run reference, one process with a reader thread per bus
  (the station before reader processes; ``capture(..., clock=MonotonicClock())``);

each idle and with ``--busy`` busy-loop processes beside it (started and stopped
here). Prints per device the samples written and lost (and per 10,000), the CPU
each reader process used per sample of its devices while recording, the writer's
CPU per sample, the machine's load (1-minute load average after each case), and
whether the run file accounts for every sample (``imustation inspect``'s check:
every hole logged, written + logged = produced; on the host clock this is the
check the test suite cannot make, its outcome depending on the machine's load).

Targets (issue 36): readers, idle: 0 lost; beside two busy loops: at most 1 in
10,000 per device.

    python benchmarks/bench_hostclock.py                   # 60 s per case, 4 cases
    python benchmarks/bench_hostclock.py --duration 600 --only readers
    python benchmarks/bench_hostclock.py --duration 600 --only readers --spin-us 500   # hybrid sleep
    python benchmarks/bench_hostclock.py --duration 300 --modes readers,blind          # phase-locked vs blind
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
import warnings

from imustation.acquisition import capture, load_config
from imustation.clock import MonotonicClock
from imustation.configs import config_path
from imustation.runfile import open_run
from imustation.runfile.holes import check_run, check_thermometers

TARGET_BUSY_PER_10K = 1.0


def busy_loops(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def run_case(cfg, mode: str, busy: int, duration_s: float, folder: str, spin_us: int = 0) -> dict:
    """One capture: ``mode`` readers (phase-locked polls), blind (readers polling twice a sample) or threads."""
    loops = busy_loops(busy)
    try:
        out = os.path.join(folder, f"{mode}-{busy}.h5")
        self0 = resource.getrusage(resource.RUSAGE_SELF)
        wall0 = time.monotonic()
        if mode in ("readers", "blind"):
            summary = capture(
                cfg,
                out,
                duration_s,
                simulate=True,
                real_time=True,
                overwrite=True,
                reader_spin_us=spin_us,
                reader_phase=mode == "readers",
            )
        else:
            summary = capture(cfg, out, duration_s, simulate=True, clock=MonotonicClock(), overwrite=True)
        wall = time.monotonic() - wall0
        self1 = resource.getrusage(resource.RUSAGE_SELF)
    finally:
        for p in loops:
            p.kill()
            p.wait()
    accounting, (late, holes) = file_accounting(out), event_lines(out)
    os.unlink(out)
    main_cpu = (self1.ru_utime + self1.ru_stime) - (self0.ru_utime + self0.ru_stime)
    return {
        "summary": summary,
        "main_cpu": main_cpu,
        "wall": wall,
        "load": os.getloadavg()[0],
        "config": cfg,
        "accounting": accounting,
        "late": late,
        "holes": holes,
    }


def file_accounting(path: str) -> list[str]:
    """What the run file's own check finds wrong (empty: every hole logged, written + logged = produced),
    and the rates its reader corrected from the stamps (they change how it counts a hole)."""
    problems: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with open_run(path) as run:
            for name, c in check_run(run).items():
                if not c.consistent:
                    problems.append(
                        f"{name}: {c.samples} written + {c.logged} logged != {c.produced} produced; "
                        f"unlogged holes {[(h.lost, h.logged) for h in c.unlogged[:3]]}"
                    )
            for name, c in check_thermometers(run).items():
                if c is not None and not c.consistent:
                    problems.append(f"thermometer {name}: {c.samples} read + {c.logged} logged != {c.produced}")
    problems += [f"note: {w.message}" for w in caught if "contradicts its timestamps" in str(w.message)]
    return problems


def event_lines(path: str, most: int = 12) -> tuple[list[str], list[str]]:
    """From the run file's events: the readers' notes of polls started late (acquisition/readers.py
    lateness_note), and the first ``most`` logged losses - when, how many, why (how long unread)."""
    with open_run(path) as run:
        events = run.events()
    late = [e.detail for e in events if e.kind == "note" and "polls started over" in e.detail]
    holes = [f"{e.source} at {e.t_ns / 1e9:.3f} s: {e.lost} lost ({e.detail})" for e in events if e.lost]
    return late, holes[:most]


def report(mode: str, busy: int, res: dict) -> bool:
    s = res["summary"]
    total = sum(s.samples.values())
    print(f"\n{mode}, {busy} busy loop(s) beside it: {s.duration_s:.0f} s recorded, load {res['load']:.1f}")
    print(f"  {'device':14s} {'samples':>9s} {'lost':>6s} {'per 10k':>8s}")
    ok = True
    for name, n in s.samples.items():
        lost = s.lost[name]
        per10k = 1e4 * lost / max(1, n + lost)
        ok &= per10k <= (TARGET_BUSY_PER_10K if busy else 0.0)
        print(f"  {name:14s} {n:9d} {lost:6d} {per10k:8.2f}")
    if s.reader_cpu_s:
        for bus, cpu in s.reader_cpu_s.items():
            n_bus = sum(s.samples[d.name] for d in res["config"].devices if d.bus == bus)
            print(f"  reader {bus}: {cpu:.2f} s CPU, {1e6 * cpu / max(1, n_bus):.0f} us per sample of its devices")
        readers = sum(s.reader_cpu_s.values())
        print(
            f"  CPU per sample: readers {1e6 * readers / max(1, total):.1f} us, "
            f"writer (main process) {1e6 * res['main_cpu'] / max(1, total):.1f} us"
        )
    else:
        print(f"  CPU per sample (one process, readers and writer): {1e6 * res['main_cpu'] / max(1, total):.1f} us")
    problems = res["accounting"]
    print("  the file accounts for every sample" if not problems else "  the file's check:")
    for line in problems:
        print(f"    {line}")
    for line in res["late"]:
        print(f"  {line}")
    for line in res["holes"]:
        print(f"  hole: {line}")
    return ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds per case (default 60)")
    ap.add_argument("--busy", type=int, default=2, help="busy-loop processes in the loaded cases (default 2)")
    ap.add_argument("--config", default="lab-example.toml")
    ap.add_argument(
        "--modes",
        default="readers,threads",
        help="comma-separated: readers (reader processes, phase-locked polls), blind (reader processes polling "
        "a device without a FIFO twice a sample: the reference for phase locking), threads (default "
        "readers,threads)",
    )
    ap.add_argument("--only", choices=["readers", "blind", "threads"], default=None, help="run one mode only")
    ap.add_argument("--cases", default="idle,busy", help="comma-separated: idle, busy (default both)")
    ap.add_argument(
        "--spin-us",
        type=int,
        default=0,
        help="readers: hybrid sleep, the last N us before a poll of a device without a FIFO spent reading "
        "the clock instead of sleeping (default 0: off)",
    )
    args = ap.parse_args()
    cfg = load_config(config_path(args.config))
    print(f"{args.config}: {len(cfg.devices)} devices, {os.cpu_count()} CPUs; uptime: ", end="", flush=True)
    subprocess.run(["uptime"], check=False)
    modes = [args.only] if args.only else args.modes.split(",")
    cases = {"idle": 0, "busy": args.busy}
    loads = [cases[c] for c in args.cases.split(",")]
    verdicts = {}
    with tempfile.TemporaryDirectory() as folder:
        for busy in loads:
            for mode in modes:  # modes side by side in each case: the same host conditions
                res = run_case(cfg, mode, busy, args.duration, folder, args.spin_us)
                verdicts[(mode, busy)] = report(mode, busy, res)
    if "readers" in modes:
        said = {0: "idle 0 lost", args.busy: f"{args.busy} busy loops <= {TARGET_BUSY_PER_10K:g} in 10,000 per device"}
        print(
            "\ntargets (readers): "
            + "; ".join(f"{said[b]}: {'met' if verdicts[('readers', b)] else 'NOT met'}" for b in loads)
        )


if __name__ == "__main__":
    main()
