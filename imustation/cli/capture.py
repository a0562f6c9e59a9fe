"""``imustation capture``: record every device of a config into a run file."""

from __future__ import annotations

import json
import os
import signal
import sys
import threading

import click

from imustation import stopsignals
from imustation.cli import cli
from imustation.cli.statusview import StatusView
from imustation.errors import BusError, DeviceError, InputError, SettingError
from imustation.outputs import check_file
from imustation.units import format_duration, parse_duration


def _record_stop_signals() -> list[int]:
    """SIGINT/SIGTERM received from now until the command ends, in order (handlers restored then).

    The entry point (``imustation.__main__``) records them from the process's first moments;
    its list is taken over then (called in-process, e.g. by tests, the recording starts here).
    """
    if stopsignals.recording():
        return stopsignals.received
    early: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        return early
    sigs = (signal.SIGINT, signal.SIGTERM)
    previous = {sig: signal.signal(sig, lambda signum, _frame: early.append(signum)) for sig in sigs}
    click.get_current_context().call_on_close(lambda: [signal.signal(s, h) for s, h in previous.items()])
    return early


def _write_status_file(path: str, status: dict) -> None:
    """Replace ``path`` atomically, so a reader never sees half a document."""
    tmp = f"{path}.tmp"
    with open(tmp, "w") as fh:
        json.dump(status, fh)
        fh.write("\n")
    os.replace(tmp, path)


def _cpus(value: str | None) -> tuple[int, ...] | None:
    """``--reader-cpus``: CPU numbers and ranges (``2,3`` or ``1-3``) this process may use, or None."""
    if value is None:
        return None
    usable = os.sched_getaffinity(0)
    cpus: set[int] = set()
    try:
        for part in value.split(","):
            lo, _, hi = part.partition("-")
            cpus.update(range(int(lo), int(hi or lo) + 1))
    except ValueError:
        cpus = set()
    if not cpus or not cpus <= usable:
        raise InputError(
            f"--reader-cpus {value!r}: CPU numbers or ranges (e.g. 2,3 or 1-3) among those usable here:"
            f" {','.join(map(str, sorted(usable)))}"
        )
    return tuple(sorted(cpus))


def _workers(value: str, cfg, can: bool) -> int:
    """``--workers``: a count, or auto (cores, at most one per bus group; 1 where workers cannot help)."""
    if value == "auto":
        from imustation.acquisition.workers import default_workers

        return default_workers(cfg) if can else 1
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise InputError(f"--workers {value!r}: a whole number >= 1, or auto")
    return n


def _bring_up_check(cfg, seconds: float, *, simulate: bool, sim_level: str, fsync: bool) -> None:
    """``capture --check``: the report on stdout, exit status 1 for NO-GO."""
    from imustation.acquisition.bringup import run_check

    click.echo(f"checking {cfg.name} for {format_duration(seconds)} (keep the rig still) ...", err=True)
    report = run_check(cfg, seconds, simulate=simulate, sim_level=sim_level, fsync=fsync)
    for line in report.lines():
        click.echo(line)
    if not report.go:
        raise SystemExit(1)


#: capture options that make or shape a run file: --check records none (a temporary file, then the verdict)
_NOT_WITH_CHECK = {
    "output": "-o",
    "duration": "--duration",
    "overwrite": "--overwrite",
    "rotate": "--rotate",
    "resume": "--resume",
    "json_status": "--json-status",
    "status_file": "--status-file",
    "trace_file": "--trace",
    "replay_file": "--replay",
    "with_monitor": "--monitor",
    "workers": "--workers",
    "real_time": "--real-time",
    "reader_cpus": "--reader-cpus",
}


def _refuse_with_check() -> None:
    """``--check`` with an option it would silently ignore (a file kept, a duration, a host clock): one line."""
    ctx = click.get_current_context()
    given = [
        flag
        for name, flag in _NOT_WITH_CHECK.items()
        if ctx.get_parameter_source(name) not in (None, click.core.ParameterSource.DEFAULT)
    ]
    if given:
        raise InputError(
            f"--check with {', '.join(given)}: the check records DURATION into a temporary file and keeps no run; "
            "it takes the config, --simulate, --sim-level and its own DURATION only"
        )


