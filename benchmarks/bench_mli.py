"""ML_i speed: one axis of a 12 h, 400 Hz record (budget: fit <= 0.2 s after integration).

The budget is docs/reference/design-contracts.md, "Performance budgets".

Prints the integration pass against a plain ``np.sum`` over the same data (the
memory-speed reference measured in the same run), the fit time split
(start points, Newton, observed information) and the other models' fit times.

    python benchmarks/bench_mli.py [--hours 12] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import best_of, table_iii_record

import imustation.analysis.estimators.engine.fitting as fitting
import imustation.analysis.estimators.engine.pattern as pattern
import imustation.analysis.estimators.ml.mli as mli


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    fs = 400.0
    n, x, counts = table_iii_record(args.hours, fs)
    print(f"record: {n} samples ({args.hours:g} h at {fs:g} Hz)")
    for label, data in (("float64", x), ("int16 counts", counts)):
        t_sum, _ = best_of(lambda d=data: np.sum(d, dtype=np.int64 if d.dtype.kind == "i" else None), args.repeat)
        t_int, _ = best_of(lambda d=data: pattern.integrate(d, fs), args.repeat)
        print(f"integration ({label}): {t_int * 1e3:7.1f} ms  np.sum: {t_sum * 1e3:7.1f} ms  ratio {t_int / t_sum:.2f}")
    inc = pattern.integrate(x, fs)

    # time split of the standard-model fit
    split: dict[str, float] = {}
    # each name is patched where the fit looks it up
    for module, name in (
        (mli, "allan_start"),
        (mli, "grid_start"),
        (mli, "optimise"),
        (fitting, "observed_information"),
    ):
        fn = getattr(module, name)

        def timed(*a, _fn=fn, _name=name, **k):
            t0 = time.perf_counter()
            r = _fn(*a, **k)
            split[_name] = split.get(_name, 0.0) + time.perf_counter() - t0
            return r

        setattr(module, name, timed)
    times = []
    for _ in range(args.repeat):
        split.clear()
        t0 = time.perf_counter()
        res = mli.fit_integrated(inc, "wn+gm")
        times.append(time.perf_counter() - t0)
    print(
        f"fit wn+gm (after integration): {min(times):.3f} s  (budget 0.2 s, ratio {min(times) / 0.2:.2f}); "
        f"starts {res.starts}, evaluations {res.n_eval}, converged {res.converged}"
    )
    print("  split (last run): " + ", ".join(f"{k.strip('_')} {v * 1e3:.0f} ms" for k, v in split.items()))
    print(f"  sigma_w {res.sigma_w:.4g}  sigma_b {res.sigma_b:.4g}  tau_b {res.tau_b:.4g}")
    for model in ("wn+rw", "wn+gm+rw", "wn+2gm", "wa+wn+gm"):
        tm, r = best_of(lambda mm=model: mli.fit_integrated(inc, mm), 1)
        print(f"fit {model:<9}: {tm:.3f} s  nll {r.nll:.2f}  BIC {r.bic:.2f}  converged {r.converged}")


if __name__ == "__main__":
    main()
