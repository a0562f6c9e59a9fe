"""``imustation report``: noise tables, figures and one HTML page per run."""

from __future__ import annotations

import click

from imustation.analysis.pipeline import choices
from imustation.cli import cli


@cli.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out_dir", required=True, help="Directory for the report (one folder per run).")
@click.option("--overwrite", is_flag=True, help="Replace the report of a run already in the directory.")
@click.option(
    "--channel", "globs", multiple=True, metavar="GLOB", help="Channels to report (default: gyro/accel axes)."
)
@click.option("--model", default=choices.DEFAULT_MODEL, show_default=True, help=choices.MODEL_HELP)
@click.option("--warmup", default=choices.DEFAULT_WARMUP, show_default=True, help=choices.WARMUP_HELP)
def report(
    runs: tuple[str, ...], out_dir: str, overwrite: bool, globs: tuple[str, ...], model: str, warmup: str
) -> None:
    """Noise tables (CSV, Markdown, LaTeX), Allan/PSD/temperature figures (PNG, PDF) and an HTML page per run.

    Writes OUTPUT/<run name>/index.html with relative links to its tables and
    figures (self-contained folder, no network), plus OUTPUT/noise.* over all runs.
    A rotated capture is one run: its base name (week.h5) or all its parts.
    """
    from imustation.analysis.reports.runreport import report_runs
    from imustation.runfile import join_parts

    report_runs(
        join_parts(runs),  # a rotated capture's parts: one run
        out_dir,
        globs=globs,
        model=model,
        warmup=warmup,
        progress=lambda line: click.echo(line, err=True),
        on_report=lambda rep: click.echo(rep.summary()),
        overwrite=overwrite,
    )
