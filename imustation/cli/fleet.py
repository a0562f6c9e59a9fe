"""``imustation fleet``: one noise table over many runs and devices, repeatability, outliers."""

from __future__ import annotations

import click

from imustation.analysis.pipeline import choices
from imustation.cli import cli
from imustation.cli._parallel import cluster_options, report_failures, run_with_progress


@cli.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path())
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False), help="Output directory.")
@click.option("--overwrite", is_flag=True, help="Replace a fleet report already in the directory.")
@click.option(
    "--channel", "globs", multiple=True, metavar="GLOB", help="Channels to include (default: every gyro/accel axis)."
)
@click.option("--model", default=choices.DEFAULT_MODEL, show_default=True, help=choices.MODEL_HELP)
@click.option("--warmup", default=choices.DEFAULT_WARMUP, show_default=True, help=choices.WARMUP_HELP)
@cluster_options
def fleet(
    runs: tuple[str, ...],
    out_dir: str,
    overwrite: bool,
    globs: tuple[str, ...],
    model: str,
    warmup: str,
    workers: int | None,
    scheduler: str | None,
    memory_limit: str,
) -> None:
    """One noise table over every run and device of RUNS (run files), with repeatability and outliers.

    \b
    Writes OUTPUT/fleet.csv, fleet.md, fleet.json, fleet.html (self-contained)
    and fleet_allan.png: per run and axis the device identity, the noise
    model's sigma_w, sigma_b, tau_b and the IEEE-952 N, B, K it implies (the
    numbers analyze and report give) with 90 % intervals, "< x" for a term
    a run does not show; per device and axis the mean and std over its runs
    (Table III) and the run-to-run scatter beside the runs' own intervals;
    runs flagged against the fleet (robust z > 3.5, each run with its own
    interval, comparable models only; too-short runs listed and left
    out). Channels are analysed
    in parallel with --workers N or --scheduler ADDR (docs/fleet.md). A run
    that fails is reported and listed; the exit status is 2 only when every
    run failed.
    """
    from imustation.analysis.pipeline.parallel import AnalysisOptions, plan_tasks
    from imustation.analysis.pipeline.warmup import check_warmup
    from imustation.analysis.reports.fleetreport import FLEET_FILES, write_fleet_report
    from imustation.outputs import check_folder
    from imustation.runfile import join_parts

    check_warmup(warmup)  # a bad value fails before anything is analysed
    check_folder(out_dir, overwrite=overwrite, writes=FLEET_FILES)
    runs = tuple(join_parts(runs))  # a rotated capture's parts: one run
    tasks, failures = plan_tasks(runs, globs)
    report_failures(failures)
    results, failed = run_with_progress(
        tasks,
        AnalysisOptions(model=model, warmup=warmup),
        workers=workers,
        scheduler=scheduler,
        memory_limit=memory_limit,
    )
    rep = write_fleet_report(runs, results, failures + failed, out_dir)
    for line in rep.outlier_lines() + rep.scatter_lines() + rep.left_out_lines():
        click.echo(line, err=True)
    click.echo(rep.summary_line())
