"""``imustation capture``: record every device of a config into a run file."""

from __future__ import annotations

import json
import math
import sys

import click

from imustation.acquisition import capture as run_capture
from imustation.acquisition import load_config
from imustation.cli import cli
from imustation.units import format_duration, parse_duration


def format_status(status: dict) -> str:
    parts = [f"{format_duration(status['elapsed_s'])}/{format_duration(status['duration_s'])}"]
    for name, d in status["devices"].items():
        temp = f" {d['temp_c']:.1f}C" if math.isfinite(d["temp_c"]) else ""
        parts.append(f"{name}: {d['samples']} @ {d['rate_hz']:.1f}/{d['rate_cfg_hz']:g} Hz gaps {d['gaps']}{temp}")
    return " | ".join(parts)


@cli.command()
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("-o", "--output", default="run.h5", show_default=True, help="Run file to create (HDF5).")
@click.option("--duration", default="12h", show_default=True, help="How long to record: 12h, 90m, 1h30m, 45s.")
@click.option("--simulate", is_flag=True, help="Replace every bus and chip by its simulator (virtual clock).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.option("--quiet", is_flag=True, help="No live status line.")
@click.option("--json-status", is_flag=True, help="Print the status as one JSON line per second (for CI/logs).")
def capture(
    config: str, output: str, duration: str, simulate: bool, overwrite: bool, quiet: bool, json_status: bool
) -> None:
    """Record every device of CONFIG into a run file (format v1).

    Data are flushed to disk at least every flush_interval_s of the config;
    Ctrl-C or SIGTERM stops the capture cleanly and finishes the file.
    """
    cfg = load_config(config)
    seconds = parse_duration(duration)
    tty = sys.stderr.isatty()

    def on_status(status: dict) -> None:
        if json_status:
            click.echo(json.dumps(status))
        elif not quiet:
            click.echo(("\r" if tty else "") + format_status(status), err=True, nl=not tty)

    summary = run_capture(cfg, output, seconds, simulate=simulate, overwrite=overwrite, on_status=on_status)
    if tty and not quiet and not json_status:
        click.echo("", err=True)
    total = sum(summary.samples.values())
    speed = summary.duration_s / summary.wall_s if summary.wall_s > 0 else float("inf")
    note = " (stopped early)" if summary.stopped_early else ""
    click.echo(
        f"wrote {output}: {total} samples from {len(summary.samples)} device(s), "
        f"{format_duration(summary.duration_s)} in {summary.wall_s:.1f} s wall ({speed:.0f}x real time){note}"
    )
