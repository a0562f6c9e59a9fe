"""Peak memory of the Allan deviation of a long run-file channel (design budget: 120 h at 400 Hz < 1 GB).

Writes a run file of one simulated 3-axis int16 gyro (white counts, written in
blocks), then, in a fresh process, loads one axis lazily (compact int16 counts,
read in blocks) and computes the overlapping ADEV at ~100 log taus; prints the
peak resident memory of that process and the time:

    python benchmarks/bench_oadev_memory.py [--hours 120] [--keep FILE.h5]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

FS = 400.0
BLOCK = 1 << 20


def write_run(path: str, hours: float) -> int:
    from imustation.runfile import ChannelSpec, DeviceSpec, RunWriter

    n = int(hours * 3600 * FS)
    spec = DeviceSpec(
        "gyro0", "sim", "sim", "sim", "0", FS, {}, (ChannelSpec("gyro", "<i2", "rad/s", 6.65e-5, 0.0, ("x", "y", "z")),)
    )
    rng = np.random.default_rng(0)
    period = int(1e9 / FS)
    with RunWriter(path, station="bench", config_text="", simulated=True, devices=[spec], overwrite=True) as w:
        for i in range(0, n, BLOCK):
            k = min(BLOCK, n - i)
            t = (np.arange(i, i + k, dtype=np.int64) + 1) * period
            w.append("gyro0", t, {"gyro": rng.normal(0, 30, (k, 3)).astype(np.int16)})
    return n


def measure(path: str) -> None:
    from imustation.analysis import oadev
    from imustation.analysis.pipeline.loaders import load_run

    t0 = time.perf_counter()
    ch = load_run(path, ["gyro0/gyro/z"])[0]
    data = ch.data
    t_load = time.perf_counter() - t0
    m = np.unique(np.round(np.logspace(0, np.log10((ch.n - 1) // 2), 100)))
    t0 = time.perf_counter()
    res = oadev(data, ch.fs_hz, m / ch.fs_hz, scale=ch.scale, segments=ch.segments)
    t_adev = time.perf_counter() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"samples {ch.n} ({ch.n / FS / 3600:.0f} h at {FS:g} Hz), {len(res.tau)} taus")
    print(
        f"load counts {t_load:.1f} s, oadev {t_adev:.1f} s, peak RSS {peak_mb:.0f} MB (budget 1024 MB):",
        "MET" if peak_mb < 1024 else "NOT MET",
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=120.0)
    ap.add_argument("--keep", default=None, help="write the run file here and keep it")
    ap.add_argument("--measure", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        measure(args.measure)
        return
    path = args.keep or os.path.join(tempfile.mkdtemp(), "long.h5")
    if not os.path.exists(path):
        t0 = time.perf_counter()
        n = write_run(path, args.hours)
        print(f"wrote {n} samples x 3 axes to {path} in {time.perf_counter() - t0:.0f} s")
    subprocess.run([sys.executable, __file__, "--measure", path], check=True)
    if not args.keep:
        os.remove(path)


if __name__ == "__main__":
    main()
