"""``imustation import``: field recordings (ROS bags, MCAP, text logs, .npy) -> run file v1."""

from __future__ import annotations

import click

from imustation.cli import cli
from imustation.cli._field import field_options, run_import, text_options
from imustation.outputs import check_file


@cli.command("import")
@click.argument("source", type=click.Path(exists=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="Run file to write (.h5).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.option("--quiet", is_flag=True, help="No progress bar or summary.")
@field_options
def import_(
    source, out, overwrite, quiet, topic, time_column, gyro_columns, accel_columns, time_unit, gyro_unit, accel_unit
):
    """Convert a field recording SOURCE into a run file (format v1).

    SOURCE: ROS 1 .bag, ROS 2 bag folder, .mcap, CSV/TSV/whitespace text log with a
    time column, or an (n, 4|7) .npy array (time, gyro[, accel]). Timestamps are
    checked (order, duplicates, gaps, jitter, true rate), kept in file order, and
    their problems logged as events. See docs/import.md.
    """
    check_file(out, overwrite=overwrite)
    res = run_import(
        source, out, quiet=quiet, overwrite=overwrite, topic=topic, time_unit=time_unit,
        text=text_options(time_column, gyro_columns, accel_columns, gyro_unit, accel_unit),
    )  # fmt: skip
    parts = [f"{n} ({r.n} samples)" for n, r in res.reports.items()]
    parts += [f"thermometer {n} ({k} readings)" for n, (_topic, k) in res.thermometers.items()]
    click.echo(f"wrote {res.path}: {', '.join(parts)}")
