"""Model adequacy: cost per channel, false alarms on true-model records, detection of a flicker floor.

Prints, for a 12 h, 400 Hz record of the paper's Table III model: the time of the
adequacy test (AVAR covariance across tau + statistic) and of the degenerate-channel
screen, as ratios of the ML_i-F fit measured in the same run; then the share of
"does not fit" verdicts on ``--records`` seeded records whose model is true (fitted by
ML_i-F, so the nominal rate is an upper bound: ALPHA), and on records with a flicker
floor (equal-variance Gauss-Markov terms, two per decade of correlation time, 1 s to
3000 s) fitted with wn+gm.

    python benchmarks/bench_adequacy.py [--records 100] [--hours 2] [--fs 100]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import COUNT_SCALE, best_of, table_iii_record

from imustation.analysis.estimators.classical.allan import oadev
from imustation.analysis.estimators.ml.composite import fit_composite
from imustation.analysis.estimators.models.noise_models import GaussMarkov, NoiseModel, WhiteRate, standard
from imustation.analysis.estimators.selection.adequacy import ALPHA, NO_FIT, model_adequacy
from imustation.analysis.estimators.selection.screen import screen


def flicker(sigma_w: float, level: float, t_lo: float = 1.0, t_hi: float = 3000.0) -> NoiseModel:
    """White noise plus an Allan floor of about ``level`` between t_lo and t_hi (s)."""
    taus = np.logspace(np.log10(t_lo), np.log10(t_hi), int(round(2 * np.log10(t_hi / t_lo))) + 1)
    unit = NoiseModel(tuple(GaussMarkov(np.sqrt(2.0 / t), t) for t in taus))
    floor = np.sqrt(unit.avar(np.logspace(np.log10(3 * t_lo), np.log10(t_hi / 3), 20))).mean()
    k = level / floor
    return NoiseModel((WhiteRate(sigma_w),) + tuple(GaussMarkov(k * np.sqrt(2.0 / t), t) for t in taus))


def verdicts(model: NoiseModel, n: int, fs: float, seeds: range) -> tuple[list[str], list[float]]:
    out, times = [], []
    for s in seeds:
        x = model.simulate(n, fs, seed=s)
        allan = oadev(x, fs)
        fit = fit_composite(x, fs)
        t0 = time.perf_counter()
        out.append(model_adequacy(allan, fit.noise_model, fs, [n], n_fitted=3).verdict)
        times.append(time.perf_counter() - t0)
    return out, times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", type=int, default=100, help="records per rate measurement")
    ap.add_argument("--hours", type=float, default=2.0, help="length of those records")
    ap.add_argument("--fs", type=float, default=100.0, help="their sampling rate, Hz")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    fs = 400.0
    n, x, counts = table_iii_record(12.0, fs)
    allan = oadev(counts, fs, scale=COUNT_SCALE)
    t_fit, fit = best_of(lambda: fit_composite(counts, fs, scale=COUNT_SCALE), 1)
    t_adq, adq = best_of(lambda: model_adequacy(allan, fit.noise_model, fs, [n], n_fitted=3), args.repeat)
    t_scr, _ = best_of(lambda: screen(counts, scale=COUNT_SCALE), args.repeat)
    print(f"12 h at {fs:g} Hz ({n} int16 samples), {len(allan.tau)} taus, {adq.tested.sum()} in the statistic:")
    print(f"  adequacy {t_adq * 1e3:.1f} ms, screen {t_scr * 1e3:.1f} ms, ML_i-F fit {t_fit * 1e3:.0f} ms")
    print(f"  ratios to the fit: adequacy {t_adq / t_fit:.3f}, screen {t_scr / t_fit:.3f}; verdict: {adq.summary()}")

    m = int(args.hours * 3600 * args.fs)
    truth = standard(1.05e-4, 1.26e-6, 530.5)
    v, times = verdicts(truth, m, args.fs, range(1000, 1000 + args.records))
    k = sum(x == NO_FIT for x in v)
    sd = np.sqrt(ALPHA * (1 - ALPHA) / len(v))
    print(
        f"true wn+gm, {args.records} x {args.hours:g} h at {args.fs:g} Hz: does not fit {k}/{len(v)} "
        f"= {k / len(v):.1%} (nominal <= {ALPHA:.0%} +- {sd:.1%}); adequacy {np.median(times) * 1e3:.1f} ms each"
    )
    for level in (2e-5, 3e-5):
        v, _ = verdicts(flicker(1.05e-4, level), m, args.fs, range(500, 500 + max(10, args.records // 5)))
        k = sum(x == NO_FIT for x in v)
        print(f"flicker floor {level:g} rad/s fitted with wn+gm: does not fit {k}/{len(v)} = {k / len(v):.0%}")


if __name__ == "__main__":
    main()