@cli.command()
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("-o", "--output", default="run.h5", show_default=True, help="Run file to create (HDF5).")
@click.option("--duration", default="12h", show_default=True, help="How long to record: 12h, 90m, 1h30m, 45s.")
@click.option("--simulate", is_flag=True, help="Replace every bus and chip by its simulator (virtual clock).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file (and --trace file).")
@click.option(
    "--rotate",
    default=None,
    metavar="DURATION",
    help="Start a new part file every DURATION (e.g. 6h): run.001.h5, run.002.h5, ...",
)
@click.option(
    "--resume",
    is_flag=True,
    help="Continue the run at OUTPUT as its next part if it exists (after a crash, power cut or stop): same run, "
    "the outage a logged gap, a cut-off part recovered first; --duration counts from the run's start. "
    "Without a run there, a new one starts (docs/capture.md).",
)
@click.option(
    "--check",
    default=None,
    metavar="DURATION",
    help="Bring-up check instead of a run: capture DURATION (e.g. 30s) into a temporary file and report per "
    "device the rate reached, losses, gravity, gyro bias against the range, temperatures, then GO / NO-GO "
    "(exit status 0 / 1). The rig must stand still.",
)
@click.option("--quiet", is_flag=True, help="No live status (errors and the final summary only).")
@click.option("--json-status", is_flag=True, help="Print the status as one JSON line per interval on stdout.")
@click.option("--status-file", default=None, metavar="PATH", help="Keep the latest JSON status in PATH.")
@click.option(
    "--status-interval", default=1.0, show_default=True, type=float, metavar="SECONDS", help="Wall s between statuses."
)
@click.option(
    "--trace",
    "trace_file",
    default=None,
    metavar="FILE",
    help="Record every bus transaction of every device to FILE (JSON lines), to replay later.",
)
@click.option(
    "--replay",
    "replay_file",
    default=None,
    metavar="FILE",
    help="Answer every driver from a trace made with --trace instead of a bus (virtual clock; "
    "use the same config and duration): a recorded capture becomes a regression test.",
)
@click.option(
    "--monitor",
    "with_monitor",
    is_flag=True,
    help="Also start 'imustation monitor' on the run file, in its own process (a web page; docs/monitor.md).",
)
@click.option("--monitor-host", default="127.0.0.1", show_default=True, help="--monitor: address to listen on.")
@click.option("--monitor-port", default=8765, show_default=True, type=int, help="--monitor: TCP port.")
@click.option(
    "--workers",
    default="1",
    show_default=True,
    metavar="N|auto",
    help="--simulate: processes polling the bus groups (simulated chips cost CPU; 2 halves a long lab "
    "simulation). auto = one per core, at most one per bus. A device's noise realisation then differs "
    "from a one-process run (docs/capture.md).",
)
@click.option(
    "--sim-level",
    type=click.Choice(["bus", "model"]),  # acquisition.modes.SIM_LEVELS (not imported: --help stays light)
    default="bus",
    show_default=True,
    help="--simulate: bus = chip simulators answer the drivers byte by byte through the real bus code "
    "(40-70x real time for the paper's lab); model = each device, once opened that way, is polled at the "
    "noise-model level without bus transport (same noise sources and seeds; faults: disconnect, checksum; "
    "hundreds of times real time). docs/capture.md.",
)
@click.option(
    "--real-time",
    is_flag=True,
    help="--simulate: run the chip simulators on the host clock, each bus polled by a reader process as "
    "in a capture of real devices: a rehearsal of a night on this machine (samples it would lose are "
    "logged). docs/capture.md.",
)
@click.option(
    "--reader-cpus",
    default=None,
    metavar="LIST",
    help="Host clock: run the bus reader processes on these CPUs (e.g. 2,3 or 1-3; default: where the "
    "kernel puts them).",
)
@click.option("--sim-speed", default=None, type=float, hidden=True, help="Simulation: max virtual s per wall s.")
@click.option("--no-fsync", is_flag=True, hidden=True, help="Skip fsync after flushes (tests on slow disks).")
def capture(
    config: str,
    output: str,
    duration: str,
    simulate: bool,
    overwrite: bool,
    rotate: str | None,
    quiet: bool,
    json_status: bool,
    status_file: str | None,
    status_interval: float,
    trace_file: str | None,
    replay_file: str | None,
    with_monitor: bool,
    monitor_host: str,
    monitor_port: int,
    workers: str,
    sim_level: str,
    real_time: bool,
    reader_cpus: str | None,
    sim_speed: float | None,
    no_fsync: bool,
    resume: bool,
    check: str | None,
) -> None:
    """Record every device and thermometer of CONFIG into a run file (format v1).

    Data are on disk at least every flush_interval_s of the config. Ctrl-C or
    SIGTERM stops the capture cleanly and finishes the file; after a crash the
    file holds every sample up to the last flush (see docs/capture.md). On the
    host clock (real devices, or --simulate --real-time) each bus is polled by a
    reader process of its own, at real-time priority where the system permits.
    """
    # a stop asked for while the imports, the config and the devices take their time must
    # still give a finished file (capture() reads it), not a process killed with nothing left
    early = _record_stop_signals()
    from imustation.acquisition import capture as run_capture
    from imustation.acquisition import load_config
    from imustation.acquisition.modes import check_options, workers_possible
    from imustation.monitor.launcher import MonitorProcess

    if resume and overwrite:
        raise InputError("--resume continues the run at -o; --overwrite would replace it: give one of them")
    cfg = load_config(config)
    if check is not None:
        _refuse_with_check()
        _bring_up_check(
            cfg, parse_duration(check, "--check"), simulate=simulate, sim_level=sim_level, fsync=not no_fsync
        )
        return
    # outputs before any device is touched (existing parts of a rotated capture: the recorder's check)
    check_file(output, overwrite=overwrite or bool(rotate) or resume)
    if trace_file is not None:
        check_file(trace_file, overwrite=overwrite, option="--trace")
    if status_file is not None:
        check_file(status_file, overwrite=True, option="--status-file")  # replaced every interval by design
    seconds = parse_duration(duration, "--duration")
    rotate_s = parse_duration(rotate, "--rotate") if rotate else None
    check_rotate(rotate, rotate_s, duration, seconds)
    if not status_interval > 0:
        raise InputError(f"--status-interval {status_interval}: must be > 0 s")
    if sim_speed is not None and not sim_speed > 0:
        raise InputError(f"--sim-speed {sim_speed}: must be > 0")
    given = {"trace": trace_file is not None, "replay": replay_file is not None, "rotate": rotate_s is not None}
    n_workers = _workers(workers, cfg, workers_possible(simulate=simulate, virtual_clock=not real_time, **given))
    check_options(simulate=simulate, sim_level=sim_level, workers=n_workers, cli=True, real_time=real_time, **given)
    cpus = _cpus(reader_cpus)
    live = not quiet and not json_status
    view = StatusView(sys.stderr) if live else None
    # the monitor's notes go through the view, so they never land inside the status block
    launcher = MonitorProcess(
        monitor_host, monitor_port, note=view.note if view is not None else lambda msg: click.echo(msg, err=True)
    )

    def on_status(status: dict) -> None:
        if with_monitor:
            launcher.poll(status.get("file"))
        if json_status:
            click.echo(json.dumps(status))
        if status_file:
            _write_status_file(status_file, status)
        if view is not None:
            view.show(status)

    try:
        summary = run_capture(
            cfg,
            output,
            seconds,
            simulate=simulate,
            overwrite=overwrite,
            on_status=on_status,
            status_interval_s=status_interval,
            rotate_s=rotate_s,
            pace=sim_speed,
            fsync=not no_fsync,
            trace=trace_file,
            replay=replay_file,
            workers=n_workers,
            sim_level=sim_level,
            early_stop=early,
            resume=resume,
            real_time=real_time,
            reader_cpus=cpus,
            on_note=view.note if view is not None else lambda msg: click.echo(msg, err=True),
        )
    except (BusError, DeviceError) as exc:
        if simulate or isinstance(exc, SettingError):
            raise
        # a device that does not answer on a real bus: 'devices' knows the causes (module, permission, udev, port)
        raise DeviceError(f"{exc} - 'imustation devices {config}' names the cause and the remedy") from None
    finally:
        launcher.stop()
        if view is not None:
            view.close()
    if not summary.paths:  # a resume that found its run over
        click.echo(f"{output}: {summary.stop_reason}", err=json_status)
        return
    total = sum(summary.samples.values())
    lost = sum(summary.lost.values())
    speed = summary.duration_s / summary.wall_s if summary.wall_s > 0 else float("inf")
    note = f" ({summary.stop_reason})" if summary.stop_reason else ""
    files = summary.paths[0] if len(summary.paths) == 1 else f"{len(summary.paths)} parts {summary.paths[0]} .. "
    files += os.path.basename(summary.paths[-1]) if len(summary.paths) > 1 else ""
    msg = (
        f"wrote {files}: {total} samples from {len(summary.samples)} device(s)"
        + (f", {sum(summary.readings.values())} thermometer readings" if summary.readings else "")
        + (f", {lost} samples lost (see inspect)" if lost else "")
        + f", {format_duration(summary.duration_s)} in {summary.wall_s:.1f} s wall ({speed:.0f}x real time){note}"
    )
    click.echo(msg, err=json_status)


def check_rotate(rotate: str | None, rotate_s: float | None, duration: str, seconds: float) -> None:
    """Refuse a ``--rotate`` part length longer than the run's ``--duration`` (texts as given, values in s):
    the run would be one part, which is not what a user asking for parts expects (docs/capture.md)."""
    if rotate_s is not None and rotate_s > seconds:
        raise InputError(
            f"--rotate {rotate} is longer than --duration {duration}: the run would be a single part; give a part "
            f"length up to the duration (e.g. --rotate {_part_hint(seconds)}), or leave --rotate out"
        )


def _part_hint(seconds: float) -> str:
    """A round part length for a run of ``seconds``: an hour, or a tenth of a shorter run (whole minutes)."""
    if seconds >= 2 * 3600:
        return "1h"
    return f"{max(1, round(seconds / 600))}m" if seconds >= 600 else f"{max(1, round(seconds / 10))}s"
