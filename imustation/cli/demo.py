"""``imustation demo``: simulated capture -> analysis -> identified vs simulated."""

from __future__ import annotations

import os
import tempfile

import click

from imustation.acquisition import capture as run_capture
from imustation.acquisition import load_config
from imustation.analysis.loaders import load_inputs
from imustation.analysis.pipeline import analyze_channel
from imustation.cli import cli
from imustation.configs import config_path
from imustation.drivers.sim import simulated_truth
from imustation.units import format_duration, parse_duration


@cli.command()
@click.option("--duration", default="6h", show_default=True, help="Virtual duration of the simulated capture.")
@click.option("-o", "--output", default=None, help="Keep the run file here (default: a temporary file).")
@click.option("--config", "config_file", default=None, help="Config to simulate (default: the shipped demo.toml).")
def demo(duration: str, output: str | None, config_file: str | None) -> None:
    """Simulate a capture, analyse it, and compare identified with simulated parameters.

    The simulated chips draw their noise from the paper's Table IV parameters;
    the table shows how close ML_i gets to them.
    """
    cfg = load_config(config_file or config_path("demo.toml"))
    seconds = parse_duration(duration)
    with tempfile.TemporaryDirectory() as tmp:
        path = output or os.path.join(tmp, "demo.h5")
        click.echo(f"simulating {format_duration(seconds)} of {len(cfg.devices)} device(s) -> {path}")
        summary = run_capture(cfg, path, seconds, simulate=True, overwrite=output is not None)
        click.echo(f"  {sum(summary.samples.values())} samples in {summary.wall_s:.1f} s wall")
        channels = load_inputs([path], ["*/gyro/*"])
        head = f"{'channel':<18} {'param':<8} {'simulated':>11} {'identified':>11} {'90% interval':>25} {'error':>8}"
        click.echo(head)
        click.echo("-" * len(head))
        truths = simulated_truth(cfg)
        for ch in channels:
            res = analyze_channel(ch)
            truth = truths.get(ch.id)
            if truth is None:
                continue  # replayed or unknown source: nothing to compare with
            for name in ("sigma_w", "sigma_b", "tau_b"):
                sim_v, fit_v = getattr(truth, name), getattr(res.mli, name)
                lo, hi = res.mli.ci90[name]
                click.echo(
                    f"{ch.id:<18} {name:<8} {sim_v:>11.4g} {fit_v:>11.4g} "
                    f"{f'[{lo:.3g}, {hi:.3g}]':>25} {100 * (fit_v / sim_v - 1):>7.1f}%"
                )
