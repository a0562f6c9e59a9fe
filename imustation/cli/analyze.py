"""``imustation analyze``: Allan deviation and noise-model fits per channel."""

from __future__ import annotations

import json
import math

import click

from imustation.analysis.pipeline import choices
from imustation.cli import cli
from imustation.cli._field import field_options, plan_inputs, text_options
from imustation.cli._parallel import cluster_options, report_failures, run_with_progress
from imustation.errors import InputError
from imustation.units import DEG2RAD


def _g(x: float, fmt: str = ".3e") -> str:
    return format(x, fmt) if math.isfinite(x) else "-"


def results_table(results) -> str:
    head = (
        f"{'channel':<22} {'n':>9} {'fs Hz':>7} {'sigma_w':>10} {'deg/h/rtHz':>10} {'sigma_b':>10} "
        f"{'tau_b s':>9} {'b_on':>10} {'ADEV(1s)':>10}  fit"
    )
    lines = [head, "-" * len(head)]
    for r in results:
        adev1 = _interp_adev(r.allan, 1.0)
        fits = [f for f in (r.noise_model, r.mli, r.gmwm) if f is not None]
        fits = [f for k, f in enumerate(fits) if all(f is not g for g in fits[:k])]
        for m in fits:
            flag = "ok" if m.converged else f"! {m.message}"
            name = r.channel.id if m is r.noise_model else f"  {m.estimator}"
            lines.append(
                f"{name:<22} {r.channel.n:>9} {r.channel.fs_hz:>7g} {_g(m.sigma_w):>10} "
                f"{_g(m.sigma_w / DEG2RAD * 3600, '.2f'):>10} {_g(m.sigma_b):>10} {_g(m.tau_b, '.1f'):>9} "
                f"{_g(m.b_on):>10} {_g(adev1):>10}  {m.estimator} {flag}"
            )
        if r.choice is not None:
            lines += _choice_lines(r)
        for alt in r.models:
            lines.append(f"    {alt.model:<18} nll {alt.nll:.2f}  AIC {alt.aic:.2f}  BIC {alt.bic:.2f}")
    for r in results:
        if r.verdict is not None:
            lines.append(f"enough data? {r.channel.id}: {r.verdict.verdict} - {'; '.join(r.verdict.reasons)}")
    lines.append(
        "units: sigma_w (unit)/s*sqrt(s) = (unit)/sqrt(Hz); sigma_b (unit)/s/sqrt(Hz); "
        "b_on, ADEV in the channel unit (rad/s or m/s^2)"
    )
    return "\n".join(lines)


def _choice_lines(r) -> list[str]:
    """The automatic choice of one channel: chosen model with N, B, K (90 % intervals), the paper's model."""
    from imustation.analysis.estimators.model_choice import ieee952_summary

    def nbk(fit) -> str:
        s = ieee952_summary(fit, r.channel.n / r.channel.fs_hz)
        parts = []
        for q in ("N", "B", "K"):
            if s[q] is not None:
                lo, hi = s[f"{q}_ci90"]
                parts.append(f"{q} {_g(s[q])} [{_g(lo)}, {_g(hi)}]")
        return "  ".join(parts)

    c = r.choice
    head = f"    model {c.chosen.model} ({'fits' if c.fits else 'NO MODEL FITS'}): {nbk(r.noise_model)}"
    out = [head]
    if not c.fits:
        out.append(f"      {c.reason}")
    if c.paper is not None:
        flag = "ok" if c.paper.converged else f"! {c.paper.message}"
        out.append(f"    paper's wn+gm: sigma_w {_g(c.paper.sigma_w)}  {nbk(c.paper)}  {flag}")
    return out


def _interp_adev(allan, tau: float) -> float:
    import numpy as np

    if tau < allan.tau[0] or tau > allan.tau[-1]:
        return float("nan")
    return float(np.exp(np.interp(np.log(tau), np.log(allan.tau), np.log(allan.adev))))


