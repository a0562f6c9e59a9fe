"""Options and progress display shared by ``analyze`` and ``fleet`` for parallel analysis (dask.distributed)."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import click

if TYPE_CHECKING:
    from imustation.analysis.pipeline.channel import ChannelAnalysis
    from imustation.analysis.pipeline.parallel import AnalysisOptions, ChannelTask, TaskFailure


def cluster_options(f):
    """``--workers N``, ``--scheduler ADDR`` and ``--memory-limit SIZE``."""
    f = click.option(
        "--memory-limit",
        default="auto",
        show_default=True,
        metavar="SIZE",
        help="Memory limit of each local worker, hence of each task (dask size, e.g. 2GiB; 'auto' = RAM / workers).",
    )(f)
    f = click.option(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:8786",
        help="Run the tasks on an existing dask.distributed cluster (workers must see the input paths).",
    )(f)
    f = click.option(
        "--workers",
        type=click.IntRange(1),
        default=None,
        metavar="N",
        help="Analyse channels in parallel on a local dask cluster of N single-threaded worker processes.",
    )(f)
    return f


def run_with_progress(
    tasks: Sequence[ChannelTask],
    options: AnalysisOptions,
    *,
    workers: int | None,
    scheduler: str | None,
    memory_limit: str = "auto",
    label: str = "analysing",
    bar: bool = True,
) -> tuple[list[ChannelAnalysis | None], list[TaskFailure]]:
    """:func:`~imustation.analysis.pipeline.parallel.execute` with the dashboard link, progress per
    channel on stderr (unless ``bar`` is False) and each failure on stderr; a single task shows
    neither progress nor failure line (its failure becomes the command's one error line).

    On a terminal the progress is a bar naming the last channel done; otherwise (a log, a pipe:
    a bar would print its label once and then nothing for minutes) one line per channel done,
    ``[3/31] mpu9150/gyro/x (12 s)``.
    """
    from imustation.analysis.pipeline.parallel import execute

    several = len(tasks) > 1
    paths = {t.path for t in tasks}
    tty = sys.stderr.isatty()
    with contextlib.ExitStack() as stack:
        shown = []
        count = [0]
        last = [time.monotonic()]

        def on_start(client) -> None:
            if client is not None:
                click.echo(f"dask dashboard: {client.dashboard_link}", err=True)
            if several and bar and tty:
                shown.append(
                    stack.enter_context(
                        click.progressbar(
                            length=len(tasks),
                            label=label,
                            file=sys.stderr,
                            show_pos=True,
                            item_show_func=lambda t: t.channel if t is not None else "",
                        )
                    )
                )
            elif several and bar:
                click.echo(f"{label} {len(tasks)} channels ...", err=True)

        def on_task(task) -> None:
            count[0] += 1
            now = time.monotonic()
            for progress in shown:
                progress.update(1, task)
            if several and bar and not tty:
                where = f"{os.path.basename(task.path)} " if len(paths) > 1 else ""
                click.echo(f"[{count[0]}/{len(tasks)}] {where}{task.channel} ({now - last[0]:.0f} s)", err=True)
            last[0] = now

        def on_done(done: int, total: int, fail: TaskFailure | None) -> None:
            if fail is not None and several:
                click.echo(f"\n{failure_line(fail)}" if shown else failure_line(fail), err=True)

        return execute(
            tasks,
            options,
            workers=workers,
            scheduler=scheduler,
            memory_limit=memory_limit,
            on_start=on_start,
            on_done=on_done,
            on_task=on_task,
        )


def failure_line(f: TaskFailure) -> str:
    """``failed: <error>``, or for a degenerate channel ``skipped <channel>: <reason>`` (its error says so)."""
    return f.error if f.skipped else f"failed: {f.error}"


def report_failures(failures: Sequence[TaskFailure]) -> None:
    """One stderr line per failed run or skipped channel."""
    for f in failures:
        click.echo(failure_line(f), err=True)
