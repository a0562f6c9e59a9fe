"""Field recordings on the command line: the options ``import`` and ``analyze`` share and the import summary."""

from __future__ import annotations

import contextlib
import os
import sys

import click

from imustation.analysis.choices import TIME_UNITS


@contextlib.contextmanager
def progress_bar(label: str, quiet: bool):
    """A ``progress(done, total)`` callback drawing click.progressbar on stderr (none when quiet / not a tty)."""
    if quiet or not sys.stderr.isatty():
        yield None
        return
    state: dict = {}
    with click.progressbar(length=1, label=label, file=sys.stderr) as bar:

        def progress(done: int, total: int) -> None:
            bar.length = max(total, 1)
            bar.update(done - state.get("done", 0))
            state["done"] = done

        yield progress


def field_options(f):
    """Options shared by ``import`` and ``analyze`` for field recordings."""
    for opt in reversed(
        [
            click.option("--topic", default=None, help="Imu topic of a bag (default: every sensor_msgs/Imu topic)."),
            click.option(
                "--time-column", default=None, metavar="COL", help="Text logs: time column (name or 0-based index)."
            ),
            click.option("--gyro-columns", default=None, metavar="A,B,C", help="Text logs: gyro x,y,z columns."),
            click.option("--accel-columns", default=None, metavar="A,B,C", help="Text logs: accel x,y,z columns."),
            click.option(
                "--time-unit",
                type=click.Choice(list(TIME_UNITS)),
                default=None,
                help="Unit of the time column of text logs / .npy (default: from the header or the step size).",
            ),  # fmt: skip
            click.option(
                "--gyro-unit",
                type=click.Choice(["rad/s", "deg/s"]),
                default="rad/s",
                show_default=True,
                help="Text logs: unit of the gyro columns.",
            ),  # fmt: skip
        ]
    ):
        f = opt(f)
    return f


def text_options(time_column, gyro_columns, accel_columns, gyro_unit) -> dict:
    return {"time_col": time_column, "gyro_cols": gyro_columns, "accel_cols": accel_columns, "gyro_unit": gyro_unit}


def run_import(source: str, out: str, *, quiet: bool, overwrite: bool, topic, time_unit, text: dict):
    """Import with a progress bar; prints the mapping and the stamp summary on stderr."""
    from imustation.acquisition.importers import import_recording

    with progress_bar(f"importing {os.path.basename(source.rstrip('/'))}", quiet) as progress:
        res = import_recording(
            source, out, topic=topic, text=text, time_unit=time_unit, overwrite=overwrite, progress=progress
        )
    if not quiet:
        print_summary(source, res)
    return res


def print_summary(source: str, res) -> None:
    """The column mapping, each device's stamp summary and the reader's notes of an import, on stderr."""
    if res.mapping:
        click.echo(f"{source}: columns: {res.mapping}", err=True)
    for name, rep in res.reports.items():
        click.echo(f"{source}: {res.devices[name]} -> {name}: {rep.summary()}", err=True)
    for note in res.notes:
        click.echo(f"{source}: {note}", err=True)
