"""Repeated recordings of one device: do the stated 90 % intervals hold? (issue 22, "Intervals").

Simulates ``--repeats`` recordings of each filtered device with the chip's own filter chain,
bias instability B and a weak rate random walk K (``tests/realistic_records.py``), runs the
automatic model choice on each and prints, per device: the models chosen, how often the
90 % intervals of N (against the output's white-noise density) and B cover the truth, the
run-to-run scatter of N against its stated standard error, and the same for the paper's
``wn+gm`` fit. Not a speed benchmark: the figures are coverage counts.

    python benchmarks/repeat_coverage.py [--hours 12] [--repeats 8] [--devices bmx055,mpu9150,adis16448]
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from imustation.analysis.estimators.engine.fitting import Z90  # noqa: E402
from imustation.analysis.estimators.selection.coefficients import ieee952_summary  # noqa: E402
from imustation.analysis.estimators.selection.model_choice import choose_model  # noqa: E402
from tests.realistic_records import low_frequency_gain, record  # noqa: E402

SIGMA_W = 2.44e-4  # 0.014 deg/s/sqrt(Hz), rad/s/sqrt(Hz)
B_TRUE = 1.5e-5  # rad/s
K_TRUE = 2e-7  # rad/s^2/sqrt(Hz)


def one_device(device: str, hours: float, repeats: int, seed0: int) -> dict:
    n_true = SIGMA_W * math.sqrt(low_frequency_gain(device))
    rows = []
    for seed in range(seed0, seed0 + repeats):
        x, fs = record(device, hours, SIGMA_W, B=B_TRUE, K=K_TRUE, seed=seed)
        choice = choose_model(x, fs)
        s = ieee952_summary(choice.chosen, len(x) / fs, choice.close)
        p = choice.paper
        rows.append((choice.chosen.model, s["N"], *s["N_ci90"], *s["B_ci90"], p.sigma_w, *p.ci90["sigma_w"]))
    models = Counter(r[0] for r in rows)
    a = np.array([r[1:] for r in rows], dtype=float)
    n_est, n_lo, n_hi, b_lo, b_hi, p_est, p_lo, p_hi = a.T
    se = np.log(n_hi / n_lo) / (2 * Z90)
    return {
        "device": device,
        "models": ", ".join(f"{m} x{c}" for m, c in models.most_common()),
        "N covered": f"{int(np.sum((n_lo <= n_true) & (n_true <= n_hi)))}/{repeats}",
        "N scatter/se": f"{100 * np.std(np.log(n_est), ddof=1):.2f} % / {100 * np.median(se):.2f} %",
        "N bias": f"{100 * (np.mean(n_est) / n_true - 1):+.2f} %",
        "B covered": f"{int(np.sum((b_lo <= B_TRUE) & (B_TRUE <= b_hi)))}/{repeats}",
        "paper N covered": f"{int(np.sum((p_lo <= n_true) & (n_true <= p_hi)))}/{repeats}",
        "paper N bias": f"{100 * (np.mean(p_est) / n_true - 1):+.2f} %",
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--repeats", type=int, default=8)
    ap.add_argument("--seed", type=int, default=300)
    ap.add_argument("--devices", default="bmx055,mpu9150,adis16448")
    args = ap.parse_args()
    print(f"{args.repeats} recordings of {args.hours:g} h per device; B {B_TRUE:g} rad/s, K {K_TRUE:g} rad/s^2/rtHz")
    for device in args.devices.split(","):
        row = one_device(device, args.hours, args.repeats, args.seed)
        print("  " + "; ".join(f"{k}: {v}" for k, v in row.items()), flush=True)


if __name__ == "__main__":
    main()
