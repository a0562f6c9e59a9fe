"""Speed of ``imustation.analysis.oadev`` against allantools ``oadev`` (same data, same taus).

Design budget: >= 10x allantools on 17.3 M samples (12 h at 400 Hz) with ~100 log-spaced
taus, results identical to 1e-9 relative. Both are timed in this run, on this machine:

    python benchmarks/bench_oadev.py [--n 17280000] [--taus 100]
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=17_280_000, help="samples (default 12 h at 400 Hz)")
    ap.add_argument("--taus", type=int, default=100, help="number of log-spaced taus requested")
    ap.add_argument("--fs", type=float, default=400.0)
    args = ap.parse_args()

    import allantools

    from imustation.analysis import StandardModel, oadev, simulate_standard

    fs, n = args.fs, args.n
    scale = 6.65e-5  # rad/s per count, a BMX055-like gyro (docs/reference/sensors.md)
    truth = StandardModel(1.05e-4, 1.26e-6, 530.5, 0.01)
    counts = np.rint(simulate_standard(truth, n, fs, 1) / scale).astype(np.int16)
    rate = counts.astype(np.float64) * scale
    m = np.unique(np.round(np.logspace(0, np.log10((n - 1) // 2), args.taus))).astype(np.int64)
    taus = m / fs

    oadev(counts[:10_000], fs, taus[:3], scale=scale)  # compile the kernels (cached on disk afterwards)
    t0 = time.perf_counter()
    ours = oadev(counts, fs, taus, scale=scale)
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    ours_f = oadev(rate, fs, taus)
    t_ours_f = time.perf_counter() - t0
    t0 = time.perf_counter()
    t_ref, ad_ref, _, _ = allantools.oadev(rate, rate=fs, data_type="freq", taus=taus)
    t_at = time.perf_counter() - t0

    assert np.allclose(ours.tau, t_ref, rtol=1e-12, atol=0)
    err = float(np.max(np.abs(ours.adev / ad_ref - 1)))
    err_f = float(np.max(np.abs(ours_f.adev / ad_ref - 1)))
    print(f"samples {n}, taus {len(m)} (m = 1 .. {m[-1]})")
    print(f"allantools oadev (float rate)   : {t_at:8.3f} s")
    for label, t, e in (("int16 counts", t_ours, err), ("float rate  ", t_ours_f, err_f)):
        print(f"imustation oadev ({label}): {t:8.3f} s   ratio {t_at / t:6.1f}x   max rel diff {e:.1e}")
    met = min(t_at / t_ours, t_at / t_ours_f) >= 10 and max(err, err_f) <= 1e-9
    print("budget (ratio >= 10, rel diff <= 1e-9):", "MET" if met else "NOT MET")


if __name__ == "__main__":
    main()
