"""Time of the run-file reader's rate check (docs/runfile.md) on a long record, against reading its stamps.

Writes a run file of one 400 Hz device (``--hours`` of stamps with a little jitter and a gyro record),
then times ``open_run`` (which probes the stamps in windows spread over the whole record,
:func:`imustation.runfile.rate.probe_windows`) and, as the reference measured in the same run, one read
of the whole ``t`` dataset (what a check over every stamp would cost at the least):

    python benchmarks/bench_rate_check.py [--hours 12] [--keep FILE]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

RATE = 400.0
BLOCK = 1 << 20


def write(path: str, hours: float) -> int:
    from imustation.channels import ChannelSpec
    from imustation.runfile import DeviceSpec, RunWriter

    n = int(hours * 3600 * RATE)
    spec = DeviceSpec("imu", "bmi088", "BMI088", "i2c:1", "sim", RATE, {},
                      (ChannelSpec("gyro", "<i2", "rad/s", 1e-4, axes=("x", "y", "z")),))  # fmt: skip
    rng = np.random.default_rng(1)
    with RunWriter(path, station="bench", config_text="", simulated=True, devices=[spec], ballast_bytes=0) as w:
        for a in range(0, n, BLOCK):
            i = np.arange(a, min(n, a + BLOCK))
            t = np.rint(i * 1e9 / RATE + rng.uniform(0, 2e5, len(i))).astype(np.int64)
            w.append("imu", t, {"gyro": rng.normal(0, 40, (len(i), 3)).astype(np.int16)})
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--keep", help="write (or reuse) the run file here")
    args = ap.parse_args()
    from imustation.runfile import open_run

    path = args.keep or os.path.join(tempfile.mkdtemp(), "long.h5")
    if not os.path.exists(path):
        t0 = time.perf_counter()
        n = write(path, args.hours)
        print(f"wrote {n} rows ({os.path.getsize(path) / 1e6:.0f} MB) in {time.perf_counter() - t0:.1f} s")
    best_open = best_read = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        with open_run(path) as r:
            best_open = min(best_open, time.perf_counter() - t0)
            n = len(r.h5["devices/imu/t"])
            t0 = time.perf_counter()
            r.h5["devices/imu/t"][()]
            best_read = min(best_read, time.perf_counter() - t0)
    print(f"{n} rows: open_run (rate check in windows) {best_open * 1e3:.0f} ms; "
          f"one read of every stamp {best_read * 1e3:.0f} ms; ratio {best_open / best_read:.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