@cli.command()
@click.argument("inputs", nargs=-1, required=True, type=click.Path())
@click.option(
    "--channel",
    "globs",
    multiple=True,
    metavar="GLOB",
    help="Channels to analyse, e.g. 'bmx055/gyro/*' (repeatable; default: every gyro/accel axis).",
)
@click.option(
    "--rate",
    "rate_hz",
    type=float,
    default=None,
    metavar="HZ",
    help="Sampling rate of .npy/.csv inputs (run files carry their own).",
)
@click.option(
    "--pattern",
    type=click.Choice(["log", "uniform"]),
    default="log",
    show_default=True,
    help="ML_i sampling pattern of the integrated signal.",
)
@click.option(
    "-m", "m", type=click.IntRange(8, 100000), default=1000, show_default=True, help="Number of ML_i pattern intervals."
)
@click.option(
    "--model",
    default=choices.DEFAULT_MODEL,
    show_default=True,
    help=choices.MODEL_HELP,
)
@click.option(
    "--compare-models",
    "compare",
    is_flag=True,
    help="Also fit wn+gm, wn+gm+rw and wn+2gm and report AIC/BIC (JSON key 'models').",
)
@click.option(
    "--estimator",
    type=click.Choice(choices.ESTIMATORS),
    default=choices.DEFAULT_ESTIMATOR,
    show_default=True,
    help="Estimator of the noise model reported first and in the JSON 'noise_model' block: ML_i-F (ML_i's "
    "integrated likelihood + the fine-scale Allan variance, docs/noise-model.md), ML_i or GMWM.",
)
@click.option(
    "--method",
    type=click.Choice(choices.METHODS),
    default=choices.DEFAULT_METHOD,
    show_default=True,
    help="Comparison fits also reported: ML_i (paper), GMWM (docs/gmwm.md) or both (JSON keys 'mli', 'gmwm').",
)
@click.option("--json", "as_json", is_flag=True, help="Print the imustation-analysis JSON document.")
@cluster_options
@field_options
def analyze(
    inputs: tuple[str, ...],
    globs: tuple[str, ...],
    rate_hz: float | None,
    pattern: str,
    m: int,
    model: str,
    compare: bool,
    estimator: str,
    method: str,
    as_json: bool,
    workers: int | None,
    scheduler: str | None,
    memory_limit: str,
    topic: str | None,
    time_column: str | None,
    gyro_columns: str | None,
    accel_columns: str | None,
    time_unit: str | None,
    gyro_unit: str,
) -> None:
    """Allan deviation and noise-model fit (ML_i-F; ML_i and/or GMWM beside it) of every channel of INPUTS.

    INPUTS are run files (.h5), plain rate samples (.npy, .csv; one column
    per channel, SI units, with --rate), or field recordings imported on the
    fly (ROS .bag, ROS 2 bag folders, .mcap, .tsv; a .csv log with a time
    column when --rate is not given; docs/import.md). Prints a table, or with
    --json the document described in docs/analysis-json.md.

    Every channel is one task that reads its channel from the file itself
    (a field recording is streamed into memory once, no run file written,
    and its tasks carry their samples): in this process, or in parallel with --workers N (a local dask cluster)
    or --scheduler ADDR (an existing one), with identical results. A run or
    channel that fails is reported on stderr (and under 'failures' in the
    JSON) and the others finish; the exit status is 2 only when every one
    failed (docs/fleet.md).
    """
    if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"--rate {rate_hz}: must be a positive rate in Hz")
    from imustation.analysis.estimators.mli import DEFAULT_COMPARISON
    from imustation.analysis.pipeline.parallel import AnalysisOptions

    text = text_options(time_column, gyro_columns, accel_columns, gyro_unit)
    # field recordings are streamed into memory (no run file); other inputs are read by their tasks
    tasks, failures = plan_inputs(inputs, globs, rate_hz, quiet=as_json, topic=topic, time_unit=time_unit, text=text)
    opts = AnalysisOptions(pattern, m, model, DEFAULT_COMPARISON if compare else (), method, rate_hz, estimator)
    _analyze(tasks, failures, opts, as_json, workers, scheduler, memory_limit)


def _analyze(tasks, failures, opts, as_json, workers, scheduler, memory_limit) -> None:
    """Run one task per channel (serially or on a cluster) and print the table or JSON."""
    from imustation.analysis.pipeline.channel import analysis_document

    if tasks:
        report_failures(failures)  # without tasks they make the error below
    results, failed = run_with_progress(
        tasks, opts, workers=workers, scheduler=scheduler, memory_limit=memory_limit, bar=not as_json
    )
    failures += failed
    done = [r for r in results if r is not None]
    if not done:
        if len(failures) == 1:
            raise InputError(failures[0].error)
        # each failure on its own line (a single task's was not shown while it ran), then the count
        report_failures(failures if not tasks else failed if len(tasks) == 1 else [])
        first = failures[0].error if failures else "no channels"
        raise InputError(f"every input failed ({len(failures)} failures; first: {first})")
    if as_json:
        doc = analysis_document(done)
        if failures:
            doc["failures"] = [f.as_dict() for f in failures]
        click.echo(json.dumps(doc))
    else:
        click.echo(results_table(done))
        if failures:
            click.echo(f"{len(failures)} failed (see above); {len(done)} channels analysed", err=True)
