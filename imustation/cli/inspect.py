"""``imustation inspect``: summarise a run file."""

from __future__ import annotations

from typing import TYPE_CHECKING

import click

from imustation.cli import cli
from imustation.units import format_duration

if TYPE_CHECKING:
    from imustation.runfile.holes import HoleCheck


@cli.command()
@click.argument("run", type=click.Path(dir_okay=False))
def inspect(run: str) -> None:
    """Print the devices, settings, sample counts, duration and gaps of a RUN file."""
    import numpy as np

    from imustation.runfile import open_run
    from imustation.runfile.holes import check_device
    from imustation.status import LOSS_KINDS, EventTally, device_status_from_run, thermometer_status

    with open_run(run) as rf:
        a = rf.attrs
        state = "complete" if rf.complete else "INCOMPLETE (still recording, or cut off by a crash)"
        click.echo(f"{run}: {a.get('format')} v{a.get('format_version')}, station {a.get('station')!r}, {state}")
        click.echo(
            f"  started {a.get('started_utc')}  ended {a.get('ended_utc', '-')}"
            f"  simulated {bool(a.get('simulated'))}  software {a.get('software_version')}"
        )
        if "part" in a:
            click.echo(
                f"  part {a['part']} of a rotated run (run_id {a.get('run_id')}), started {a.get('part_started_utc')};"
                f" previous {a.get('previous_part') or '-'}, next {a.get('next_part') or '-'}"
            )
        if a.get("stopped"):
            click.echo(f"  stopped early: {a['stopped']}")
        events = rf.events()
        tally = EventTally()
        tally.add(events)
        unlogged = 0
        for dev in rf.devices.values():
            d = device_status_from_run(rf, dev, tally)
            click.echo(f"  device {dev.name}: {dev.model} ({dev.driver}) on {dev.bus}, {dev.identity}")
            settings = ", ".join(f"{k}={v}" for k, v in sorted(dev.settings.items()))
            click.echo(f"    settings: {settings}")
            if dev.torn:
                rows = ", ".join(f"{k} {v}" for k, v in sorted(dev.rows.items()))
                click.echo(f"    torn last block (cut off while flushing): rows {rows}; reading the first {dev.n}")
            rate = d.rate_hz if d.rate_hz is not None else float("nan")
            click.echo(
                f"    samples {d.samples}, duration {format_duration(d.duration_s)}, "
                f"rate {rate:.3f} Hz (configured {d.rate_cfg_hz:g}), gaps {d.gaps} ({d.lost} samples lost)"
            )
            check = check_device(rf, dev.name, events)
            unlogged += len(check.unlogged)
            click.echo(f"    {_holes_line(check)}")
            for ch in dev.channels.values():
                axes = f" axes {','.join(ch.axes)}" if ch.axes else ""
                click.echo(
                    f"    {ch.name}: {ch.dtype} x{ch.n}{axes}, scale {ch.scale:.6g} {ch.units}/count"
                    + (f", offset {ch.offset:g}" if ch.offset else "")
                )
            if "temp" in dev.channels and dev.n:
                tc = dev.channels["temp"]
                raw = rf.read(dev.name, "temp")
                c = raw.astype(float) * tc.scale + tc.offset
                click.echo(f"    temperature {np.min(c):.2f} .. {np.max(c):.2f} degC")
        for name in rf.thermometers:
            t, c = rf.temperatures(name)
            th = thermometer_status(name, t * 1e-9, c, tally)
            span = f"{c.min():.3f} .. {c.max():.3f} degC" if len(c) else "no readings"
            click.echo(f"  thermometer {name}: {th.readings} readings, {span}, {th.lost} missed")
        click.echo(f"  holes found: {unlogged} not logged")
        other = [e for e in events if e.kind not in LOSS_KINDS]
        click.echo(f"  events: {len(events)} ({len(events) - len(other)} gaps/overruns)")
        for e in events[:20]:
            lost = f" lost={e.lost}" if e.lost else ""
            click.echo(f"    t={e.t_ns / 1e9:12.3f}s {e.source:>12} {e.kind:<9}{lost} {e.detail}")
        if len(events) > 20:
            click.echo(f"    ... {len(events) - 20} more")


def _holes_line(check: HoleCheck) -> str:
    """What the data show of a device's losses against what its events state (``imustation.runfile.holes``)."""
    holes = check.holes
    text = f"holes in the data: {len(holes)} ({holes.samples} samples)"
    if check.unlogged:
        first = check.unlogged[0]
        text += (
            f"; NOT LOGGED: {len(check.unlogged)} (first at t={first.t_ns / 1e9:.3f}s, row {first.row}:"
            f" {first.lost} missing, {first.logged} logged)"
        )
    else:
        text += ", every one logged"
    if check.unlocated:
        text += f"; {check.unlocated} samples logged lost where the data show no hole"
    if check.edge:
        text += f"; {check.edge} logged before the first or after the last sample"
    if holes.short:
        text += f"; {holes.short} steps of half a period or less"
    return text
