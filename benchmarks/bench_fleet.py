"""Fleet analysis on dask.distributed: twenty simulated 12 h runs, 1 worker vs 2 workers.

The run files are synthesised directly (not captured): a BMX055-like gyroscope,
400 Hz, three axes drawn from the standard noise model (paper Table III mean
parameters) with :meth:`NoiseModel.simulate`, quantised to int16 counts and
written with the project's :class:`~imustation.runfile.RunWriter` (capture would
cost 20 x 12 h / 200 of wall time for the same files). Then every channel is
analysed (Allan, IEEE-952, ML_i, verdict: ``imustation analyze``'s per-channel
task) on a local cluster of 1 and of 2 single-threaded worker processes; the
JSON of both is checked identical. Prints the per-channel cost, the memory of
one task (peak RSS growth of a fresh process analysing one channel) and the
speed-up.

    python benchmarks/bench_fleet.py [--runs 20] [--hours 12] [--repeat 1] [--dir DIR] [--keep]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np

from imustation.analysis.estimators.models.noise_models import standard
from imustation.analysis.estimators.models.reference import TABLE_III_MEAN
from imustation.analysis.pipeline.channel import analysis_document
from imustation.analysis.pipeline.parallel import AnalysisOptions, dask_client, plan_tasks, run_tasks
from imustation.runfile import ChannelSpec, DeviceSpec, RunWriter

FS_HZ = 400.0
SCALE = 6.651407e-05  # rad/s per count, BMX055 at 125 deg/s
BLOCK = 1 << 21


def synth_run(path: str, hours: float, seed: int) -> int:
    """Write one run file of a simulated 3-axis gyro; returns its size in bytes."""
    n = int(hours * 3600 * FS_HZ)
    p = TABLE_III_MEAN
    model = standard(p.sigma_w, p.sigma_b, p.tau_b, 0.01)
    counts = np.empty((n, 3), dtype=np.int16)
    for j in range(3):
        counts[:, j] = np.rint(model.simulate(n, FS_HZ, seed * 3 + j) / SCALE).astype(np.int16)
    t_ns = np.rint(np.arange(n) * (1e9 / FS_HZ)).astype(np.int64)
    dev = DeviceSpec(
        name="gyro",
        driver="bmx055",
        model="BMX055 gyro (BMG160), synthesised",
        bus="sim:",
        identity=f"chip_id=0x0F serial=bench{seed:04d}",
        rate_hz=FS_HZ,
        settings={"bandwidth_hz": 47.0, "gyro_range_dps": 125},
        channels=(ChannelSpec("gyro", "<i2", "rad/s", SCALE, axes=("x", "y", "z")),),
    )
    with RunWriter(
        path, station="bench", config_text="", simulated=True, devices=[dev], fsync=False, ballast_bytes=0,
        max_buffer_rows=BLOCK * 2,
    ) as w:  # fmt: skip
        for a in range(0, n, BLOCK):
            w.append("gyro", t_ns[a : a + BLOCK], {"gyro": counts[a : a + BLOCK]})
            w.flush()
    return os.path.getsize(path)


_ONE_TASK = """
import sys, time
from imustation.analysis.pipeline.parallel import AnalysisOptions, analyze_task

def hwm():  # peak RSS of this process image, bytes (VmHWM starts afresh at exec, unlike ru_maxrss)
    with open("/proc/self/status") as fh:
        return next(int(l.split()[1]) * 1024 for l in fh if l.startswith("VmHWM"))

