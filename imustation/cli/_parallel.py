"""Options and progress display shared by ``analyze`` and ``fleet`` for parallel analysis (dask.distributed)."""

from __future__ import annotations

import contextlib
import sys
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
    """:func:`~imustation.analysis.pipeline.parallel.execute` with the dashboard link, a progress bar
    (unless ``bar`` is False) and each failure on stderr; a single task shows neither bar nor
    failure line (its failure becomes the command's one error line)."""
    from imustation.analysis.pipeline.parallel import execute

    several = len(tasks) > 1
    with contextlib.ExitStack() as stack:
        shown = []

        def on_start(client) -> None:
            if client is not None:
                click.echo(f"dask dashboard: {client.dashboard_link}", err=True)
            if several and bar:
                shown.append(
                    stack.enter_context(
                        click.progressbar(length=len(tasks), label=label, file=sys.stderr, show_pos=True)
                    )
                )

        def on_done(done: int, total: int, fail: TaskFailure | None) -> None:
            for progress in shown:
                progress.update(1)
            if fail is not None and several:
                click.echo(f"\n{failure_line(fail)}", err=True)

        return execute(
            tasks,
            options,
            workers=workers,
            scheduler=scheduler,
            memory_limit=memory_limit,
            on_start=on_start,
            on_done=on_done,
        )


def failure_line(f: TaskFailure) -> str:
    """``failed: <error>``, or for a degenerate channel ``skipped <channel>: <reason>`` (its error says so)."""
    return f.error if f.skipped else f"failed: {f.error}"


def report_failures(failures: Sequence[TaskFailure]) -> None:
    """One stderr line per failed run or skipped channel."""
    for f in failures:
        click.echo(failure_line(f), err=True)
