"""Repeated recordings of one device: do the stated 90 % intervals hold? (issue 22, "Intervals").

Simulates ``--repeats`` recordings of each filtered device with the chip's own filter chain,
bias instability B and a weak rate random walk K (``tests/realistic_records.py``), runs the
automatic model choice on each and prints, per device: the models chosen, how often the
90 % intervals of N (against the output's white-noise density) and B cover the truth, the
run-to-run scatter of N against its stated standard error, and the same for the paper's
``wn+gm`` fit. Not a speed benchmark: the figures are coverage counts.

    python benchmarks/repeat_coverage.py [--hours 12] [--repeats 8] [--devices bmx055,mpu9150,adis16448]

``--adis16405``: one device, six answers (issue 32). Six repeats of one ADIS16405-style gyro axis
(the Bartlett chain of the ADIS16448 at 409.6 Hz, 2.8 h as the issue's recordings; white noise
0.05 deg/s/sqrt(Hz) and in-run bias stability 0.007 deg/s of the ADIS16400/16405 datasheet,
Table 1, as flicker, with a walk that rises above the floor only near the record's end, so that
a Gauss-Markov bias and flicker + walk fit nearly as well), each through ``analyze_channel`` as
``imustation analyze`` runs it. Printed per repeat: the chosen model, the "enough data?"
verdict, N, B, K with their intervals; then how many verdicts agree, the share of the tau >= 0.1 s
where the model's Allan deviation lies inside the measured one's 90 % chi-square interval (median,
min over the repeats), and for N, B, K how many pairs of repeats have intervals that overlap and
how many intervals hold the truth.

    python benchmarks/repeat_coverage.py --adis16405 [--hours 2.8] [--repeats 6]
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


ADIS_SIGMA_W = 0.05 * math.pi / 180.0  # ADIS16400/16405 datasheet, Table 1: rate noise density 0.05 deg/s/sqrt(Hz)
ADIS_B = 0.007 * math.pi / 180.0 / 0.6643  # in-run bias stability 0.007 deg/s: the Allan floor 0.664 B
ADIS_K = 3e-6  # rad/s^2/sqrt(Hz): K^2 tau / 3 reaches the floor at ~5000 s, near the 2.8 h record's end


#: the second bias: a Gauss-Markov term (stationary sigma rad/s, time constant s) that acts as a walk over most
#: of the record, beside a weaker flicker -- Gauss-Markov and flicker + walk then fit nearly as well
ADIS_GM = (2.0e-4, 1500.0)
#: bias variants of the study: (name, B rad/s, K rad/s^2/sqrt(Hz), Gauss-Markov (sigma, T) or None)
ADIS_BIASES = {"flicker+walk": (ADIS_B, ADIS_K, None), "flicker+gm": (0.5 * ADIS_B, 0.0, ADIS_GM)}


def _gauss_markov(n: int, fs: float, sigma: float, T: float, seed: int) -> np.ndarray:
    """``n`` samples of a stationary first-order Gauss-Markov rate (exact AR(1))."""
    from scipy.signal import lfilter

    rng = np.random.default_rng([seed, 16405])
    phi = math.exp(-1.0 / (fs * T))
    e = rng.normal(0.0, sigma * math.sqrt(1.0 - phi * phi), n)
    return lfilter([1.0], [1.0, -phi], e, zi=[phi * rng.normal(0.0, sigma)])[0]


def _adis_repeat(job: tuple[float, int, str]) -> dict:
    """One repeat of the ADIS16405-style study: the analysis as ``analyze`` runs it, and what it says."""
    from imustation.analysis.estimators.classical.allan import chi2_bounds
    from imustation.analysis.pipeline.channel import analyze_channel
    from imustation.analysis.pipeline.loaders import Channel

    hours, seed, bias = job
    b, k, gm = ADIS_BIASES[bias]
    x, fs = record("adis16448", hours, ADIS_SIGMA_W, B=b, K=k, seed=seed)
    if gm is not None:
        x = x + _gauss_markov(len(x), fs, *gm, seed)
    meta = {"device": "adis16448", "driver": "adis16448", "settings": {"decimation": 2, "filter_taps": 4}}
    res = analyze_channel(Channel("adis16405/gyro/x", fs, "rad/s", x, 1.0, source="repeat_coverage", meta=meta))
    s = res.ieee952(res.noise_model)
    a = res.allan
    lo, hi = chi2_bounds(a.adev, a.edf, 0.90)
    keep = (a.tau >= 0.1) & np.isfinite(lo) & np.isfinite(hi)
    model = res.noise_model.noise_model.adev(a.tau[keep], fs)
    inside = float(np.mean((lo[keep] <= model) & (model <= hi[keep])))
    return {
        "model": res.noise_model.model,
        "fits": bool(res.choice.fits),
        "verdict": res.verdict.verdict,
        "problems": list(res.verdict.problems),
        "inside": inside,
        "indistinct": res.choice.indistinct() is not None,
        **{q: (s.get(q), s.get(f"{q}_ci90"), s.get(f"{q}_upper90"), s.get(f"{q}_detected", True)) for q in "NBK"},
    }


def _interval(v: tuple) -> tuple[float, float] | None:
    """The stated 90 % range of N, B or K: its interval, or [0, bound] where it is not detected."""
    value, ci, upper, detected = v
    if detected is False and upper is not None:
        return (0.0, float(upper)) if not ci or ci[0] is None else (0.0, max(float(upper), float(ci[1])))
    if ci and ci[0] is not None and ci[1] is not None:
        return (float(ci[0]), float(ci[1]))
    return None


def adis16405_study(hours: float, repeats: int, seed0: int, workers: int, bias: str) -> None:
    """One device, six answers (module docstring): print per repeat and the agreement across repeats. For
    the ``flicker+gm`` bias K's truth is the Gauss-Markov term's walk over times short against its T
    (``sigma sqrt(2 / T)``), B's the flicker's."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers) as pool:
        rows = list(pool.map(_adis_repeat, [(hours, seed0 + i, bias) for i in range(repeats)]))
    b, k, gm = ADIS_BIASES[bias]
    k = k or (gm[0] * math.sqrt(2.0 / gm[1]) if gm else 0.0)
    truth = {"N": ADIS_SIGMA_W * math.sqrt(low_frequency_gain("adis16448")), "B": b, "K": k}
    print(f"{repeats} repeats of {hours:g} h, ADIS16405-style, {bias} (N {truth['N']:.3g}, B {b:.3g}, K {k:.3g})")
    for i, r in enumerate(rows):
        nbk = "; ".join(
            f"{q} {r[q][0] / truth[q] if r[q][0] else math.nan:.3f} "
            + (f"[{iv[0] / truth[q]:.3f}, {iv[1] / truth[q]:.3f}]" if (iv := _interval(r[q])) else "none")
            for q in "NBK"
        )
        print(
            f"  seed {seed0 + i}: {r['model']:14s} fits {'y' if r['fits'] else 'n'} {r['verdict']:10s} "
            f"model ADEV inside 90 % {100 * r['inside']:3.0f} %  (/truth) {nbk}"
            + ("  indistinct" if r["indistinct"] else "")
        )
        for p in r["problems"]:
            print(f"      {p}")
    verdicts = Counter(r["verdict"] for r in rows)
    inside = sorted(r["inside"] for r in rows)
    print(f"verdicts: {', '.join(f'{v} x{c}' for v, c in verdicts.most_common())}")
    print(f"models: {', '.join(f'{m} x{c}' for m, c in Counter(r['model'] for r in rows).most_common())}")
    print(f"model ADEV inside the measured 90 % interval, tau >= 0.1 s: median {100 * inside[len(inside) // 2]:.0f} %, "
          f"min {100 * inside[0]:.0f} %")  # fmt: skip
    for q in "NBK":
        ivs = [_interval(r[q]) for r in rows]
        pairs = [(a, b) for i, a in enumerate(ivs) for b in ivs[i + 1 :] if a and b]
        overlap = sum(a[0] <= b[1] and b[0] <= a[1] for a, b in pairs)
        held = sum(iv is not None and iv[0] <= truth[q] <= iv[1] for iv in ivs)
        print(
            f"{q}: intervals of two repeats overlap in {overlap} of {len(pairs)} pairs; "
            f"hold the truth {held} of {len(ivs)}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--repeats", type=int, default=8)
    ap.add_argument("--seed", type=int, default=300)
    ap.add_argument("--devices", default="bmx055,mpu9150,adis16448")
    ap.add_argument("--adis16405", action="store_true", help="the one-device-six-answers study (issue 32)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--bias", default="flicker+walk,flicker+gm", help="--adis16405: the bias variants to run")
    args = ap.parse_args()
    if args.adis16405:
        hours = args.hours if "--hours" in sys.argv else 2.8
        repeats = args.repeats if "--repeats" in sys.argv else 6
        for bias in args.bias.split(","):
            adis16405_study(hours, repeats, args.seed, args.workers, bias)
        return
    print(f"{args.repeats} recordings of {args.hours:g} h per device; B {B_TRUE:g} rad/s, K {K_TRUE:g} rad/s^2/rtHz")
    for device in args.devices.split(","):
        row = one_device(device, args.hours, args.repeats, args.seed)
        print("  " + "; ".join(f"{k}: {v}" for k, v in row.items()), flush=True)


if __name__ == "__main__":
    main()