r0 = hwm()
t0 = time.perf_counter()
analyze_task(sys.argv[1], sys.argv[2], AnalysisOptions())
dt = time.perf_counter() - t0
print(r0, hwm(), dt)
"""


def task_memory(path: str, channel: str) -> tuple[float, float, float]:
    """(RSS after imports, peak RSS, seconds) of a fresh single-threaded process analysing one channel."""
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    out = subprocess.run(
        [sys.executable, "-c", _ONE_TASK, path, channel], capture_output=True, text=True, env=env, check=True
    )
    a, b, dt = out.stdout.split()
    return float(a), float(b), float(dt)


def _cpu_s() -> float:
    """CPU seconds (user + system) of this worker process."""
    t = os.times()
    return t.user + t.system


def _warm_up() -> None:
    """Load the numba kernels and scipy in a worker (part of the cluster start, not of the tasks)."""
    from imustation.analysis.pipeline.channel import analyze_channel
    from imustation.analysis.pipeline.loaders import Channel

    x = standard(1e-4, 1e-6, 100.0, 0.0).simulate(40000, FS_HZ, 0)
    analyze_channel(Channel("warm", FS_HZ, "rad/s", np.rint(x / SCALE).astype(np.int16), SCALE))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--dir", default="/tmp/imustation-fleet-bench")
    ap.add_argument("--repeat", type=int, default=1, help="alternate 1 and 2 workers this often, keep the best")
    ap.add_argument("--keep", action="store_true", help="keep the run files (and reuse them next time)")
    args = ap.parse_args()
    os.makedirs(args.dir, exist_ok=True)
    paths, size, t0 = [], 0, time.perf_counter()
    for k in range(args.runs):
        p = os.path.join(args.dir, f"run{k:02d}_{args.hours:g}h.h5")
        if not os.path.exists(p):
            synth_run(p, args.hours, k + 1)
        size += os.path.getsize(p)
        paths.append(p)
    n = int(args.hours * 3600 * FS_HZ)
    print(f"{args.runs} runs x 3 axes of {args.hours:g} h at {FS_HZ:g} Hz ({n} samples/axis): "
          f"{size / 2**30:.2f} GiB on disk ({size / args.runs / 2**20:.0f} MiB/run), "
          f"made in {time.perf_counter() - t0:.0f} s")  # fmt: skip
    tasks, failures = plan_tasks(paths)
    assert not failures, failures
    rss0, rss1, one = task_memory(paths[0], tasks[0].channel)
    print(f"one task in a fresh process: {one:.2f} s, RSS {rss0 / 2**20:.0f} MiB after imports, "
          f"peak {rss1 / 2**20:.0f} MiB (+{(rss1 - rss0) / 2**20:.0f} MiB for the channel)")  # fmt: skip
    opts = AnalysisOptions()
    times: dict[int, float] = {1: np.inf, 2: np.inf}
    docs, cpu = {}, {}
    for rep in range(args.repeat):  # 1 and 2 workers alternate: both see the same machine load
        for workers in (1, 2):
            t0 = time.perf_counter()
            with dask_client(workers, dashboard_address=None) as client:
                client.run(_warm_up)  # every worker up, kernels loaded
                t_start = time.perf_counter() - t0
                cpu0 = sum(client.run(_cpu_s).values())
                t1 = time.perf_counter()
                results, failed = run_tasks(tasks, opts, client)
                wall = time.perf_counter() - t1
                used = sum(client.run(_cpu_s).values()) - cpu0
            assert not failed, failed
            docs[workers] = json.dumps(analysis_document(results))
            if wall < times[workers]:
                times[workers], cpu[workers] = wall, used
            print(f"[{rep + 1}/{args.repeat}] {workers} worker(s): {wall:.1f} s for {len(tasks)} channels "
                  f"({wall / len(tasks):.2f} s/channel wall, start+warm-up {t_start:.1f} s); "
                  f"worker CPU {used:.1f} s = {used / len(tasks):.2f} CPU-s/channel, "
                  f"{used / (wall * workers):.0%} of {workers} core(s)", flush=True)  # fmt: skip
    print(f"best of {args.repeat}: 1 worker {times[1]:.1f} s, 2 workers {times[2]:.1f} s")
    print(f"speed-up 2 vs 1 worker: {times[1] / times[2]:.2f}")
    print(f"CPU-s per channel: 1 worker {cpu[1] / len(tasks):.2f}, 2 workers {cpu[2] / len(tasks):.2f}; "
          f"speed-up on two idle cores (2 x CPU ratio): {2 * cpu[1] / cpu[2]:.2f}")  # fmt: skip
    print(f"JSON identical: {docs[1] == docs[2]}")
    print(f"core-seconds per channel: {times[1] / len(tasks):.2f} (1 worker wall), "
          f"{cpu[1] / len(tasks):.2f} (CPU)")  # fmt: skip
    print("a worker that got less than 100 % of its core shared the machine with other jobs")
    if not args.keep:
        shutil.rmtree(args.dir, ignore_errors=True)


if __name__ == "__main__":
    main()
