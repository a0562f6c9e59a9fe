"""ML_i-F speed: one axis of a 12 h, 400 Hz record (issue budget: <= 0.5 s per axis).

Prints, best of ``--repeat`` runs, the data passes (uniform-pattern integration and
the fine-scale Allan variance with the whiteness test) and the fit, against ML_i
(log pattern, m = 1000) and GMWM on the same record measured in the same run.

    python benchmarks/bench_noise_model.py [--hours 12] [--repeat 3]
"""

from __future__ import annotations

import argparse

from _common import COUNT_SCALE, best_of, table_iii_record

from imustation.analysis.estimators.engine.pattern import integrate
from imustation.analysis.estimators.ml.composite import DEFAULT_M, fine_scale, fit_composite_data
from imustation.analysis.estimators.ml.gmwm import fit_gmwm
from imustation.analysis.estimators.ml.mli import fit_integrated


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    fs = 400.0
    n, x, counts = table_iii_record(args.hours, fs)
    print(f"record: {n} samples ({args.hours:g} h at {fs:g} Hz)")
    for label, data, scale in (("float64", x, 1.0), ("int16 counts", counts, COUNT_SCALE)):
        t_int, inc = best_of(
            lambda d=data, s=scale: integrate(d, fs, m=DEFAULT_M, pattern="uniform", scale=s), args.repeat
        )
        t_fine, fine = best_of(lambda d=data, s=scale: fine_scale(d, fs, samples="auto", scale=s), args.repeat)
        t_fit, res = best_of(lambda i=inc, f=fine: fit_composite_data(i, f), args.repeat)
        total = t_int + t_fine + t_fit
        print(
            f"ML_i-F ({label}): integration {t_int * 1e3:6.1f} ms, fine scale {t_fine * 1e3:6.1f} ms, "
            f"fit {t_fit * 1e3:6.1f} ms; total {total:.3f} s (budget 0.5 s, ratio {total / 0.5:.2f})"
        )
    print(f"  sigma_w {res.sigma_w:.5g}  sigma_b {res.sigma_b:.4g}  tau_b {res.tau_b:.4g}  {res.message}")
    t_mli_int, inc_log = best_of(lambda: integrate(x, fs), args.repeat)
    t_mli, r_mli = best_of(lambda: fit_integrated(inc_log), args.repeat)
    t_gmwm, r_gmwm = best_of(lambda: fit_gmwm(x, fs), max(1, args.repeat - 1))
    print(f"ML_i (log, m=1000): integration {t_mli_int * 1e3:.1f} ms + fit {t_mli:.3f} s")
    print(f"GMWM              : {t_gmwm:.3f} s (wavelet variance and fit)")
    print(f"ratio ML_i-F total / GMWM: {total / t_gmwm:.2f}; / ML_i total: {total / (t_mli_int + t_mli):.2f}")
    for name, r in (("ML_i", r_mli), ("GMWM", r_gmwm)):
        print(f"  {name}: sigma_w {r.sigma_w:.5g}  sigma_b {r.sigma_b:.4g}  tau_b {r.tau_b:.4g}")


if __name__ == "__main__":
    main()
