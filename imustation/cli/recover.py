"""``imustation recover``: make run files cut off by a crash plain, complete HDF5 files."""

from __future__ import annotations

import click

from imustation.cli import cli


@cli.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(dir_okay=False))
def recover(runs: tuple[str, ...]) -> None:
    """Make each RUN file cut off by a kill or power cut a complete HDF5 file any tool opens.

    Copies what the file holds (a torn last block left out), marks it recovered with
    what was lost (root attributes recovered, recovered_utc, ended_utc at the last
    sample; a note event) and keeps the original as RUN.before-recover. Give every
    part of a rotated run to recover them all; complete files are left as they are.
    A file a capture is writing is refused (docs/runfile.md).
    """
    from imustation.acquisition.recorder import OutputLock
    from imustation.runfile.recover import recover_run

    for path in runs:
        lock = OutputLock(path)  # no capture writes it while it is copied, and none starts
        lock.acquire()
        try:
            rec = recover_run(path)
        finally:
            lock.release()
        if rec is None:
            click.echo(f"{path}: complete, nothing to recover")
        else:
            click.echo(f"{path}: recovered ({rec.statement()}); the original is {rec.original}")
