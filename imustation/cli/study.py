"""``imustation study``: Monte Carlo study of ML_i, classical ML and GMWM (paper Figs. 10-11, Table III)."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import click

from imustation.analysis.pipeline.choices import DEFAULT_STUDY_ESTIMATORS, STUDY_ESTIMATORS
from imustation.cli import cli
from imustation.errors import InputError
from imustation.outputs import check_file
from imustation.units import parse_duration


def _floats(text: str, what: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"{what} {text!r}: use comma-separated numbers, e.g. 1,3,10") from None
    if not all(v > 0 for v in vals):
        raise InputError(f"{what} {text!r}: values must be positive")
    return vals


@cli.command()
@click.option("--records", type=click.IntRange(2, 10000), default=10, show_default=True, help="Records per level.")
@click.option("--duration", default="12h", show_default=True, help="Length of each simulated record: 12h, 90m, ...")
@click.option("--rate", "fs_hz", type=float, default=400.0, show_default=True, help="Sampling rate, Hz.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the first record.")
@click.option(
    "--estimators",
    default=",".join(DEFAULT_STUDY_ESTIMATORS),
    show_default=True,
    help=f"Comma-separated subset of {','.join(STUDY_ESTIMATORS)}.",
)
@click.option(
    "--levels",
    default="1",
    show_default=True,
    help="Comma-separated multipliers of the Table III sigma_b (Fig. 10 varies it), e.g. 1,3,10.",
)
@click.option("-m", "m", type=click.IntRange(8, 100000), default=1000, show_default=True, help="Pattern points.")
@click.option(
    "--check-starts",
    is_flag=True,
    help="Also fit from each estimator's single default start and count how often it ends in another optimum.",
)
@click.option(
    "-o",
    "--output",
    "--out",
    "out",
    type=click.Path(dir_okay=False),
    default=None,
    help="Write the Markdown table to this file (--out: the former spelling).",
)
@click.option("--overwrite", is_flag=True, help="Replace an existing -o file.")
def study(
    overwrite: bool,
    records: int,
    duration: str,
    fs_hz: float,
    seed: int,
    estimators: str,
    levels: str,
    m: int,
    check_starts: bool,
    out: str | None,
) -> None:
    """Simulate BMX055-like records (Table III) and report bias, spread, RMSE and CI coverage."""
    if out is not None:
        check_file(out, overwrite=overwrite)
    est = tuple(e.strip() for e in estimators.split(",") if e.strip())
    lv = _floats(levels, "--levels")
    seconds = parse_duration(duration, "--duration")
    from imustation.analysis.estimators.models.reference import TABLE_III_MEAN
    from imustation.analysis.pipeline.study import markdown, run_study, summarize

    fits = run_study(
        TABLE_III_MEAN,
        records=records,
        duration_s=seconds,
        fs_hz=fs_hz,
        seed=seed,
        estimators=est,
        levels=lv,
        m=m,
        progress=lambda t: click.echo(t, err=True),
        check_starts=check_starts,
    )
    command = "imustation study " + " ".join(shlex.quote(a) for a in sys.argv[2:])
    header = (
        f"Monte Carlo study: {records} records x {duration} at {fs_hz:g} Hz per level, truth = Table III "
        f"(sigma_w {TABLE_III_MEAN.sigma_w:.3g} rad/s/rtHz, sigma_b {TABLE_III_MEAN.sigma_b:.3g} x level "
        f"rad/s^2/rtHz, tau_b {TABLE_III_MEAN.tau_b:.4g} s), seeds {seed}..{seed + records - 1}, m = {m}.\n\n"
        f"Command: `{command}`"
    )
    text = markdown(summarize(fits), header)
    if out:
        Path(out).write_text(text)
    click.echo(text)
