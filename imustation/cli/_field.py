"""Field recordings on the command line: the options ``import`` and ``analyze`` share, the import
summary they print, and ``analyze``'s glue from the importer's stream to analysis channels.

The analysis layer imports nothing from acquisition; here the recording streamed by
:func:`imustation.acquisition.importers.stream_recording` becomes
:class:`imustation.analysis.pipeline.loaders.Channel` objects, the ones the imported run file would give.
"""

from __future__ import annotations

import contextlib
import fnmatch
import os
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

import click

from imustation.analysis.pipeline.choices import TIME_UNITS

if TYPE_CHECKING:
    from imustation.analysis.pipeline.loaders import Channel
    from imustation.analysis.pipeline.parallel import ChannelTask, TaskFailure


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
                help="Text logs: unit of the accel columns: m/s^2, g or mg (default: as --gyro-unit).",
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
        click.echo(f"{source}: {res.devices[name]} -> {name}: {rep.summary()}", err=True)
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
    """The rate channels of a field recording, streamed into memory: no run file is written.

    Equal to :func:`~imustation.analysis.pipeline.loaders.load_run`'s channels of the recording imported
    (ids, rates, units, samples, gap count, segments, metadata), except ``source``: the recording.
    """
    from imustation.acquisition.importers import stream_recording
    from imustation.analysis.pipeline.loaders import RATE_CHANNELS, Channel, record_breaks, segments_from_breaks

    with progress_bar(f"importing {os.path.basename(path.rstrip('/'))}", quiet) as progress:
        rec = stream_recording(path, topic=topic, text=text, time_unit=time_unit, progress=progress)
    if not quiet:
        print_summary(path, rec.result)
    out = []
    # devices and channels in the order a run file lists them (by name): the same table as the imported run's
    for name, dev in sorted(rec.devices.items()):
        spec = dev.spec
        breaks = [ev for ev in dev.events if ev.kind in ("gap", "overrun")]
        segments = None
        for ch in sorted(spec.channels, key=lambda c: c.name):
            if ch.name not in RATE_CHANNELS or not ch.axes:
                continue
            for j, axis in enumerate(ch.axes):
                cid = f"{name}/{ch.name}/{axis}"
                if globs and not any(fnmatch.fnmatchcase(cid, g) for g in globs):
                    continue
                if segments is None:
                    at = record_breaks(dev.t_ns, breaks, spec.rate_hz)
                    segments = segments_from_breaks(at, len(dev.t_ns))
                meta = {
                    "device": name,
                    "driver": spec.driver,
                    "model": spec.model,
                    "identity": spec.identity,
                    "station": "import",
                    "settings": {"rate_hz": spec.rate_hz, **spec.settings},
                }
                data = dev.columns[ch.name][j]
                out.append(Channel(cid, spec.rate_hz, ch.units, data, ch.scale, source=path, gaps=len(breaks),
                                   meta=meta, segments=list(segments)))  # fmt: skip
    return out
