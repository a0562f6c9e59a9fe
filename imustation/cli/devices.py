"""``imustation devices``: probe every configured device and thermometer; say why one does not answer."""

from __future__ import annotations

import click

from imustation.cli import cli
from imustation.clock import MonotonicClock, VirtualClock


@cli.command()
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--simulate", is_flag=True, help="Probe the simulated chips instead of the hardware.")
@click.option(
    "--no-baud-probe", is_flag=True, help="Do not try other baud rates on a serial device that does not answer."
)
@click.option("--host-root", default=None, hidden=True, help="Tests: read DIR/dev and DIR/sys instead of /dev, /sys.")
def devices(config: str, simulate: bool, no_baud_probe: bool, host_root: str | None) -> None:
    """Open every device and thermometer of CONFIG, print its identity or why it does not answer.

    Each one is identified and configured as a capture would do it (chips are
    reset to apply the settings), then closed. One line per device: name,
    driver, bus@address and the identity, or the error followed by its cause
    and remedy - a missing /dev/i2c-N (i2c-dev not loaded, bus not enabled),
    permissions (the node's group), a USB bridge that is not plugged in (the
    USB devices present are listed), a serial port that does not exist
    (/dev/serial/by-id is listed), a serial device answering at another baud
    rate (the common rates are tried). Then the host clock's synchronisation.
    Exit status 1 if any device failed to answer (docs/hardware.md).
    """
    from imustation.acquisition import load_config
    from imustation.acquisition.clocksync import read_sync
    from imustation.acquisition.doctor import PROBE_BAUDS, check_station
    from imustation.acquisition.hostview import HostView

    cfg = load_config(config)
    clock = VirtualClock() if simulate else MonotonicClock()
    view = HostView(dev_root=f"{host_root}/dev", sys_root=f"{host_root}/sys") if host_root else HostView()
    findings = check_station(
        cfg, simulate=simulate, clock=clock, view=view, probe_bauds=() if no_baud_probe else PROBE_BAUDS
    )
    # columns as wide as their longest entry: a bus URL such as serial:/dev/ttyUSB1?baud=921600 is 31 characters
    cols = [(f.what, f.name, f.driver, f.where) for f in findings]
    widths = [max((len(c[i]) for c in cols), default=0) for i in range(4)]
    for f, col in zip(findings, cols, strict=True):
        head = " ".join(s.ljust(w) for s, w in zip(col, widths, strict=True))
        click.echo(f"{head} {f.detail}" if f.ok else f"{head} ERROR: {f.detail}")
        if not f.ok:
            if f.cause and f.cause != f.detail:
                click.echo(f"    cause:  {f.cause}")
            click.echo(f"    remedy: {f.remedy}")
        for note in f.notes:
            click.echo(f"    note:   {note}")
    if not simulate:
        click.echo(f"host clock: {read_sync().describe()}")
    failed = sum(not f.ok for f in findings)
    if failed:
        click.echo(f"{failed} of {len(findings)} did not answer as expected", err=True)
        raise SystemExit(1)
