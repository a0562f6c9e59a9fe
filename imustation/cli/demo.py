"""``imustation demo``: simulated capture -> analysis -> identified vs simulated."""

from __future__ import annotations

import csv
import os
import tempfile
import time

import click

from imustation.acquisition import capture as run_capture
from imustation.acquisition import load_config
from imustation.analysis.loaders import load_inputs
from imustation.analysis.pipeline import analyze_channel
from imustation.cli import cli
from imustation.configs import config_path
from imustation.drivers.sim import simulated_truth
from imustation.units import format_duration, parse_duration

#: virtual durations: the quick demo, and the full lab (its ADIS16448 simulator makes one USB
#: round trip per sample, ~20-30x real time, so 45 virtual minutes take about 2 minutes of capture)
QUICK_DURATION = "6h"
LAB_DURATION = "45m"
PARAMS = ("sigma_w", "sigma_b", "tau_b")
TABLE_FIELDS = ("channel", "param", "simulated", "identified", "ci90_lo", "ci90_hi", "error_pct")


@cli.command()
@click.option(
    "--duration",
    default=None,
    help=f"Virtual duration of the simulated capture [default: {QUICK_DURATION}; {LAB_DURATION} with --lab].",
)
@click.option("-o", "--output", default=None, help="Keep the run file here (default: a temporary file).")
@click.option("--config", "config_file", default=None, help="Config to simulate (default: the shipped demo.toml).")
@click.option(
    "--lab",
    is_flag=True,
    help="The full virtual lab: every device of the paper's lab (configs/demo-lab.toml), gyros and accelerometers.",
)
@click.option(
    "--table",
    "table_path",
    default=None,
    help="Write the simulated-vs-identified table as CSV here (--lab default: imustation-lab-demo.csv).",
)
def demo(duration: str | None, output: str | None, config_file: str | None, lab: bool, table_path: str | None) -> None:
    """Simulate a capture, analyse it, and compare identified with simulated parameters.

    The simulated chips draw their noise from the paper's Table IV parameters;
    the table shows how close ML_i gets to them. With --lab every device of the
    paper's lab is simulated, gyroscopes and accelerometers (the default 45
    virtual minutes took 1 min 56 s on a 2-core machine; a 12 h lab run would
    take hours because the simulated ADIS16448 makes one USB round trip per sample).
    """
    default_cfg = "demo-lab.toml" if lab else "demo.toml"
    cfg = load_config(config_file or config_path(default_cfg))
    seconds = parse_duration(duration or (LAB_DURATION if lab else QUICK_DURATION))
    if lab and table_path is None:
        table_path = "imustation-lab-demo.csv"
    globs = ["*/gyro/*", "*/accel/*"] if lab else ["*/gyro/*"]
    with tempfile.TemporaryDirectory() as tmp:
        path = output or os.path.join(tmp, "demo.h5")
        click.echo(f"simulating {format_duration(seconds)} of {len(cfg.devices)} device(s) -> {path}")
        summary = run_capture(cfg, path, seconds, simulate=True, overwrite=output is not None)
        click.echo(f"  {sum(summary.samples.values())} samples in {summary.wall_s:.1f} s wall")
        channels = load_inputs([path], globs)
        head = f"{'channel':<22} {'param':<8} {'simulated':>11} {'identified':>11} {'90% interval':>25} {'error':>8}"
        click.echo(head)
        click.echo("-" * len(head))
        truths = simulated_truth(cfg)
        rows = []
        t0 = time.perf_counter()
        for ch in channels:
            truth = truths.get(ch.id)
            if truth is None:
                continue  # replayed or unknown source: nothing to compare with
            res = analyze_channel(ch)
            ch.release()
            for name in PARAMS:
                sim_v, fit_v = getattr(truth, name), getattr(res.noise_model, name)
                lo, hi = res.noise_model.ci90[name]
                err = 100 * (fit_v / sim_v - 1)
                rows.append(dict(zip(TABLE_FIELDS, (ch.id, name, sim_v, fit_v, lo, hi, err), strict=True)))
                click.echo(
                    f"{ch.id:<22} {name:<8} {sim_v:>11.4g} {fit_v:>11.4g} {f'[{lo:.3g}, {hi:.3g}]':>25} {err:>7.1f}%"
                )
        click.echo(f"  analysed {len(channels)} channels in {time.perf_counter() - t0:.1f} s")
    if table_path:
        with open(table_path, "w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, fieldnames=TABLE_FIELDS)
            w.writeheader()
            w.writerows(rows)
        click.echo(f"wrote {table_path}")
