"""Options and progress display shared by ``analyze`` and ``fleet`` for parallel analysis (dask.distributed)."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

import click

from imustation.errors import InputError

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


def execute(
    tasks: Sequence[ChannelTask],
    options: AnalysisOptions,
    *,
    workers: int | None,
    scheduler: str | None,
    memory_limit: str = "auto",
    label: str = "analysing",
) -> tuple[list[ChannelAnalysis | None], list[TaskFailure]]:
    """Run the tasks (serially, locally or on ``scheduler``) with a progress bar and failures on stderr."""
    from imustation.analysis.pipeline.parallel import dask_client, run_tasks

    if workers and scheduler:
        raise InputError("give --workers or --scheduler, not both")
    with dask_client(workers, scheduler, memory_limit=memory_limit) as client:
        if client is not None:
            click.echo(f"dask dashboard: {client.dashboard_link}", err=True)
        with click.progressbar(length=len(tasks), label=label, file=sys.stderr, show_pos=True) as bar:

            def on_done(done: int, total: int, fail: TaskFailure | None) -> None:
                bar.update(1)
                if fail is not None:
                    click.echo(f"\nfailed: {fail.error}", err=True)

            return run_tasks(tasks, options, client, on_done)


def report_failures(failures: Sequence[TaskFailure]) -> None:
    """One stderr line per failed run or channel."""
    for f in failures:
        click.echo(f"failed: {f.error}", err=True)
