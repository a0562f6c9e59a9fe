"""The ``imustation`` command line: one click group, one module per subcommand.

Every subcommand only parses options, calls the library and prints. Expected
errors (:class:`~imustation.errors.ImustationError`) print one line on stderr
and exit with status 2; ``--debug`` shows the traceback instead.

Start-up time: ``imustation --help``, ``imustation CMD --help`` and argument
errors must not wait for numpy, scipy, h5py, numba or matplotlib (seconds on a
small machine). So the subcommand modules import only click and light modules
(errors, units, clock, configs) at module top; everything else is imported
inside the command functions; option choices and defaults come from the
dependency-free :mod:`imustation.analysis.pipeline.choices`. tests/test_startup.py
checks this.
"""

from __future__ import annotations

import re
import sys
import warnings

import click

from imustation import __version__
from imustation.errors import ImustationError, RateCorrected

#: options whose value is a duration (imustation.units.parse_duration)
DURATION_OPTIONS = ("--duration", "--rotate", "--warmup", "--model-after")
_NUMBER = re.compile(r"^(\d+(\.\d*)?|\.\d+)$")
_UNIT = re.compile(r"^(ms|s|m|min|h|d)$", re.IGNORECASE)


def join_duration_words(args: list[str]) -> list[str]:
    """``--duration 2 h`` (unquoted: the shell makes two words) -> ``--duration 2h``.

    Only after a duration option, and only a number followed by a bare unit word (repeated:
    ``1 h 30 m``), so no file or channel name is ever taken; ``--duration "2 h"`` needs nothing.
    """
    out: list[str] = []
    i = 0
    while i < len(args):
        out.append(args[i])
        if args[i] in DURATION_OPTIONS:
            j, parts = i + 1, []
            while j + 1 < len(args) and _NUMBER.match(args[j]) and _UNIT.match(args[j + 1]):
                parts.append(args[j] + args[j + 1])
                j += 2
            if parts:
                out.append("".join(parts))
                i = j
                continue
        i += 1
    return out


class _Group(click.Group):
    """Lists commands in the order they were added and turns user errors into one line."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(self.commands)

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        return super().parse_args(ctx, join_duration_words(list(args)))

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except ImustationError as exc:
            if ctx.obj and ctx.obj.get("debug"):
                raise
            click.echo(f"imustation: error: {exc}", err=True)
            ctx.exit(2)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, "-V", "--version", prog_name="imustation")
@click.option("--debug", is_flag=True, help="Show tracebacks instead of one-line errors.")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """Record inertial sensors for hours and characterise their noise.

    \b
    Typical use:
      imustation capture configs/lab-example.toml --duration 12h -o run.h5
      imustation inspect run.h5
      imustation analyze run.h5 --channel 'bmx055/gyro/*'
      imustation import field.bag -o field.h5    # ROS bag / MCAP / CSV log -> run file
      imustation demo            # simulated capture + analysis, about a minute
      imustation devices configs/lab-example.toml   # probe every configured chip, say what to fix
      imustation setup udev           # udev rules; setup service CONFIG -o RUN.h5: a systemd unit
      imustation fleet night*.h5 -o fleet/ --workers 2   # fleet table, repeatability, outliers
    """
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug
    _show_rate_corrections()


def _show_rate_corrections() -> None:
    """Print each :class:`RateCorrected` of this command once, as one ``imustation: warning:`` line
    (a run file is opened several times by one command; other warnings keep Python's handling)."""
    seen: set[str] = set()
    previous = getattr(warnings.showwarning, "previous", warnings.showwarning)  # not chained per command

    def show(message, category, filename, lineno, file=None, line=None):
        if not issubclass(category, RateCorrected):
            return previous(message, category, filename, lineno, file, line)
        if str(message) not in seen:
            seen.add(str(message))
            click.echo(f"imustation: warning: {message}", err=True)
        return None

    show.previous = previous
    warnings.filterwarnings("always", category=RateCorrected)
    warnings.showwarning = show


def main() -> None:
    try:
        cli.main(prog_name="imustation")
    except BrokenPipeError:  # output piped into head & co.
        sys.stderr.close()
        sys.exit(1)


# subcommand modules register themselves on the group (keep their module tops light: see above)
from imustation.cli import (  # noqa: E402,F401
    analyze,
    capture,
    demo,
    devices,
    export,
    fleet,
    importcmd,
    inspect,
    monitor,
    recover,
    report,
    setup,
    study,
)
