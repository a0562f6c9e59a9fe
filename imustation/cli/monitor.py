"""``imustation monitor``: a read-only local web page that watches a run file being written."""

from __future__ import annotations

import os
import socket

import click

from imustation.cli import cli
from imustation.errors import InputError
from imustation.units import parse_duration

#: CPU priority the monitor lowers itself to (nice increment), so it yields to a capture
NICE = 10


def _url(host: str, port: int, token: str | None) -> str:
    if host in ("0.0.0.0", "::", ""):
        host = socket.gethostname()
    if ":" in host:
        host = f"[{host}]"
    return f"http://{host}:{port}/" + (f"?token={token}" if token else "")


@cli.command()
@click.argument("run_file", type=click.Path(dir_okay=False))
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="Address to listen on; any non-loopback address requires the token printed at start.",
)
@click.option("--port", default=8765, show_default=True, type=int, help="TCP port (0: any free port).")
@click.option(
    "--poll",
    "poll_s",
    default=2.0,
    show_default=True,
    type=float,
    metavar="SECONDS",
    help="Wall seconds between reads of the run file.",
)
@click.option(
    "--allan-every",
    "allan_every_s",
    default=30.0,
    show_default=True,
    type=float,
    metavar="SECONDS",
    help="Wall seconds between recomputations of the Allan curves.",
)
@click.option(
    "--model-after",
    default="10m",
    show_default=True,
    metavar="DURATION",
    help="Data a device needs before the ML_i model overlay is fitted (then every 2 min).",
)
def monitor(run_file: str, host: str, port: int, poll_s: float, allan_every_s: float, model_after: str) -> None:
    """Serve a page that watches RUN_FILE while it is being written (read-only, SWMR).

    Per device: rate achieved vs configured, samples, gaps and events; device and
    MCP9804 temperatures with the warm-up state; each gyro axis's Allan deviation
    as it grows, with the ML_i standard-model overlay once enough data exist.
    Nothing on the page changes anything; Ctrl-C stops it (docs/monitor.md).
    """
    if not 0 <= port <= 65535:
        raise InputError(f"--port {port}: must be 0..65535")
    if not (poll_s > 0 and allan_every_s > 0):
        raise InputError("--poll and --allan-every must be > 0 s")
    model_after_s = parse_duration(model_after, "--model-after")
    from imustation.monitor import Monitor
    from imustation.monitor.server import bind, is_loopback, new_token, serve

    mon = Monitor(run_file, poll_s=poll_s, allan_every_s=allan_every_s, model_after_s=model_after_s)
    sockets = bind(host, port)
    token = new_token(host)
    actual = sockets[0].getsockname()[1]
    try:
        os.nice(NICE)
    except OSError:
        pass

    def ready() -> None:
        click.echo(f"imustation monitor: watching {run_file} at {_url(host, actual, token)} (pid {os.getpid()})")
        if token:
            click.echo(f"  listening on {host}, not only this machine: every request needs the token above")
        elif not is_loopback(host):  # pragma: no cover - new_token gives one for every non-loopback host
            click.echo("  warning: no token")
        click.echo("  read-only; Ctrl-C stops the monitor (never the capture)", nl=True)
        click.get_text_stream("stdout").flush()

    serve(mon, sockets, token=token, loopback=is_loopback(host), ready=ready)
