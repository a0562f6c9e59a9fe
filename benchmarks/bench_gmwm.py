"""GMWM speed: one axis of a 12 h, 400 Hz record.

Prints the wavelet-variance pass (float64 and int16 counts) against a plain
``np.sum`` over the same data (the memory-speed reference measured in the same
run), the fit on the WV alone (grid start + refinement + reweighting) for the
standard and richer models, and ML_i's fit time on the same record for scale.

    python benchmarks/bench_gmwm.py [--hours 12] [--repeat 3]
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import best_of, table_iii_record

from imustation.analysis.estimators.engine.pattern import integrate
from imustation.analysis.estimators.ml.gmwm import fit_gmwm, wavelet_variance
from imustation.analysis.estimators.ml.mli import fit_integrated


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    fs = 400.0
    n, x, counts = table_iii_record(args.hours, fs)
    print(f"record: {n} samples ({args.hours:g} h at {fs:g} Hz)")
    wavelet_variance(x[:10000], fs)  # compile the numba kernels outside the timings
    for label, data in (("float64", x), ("int16 counts", counts)):
        t_sum, _ = best_of(lambda d=data: np.sum(d, dtype=np.int64 if d.dtype.kind == "i" else None), args.repeat)
        t_wv, wv = best_of(lambda d=data: wavelet_variance(d, fs), args.repeat)
        print(f"wavelet variance ({label}, {len(wv.wv)} scales): {t_wv * 1e3:7.1f} ms  np.sum: {t_sum * 1e3:6.1f} ms")
    for model in ("wn+gm", "wn+gm+rw", "wn+2gm"):
        t_all, res = best_of(lambda m=model: fit_gmwm(x, fs, m), args.repeat)
        print(f"fit_gmwm {model:<9} total {t_all:6.2f} s (WV + fit), {res.n_eval} model evaluations, {res.message}")
    inc = integrate(x, fs)
    t_mli, _ = best_of(lambda: fit_integrated(inc, "wn+gm"), args.repeat)
    print(f"ML_i wn+gm fit (after integration): {t_mli:6.2f} s")


if __name__ == "__main__":
    main()
