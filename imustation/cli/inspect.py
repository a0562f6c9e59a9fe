"""``imustation inspect``: summarise a run file."""

from __future__ import annotations

from typing import TYPE_CHECKING

import click

from imustation.cli import cli
from imustation.units import format_duration

if TYPE_CHECKING:
    from imustation.runfile.holes import HoleCheck


def _clock(a) -> str:
    """The host clock's state as the run file stores it (docs/runfile.md, "Host clock")."""
    text = str(a["clock_sync"])
    if "clock_est_error_s" in a:
        text += f", estimated error {float(a['clock_est_error_s']) * 1e3:.1f} ms"
    if "clock_max_error_s" in a:
        text += f", at most {float(a['clock_max_error_s']) * 1e3:.1f} ms"
    return text


def _ended(rf) -> str:
    """``ended_utc``: the end of the data. Imports made before it was (issue 23) hold the time of the
    conversion there, and a simulated run the wall clock at its close: then the end of the data is
    derived from the last sample and said so."""
    a = rf.attrs
    ended = a.get("ended_utc", "-")
    simulated = bool(a.get("simulated", False)) and "ended_utc" in a
    if not simulated and ("source_format" not in a or "imported_utc" in a):
        return str(ended)
    import datetime as dt

    last_ns = max((int(rf.dataset(d.name, "t")[d.n - 1]) for d in rf.devices.values() if d.n), default=0)
    start = dt.datetime.fromisoformat(str(a["started_utc"]))
    end = (start + dt.timedelta(microseconds=last_ns // 1000)).isoformat(timespec="milliseconds")
    if simulated:
        # ended_utc is the host's wall clock at the clean close (docs/runfile.md); a simulation runs its
        # virtual time faster than that, so the end of the data is the virtual one
        return f"{end} (end of the simulated data; the file's ended_utc {ended} is the wall clock at its close)"
    return f"{end} (end of the data; the file says {ended}, when it was converted)"


@cli.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(dir_okay=False))
def inspect(runs: tuple[str, ...]) -> None:
    """Print the devices, settings, sample counts, duration and gaps of each RUN file.

    The parts of a rotated capture (week.001.h5, week.002.h5, ...) are one run: name
    them all, or the base name (week.h5); the parts are listed, then the devices
    over all of them.
    """
    from imustation.runfile import join_parts

    for k, run in enumerate(join_parts(runs)):
        if k:
            click.echo("")
        _inspect(run)


def _inspect(run: str) -> None:
    import os

    import numpy as np

    from imustation.runfile import RunSeries, open_series
    from imustation.runfile.holes import check_device, check_thermometer
    from imustation.runfile.series import base_of_part, series_parts
    from imustation.status import LOSS_KINDS, EventTally, device_status_from_run, thermometer_status

    with open_series(run) as rf:
        a = rf.attrs
        crashed = f"still recording, or cut off by a crash: then `imustation recover {run}` completes it"
        state = "complete" if rf.complete else f"INCOMPLETE ({crashed})"
        click.echo(f"{run}: {a.get('format')} v{a.get('format_version')}, station {a.get('station')!r}, {state}")
        click.echo(
            f"  started {a.get('started_utc')}  ended {_ended(rf)}"
            f"  simulated {bool(a.get('simulated'))}  software {a.get('software_version')}"
        )
        if "source_format" in a:
            click.echo(
                f"  imported from {a.get('source')} ({a['source_format']})"
                + (f" on {a['imported_utc']}" if "imported_utc" in a else "")
            )
        if isinstance(rf, RunSeries):
            click.echo(
                f"  rotated capture (run_id {a.get('run_id')}), parts {rf.numbers[0]}..{rf.numbers[-1]} read as one:"
            )
            for part in rf.parts:
                pa = part.attrs
                n = sum(d.n for d in part.devices.values())
                click.echo(
                    f"    part {pa.get('part')}: {os.path.basename(part.path)}, started {pa.get('part_started_utc')}, "
                    f"{n} samples, {os.path.getsize(part.path) / 2**20:.1f} MiB, "
                    + ("complete" if part.complete else "INCOMPLETE")
                )
        elif "part" in a:
            click.echo(
                f"  part {a['part']} of a rotated run (run_id {a.get('run_id')}), started {a.get('part_started_utc')};"
                f" previous {a.get('previous_part') or '-'}, next {a.get('next_part') or '-'}"
            )
            base = base_of_part(run)
            if base is not None and series_parts(base[0]):
                click.echo(f"  all parts as one run: imustation inspect {base[0]}")
        if a.get("stopped"):
            click.echo(f"  stopped early: {a['stopped']}")
        if a.get("recovered"):
            click.echo(f"  recovered {a.get('recovered_utc')}: {a['recovered']}")
        if "clock_sync" in a:
            click.echo(f"  host clock at the start: {_clock(a)}")
        events = rf.events()
        tally = EventTally()
        tally.add(events)
        unlogged = 0
        for dev in rf.devices.values():
            d = device_status_from_run(rf, dev, tally)
            click.echo(f"  device {dev.name}: {dev.model} ({dev.driver}) on {dev.bus}, {dev.identity}")
            settings = ", ".join(f"{k}={setting_text(v)}" for k, v in sorted(dev.settings.items()))
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
            rate = rf.thermometer_rate_hz(name)
            polled = f"polled at {rate:g} Hz" if rate is not None else "poll rate not stored"
            click.echo(f"  thermometer {name}: {th.readings} readings, {span}, {th.lost} missed, {polled}")
            tcheck = check_thermometer(rf, name, events)
            if tcheck is None:
                click.echo("    holes: not checked (no rate stored)")
            else:
                unlogged += len(tcheck.unlogged)
                click.echo(f"    {_holes_line(tcheck, 'readings', thermometer=True)}")
        click.echo(f"  holes found: {unlogged} not logged")
        other = [e for e in events if e.kind not in LOSS_KINDS]
        click.echo(f"  events: {len(events)} ({len(events) - len(other)} gaps/overruns)")
        for e in events[:20]:
            lost = f" lost={e.lost}" if e.lost else ""
            click.echo(f"    t={e.t_ns / 1e9:12.3f}s {e.source:>12} {e.kind:<9}{lost} {e.detail}")
        if len(events) > 20:
            click.echo(f"    ... {len(events) - 20} more")


def _holes_line(check: HoleCheck, unit: str = "samples", thermometer: bool = False) -> str:
    """What the data show of a device's or thermometer's losses against what its events state
    (``imustation.runfile.holes``)."""
    holes = check.holes
    text = f"holes in the data: {len(holes)} ({holes.samples} {unit})"
    if check.unlogged:
        first = check.unlogged[0]
        text += (
            f"; NOT LOGGED: {len(check.unlogged)} (first at t={first.t_ns / 1e9:.3f}s, row {first.row}:"
            f" {first.lost} missing, {first.logged} logged)"
        )
    else:
        text += ", every one logged"
    if check.unlocated:
        text += f"; {check.unlocated} {unit} logged lost where the data show no hole"
    if check.edge:
        text += f"; {check.edge} logged before the first or after the last {unit[:-1]}"
    if holes.short:
        # a thermometer's poll that came late is followed by one that keeps the time: not a fault
        late = " (late polls)" if thermometer else ""
        text += f"; {holes.short} steps of half a period or less{late}"
    return text


#: significant digits of a number setting as inspect prints it: an imported device's rate is the least-squares
#: fit of its stamps (200.00000000000196 Hz from millisecond stamps); the file keeps it whole for the analysis
SETTING_DIGITS = 10


def setting_text(value) -> str:
    """A device setting as printed: a float to :data:`SETTING_DIGITS` significant digits, anything else as is."""
    if isinstance(value, float) or (hasattr(value, "dtype") and getattr(value.dtype, "kind", "") == "f"):
        return format(float(value), f".{SETTING_DIGITS}g")
    return str(value)
