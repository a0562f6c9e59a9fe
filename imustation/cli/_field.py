"""Field recordings on the command line: the options ``import`` and ``analyze`` share, the import
summary they print, and ``analyze``'s glue from the importer's stream to analysis channels.

The analysis layer imports nothing from acquisition; here the recording streamed by
:func:`imustation.acquisition.importers.stream_recording` is handed to
:func:`imustation.analysis.pipeline.loaders.recording_channels`, which makes the channels the
imported run file would give.
"""

from __future__ import annotations

import contextlib
import fnmatch
import os
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

import click

from imustation.units import TIME_UNITS

if TYPE_CHECKING:
    from imustation.analysis.pipeline.loaders import Channel
    from imustation.analysis.pipeline.parallel import ChannelTask, TaskFailure

#: the device an imported text log becomes (docs/import.md: "one device imu for logs")
LOG_DEVICE = "imu"


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
            click.option(
                "--gyro-columns", default=None, metavar="A,B,C", help="Text logs: gyro columns (one to three, x,y,z)."
            ),
            click.option(
                "--accel-columns", default=None, metavar="A,B,C", help="Text logs: accel columns (one to three)."
            ),
            click.option(
                "--time-unit",
                type=click.Choice(list(TIME_UNITS)),
                default=None,
                help="Unit of the time column of text logs / .npy (default: from the header or the step size).",
            ),  # fmt: skip
            click.option(
                "--gyro-unit",
                default=None,
                metavar="UNIT",
                help="Text logs: unit of the gyro columns: rad/s, deg/s, mrad/s, mdeg/s or deg/h (default: "
                "from the column names or a header comment; a log stating none is refused).",
            ),  # fmt: skip
            click.option(
                "--accel-unit",
                default=None,
                metavar="UNIT",
                help="Text logs: unit of the accel columns: m/s^2, g or mg (default: from the column names or a header "
                "comment, as for the gyro - never taken from --gyro-unit; a log stating none is refused).",
            ),  # fmt: skip
        ]
    ):
        f = opt(f)
    return f


def text_options(time_column, gyro_columns, accel_columns, gyro_unit, accel_unit=None) -> dict:
    return {"time_col": time_column, "gyro_cols": gyro_columns, "accel_cols": accel_columns, "gyro_unit": gyro_unit,
            "accel_unit": accel_unit}  # fmt: skip


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
        # a text log's device is described by its column mapping, printed just above: not twice
        src = res.devices[name]
        click.echo(f"{source}: {name if src == res.mapping else f'{src} -> {name}'}: {rep.summary()}", err=True)
    for note in res.notes:
        click.echo(f"{source}: {note}", err=True)


def is_field(path: str, rate_hz: float | None) -> bool:
    """An input ``analyze`` reads through the importer: a bag, bag folder, .mcap, .tsv or other log, and a
    .csv/.txt log when ``--rate`` is not given (with it, plain rate columns)."""
    from imustation.acquisition.importers import is_field_input

    timed_csv = rate_hz is None and os.path.splitext(path)[1].lower() in (".csv", ".txt")
    return os.path.exists(path) and (is_field_input(path) or timed_csv)


def plan_inputs(
    inputs: Sequence[str], globs: Sequence[str], rate_hz: float | None, *, quiet: bool, topic, time_unit, text: dict
) -> tuple[list[ChannelTask], list[TaskFailure]]:
    """One analysis task per selected channel of ``inputs``, in input order.

    Field recordings are streamed into memory (:func:`streamed_channels`; no run file is
    written) and their tasks carry the channel; every other input is planned by
    :func:`~imustation.analysis.pipeline.parallel.plan_tasks` (each task reads its own channel
    from the file). Recordings are streamed first so that their import summaries print before
    any analysis output. :class:`NoChannelsError` when no input has a channel.
    """
    from imustation.analysis.pipeline.loaders import NoChannelsError
    from imustation.analysis.pipeline.parallel import plan_tasks, tasks_of_channels
    from imustation.runfile import join_parts

    inputs = join_parts(inputs)  # the parts of a rotated capture are one input
    field = {k: streamed_channels(p, globs, quiet=quiet, topic=topic, time_unit=time_unit, text=text)
             for k, p in enumerate(inputs) if is_field(p, rate_hz)}  # fmt: skip
    tasks: list[ChannelTask] = []
    failures: list[TaskFailure] = []
    for k, path in enumerate(inputs):
        if k in field:
            tasks += tasks_of_channels(field[k])
            continue
        try:
            planned, failed = plan_tasks([path], globs, rate_hz)
        except NoChannelsError:
            continue  # as in plan_tasks: an error only when no input has a channel
        tasks += planned
        failures += failed
    if not tasks and not failures:
        sel = f" matching {', '.join(globs)}" if globs else ""
        raise NoChannelsError(f"no channels{sel} in {', '.join(inputs)}")
    return tasks, failures


def streamed_channels(path: str, globs: Sequence[str], *, quiet: bool, topic, time_unit, text: dict) -> list[Channel]:
    """The rate channels of a field recording, streamed into memory with a progress bar and the
    import summary on stderr (no run file is written); the channels are
    :func:`~imustation.analysis.pipeline.loaders.recording_channels`'."""
    from imustation.acquisition.importers import stream_recording
    from imustation.analysis.pipeline.loaders import recording_channels

    if (
        globs
        and not text.get("accel_cols")
        and not any(fnmatch.fnmatchcase(f"{LOG_DEVICE}/accel/{a}", g) for g in globs for a in "xyz")
    ):  # a log's accel is read (and its unit required) only when an accel channel is selected
        text = {**text, "accel": False}
    with progress_bar(f"importing {os.path.basename(path.rstrip('/'))}", quiet) as progress:
        rec = stream_recording(path, topic=topic, text=text, time_unit=time_unit, progress=progress)
    if not quiet:
        print_summary(path, rec.result)
    return recording_channels(rec.devices, path, globs)
