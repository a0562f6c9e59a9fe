"""GMWM speed: one axis of a 12 h, 400 Hz record.

Prints the wavelet-variance pass (float64 and int16 counts) against a plain
``np.sum`` over the same data (the memory-speed reference measured in the same
run), the fit on the WV alone (grid start + refinement + reweighting) for the
standard and richer models, and ML_i's fit time on the same record for scale.

    python benchmarks/bench_gmwm.py [--hours 12] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from imustation.analysis.gmwm import fit_gmwm, wavelet_variance
from imustation.analysis.mli import fit_integrated, integrate
from imustation.analysis.noise_models import standard
from imustation.analysis.reference import TABLE_III_MEAN


def _best(fn, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    fs = 400.0
    n = int(args.hours * 3600 * fs)
    t = TABLE_III_MEAN
    x = standard(t.sigma_w, t.sigma_b, t.tau_b, 0.01).simulate(n, fs, 1)
    counts = np.rint(x / 6.1e-5).astype(np.int16)
    print(f"record: {n} samples ({args.hours:g} h at {fs:g} Hz)")
    wavelet_variance(x[:10000], fs)  # compile the numba kernels outside the timings
    for label, data in (("float64", x), ("int16 counts", counts)):
        t_sum, _ = _best(lambda d=data: np.sum(d, dtype=np.int64 if d.dtype.kind == "i" else None), args.repeat)
        t_wv, wv = _best(lambda d=data: wavelet_variance(d, fs), args.repeat)
        print(f"wavelet variance ({label}, {len(wv.wv)} scales): {t_wv * 1e3:7.1f} ms  np.sum: {t_sum * 1e3:6.1f} ms")
    for model in ("wn+gm", "wn+gm+rw", "wn+2gm"):
        t_all, res = _best(lambda m=model: fit_gmwm(x, fs, m), args.repeat)
        print(f"fit_gmwm {model:<9} total {t_all:6.2f} s (WV + fit), {res.n_eval} model evaluations, {res.message}")
    inc = integrate(x, fs)
    t_mli, _ = _best(lambda: fit_integrated(inc, "wn+gm"), args.repeat)
    print(f"ML_i wn+gm fit (after integration): {t_mli:6.2f} s")


if __name__ == "__main__":
    main()
