"""``imustation analyze``: Allan deviation and noise-model fits per channel."""

from __future__ import annotations

import json
import math
import os

import click

from imustation.analysis.pipeline import choices
from imustation.cli import cli
from imustation.cli._field import field_options, plan_inputs, text_options
from imustation.cli._parallel import cluster_options, report_failures, run_with_progress
from imustation.errors import InputError


def _needed(text: str | None) -> tuple[str, ...] | None:
    """``--need`` as parameter names; InputError for a name no model has."""
    if text is None:
        return None
    import re

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if not re.fullmatch(r"B|N|K|sigma_w|sigma_k|sigma_a|(sigma_b|tau_b)\d?", n)]
    if not names or bad:
        raise InputError(f"--need {text!r}: use model parameter names (sigma_w, sigma_b, tau_b, ...), N, B or K")
    return names


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
    type=click.Choice(choices.PATTERNS),
    default=None,
    help="Sampling pattern of the integrated signal for the ML_i fits (--estimator mli, --method mli): log "
    "(the paper's; the default) or uniform (the default for a model with a device filter, lp: the log "
    "pattern's first intervals are shorter than the filter's memory, so --pattern log with lp is refused).",
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
    help="Also fit wn+gm (white noise + Gauss-Markov bias), wn+gm+rw (+ rate random walk) and wn+2gm (two "
    "Gauss-Markov biases) and report AIC/BIC (JSON key 'models').",
)
@click.option(
    "--estimator",
    type=click.Choice(choices.ESTIMATORS),
    default=choices.DEFAULT_ESTIMATOR,
    show_default=True,
    help=choices.ESTIMATOR_HELP,
)
@click.option(
    "--method",
    type=click.Choice(choices.METHODS),
    default=choices.DEFAULT_METHOD,
    show_default=True,
    help=choices.METHOD_HELP,
)
@click.option(
    "--need",
    default=None,
    metavar="NAMES",
    help="Parameters the 'enough data?' verdict judges, comma-separated: model parameters (sigma_w, sigma_b, "
    "tau_b, sigma_k, ...), B (IEEE-952 bias instability) and N, K (the ieee952 block's). Default: with --model "
    "auto N, B, K (a K not detected by its 90 % upper bound); with a given model its sigma_w, sigma_b, tau_b.",
)
@click.option("--warmup", default=choices.DEFAULT_WARMUP, show_default=True, help=choices.WARMUP_HELP)
@click.option("--json", "as_json", is_flag=True, help="Print the imustation-analysis JSON document.")
@click.option(
    "-v",
    "--verbose",
    is_flag=True,
    help="Below the table (one row per channel) and what needs attention: every fitted block (comparison "
    "fits, the automatic choice, each adequacy test) and every verdict reason. The JSON has all of it.",
)
@cluster_options
@field_options
def analyze(
    inputs: tuple[str, ...],
    globs: tuple[str, ...],
    rate_hz: float | None,
    pattern: str | None,
    m: int,
    model: str,
    compare: bool,
    estimator: str,
    method: str,
    need: str | None,
    warmup: str,
    as_json: bool,
    verbose: bool,
    workers: int | None,
    scheduler: str | None,
    memory_limit: str,
    topic: str | None,
    time_column: str | None,
    gyro_columns: str | None,
    accel_columns: str | None,
    time_unit: str | None,
    gyro_unit: str | None,
    accel_unit: str | None,
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

    \b
    --model, --estimator, --method:
      --model      WHAT is fitted: auto (default) or terms, e.g. wn+gm, wn+fl+rw+lp
      --estimator  HOW the reported fit is made: mli-f (default), mli, gmwm
      --method     which comparison fits are shown beside it: mli (default), gmwm, both
    Every combination works; a model with a device filter (lp) is fitted by
    ML_i on the uniform pattern (--pattern log is refused for it), and a
    model term the data cannot carry (lp on samples that show no filter, as
    the demo's paper-profile chips) is refused naming the reason.
    """
    if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"--rate {rate_hz}: must be a positive rate in Hz")
    ml_model = choices.PAPER_MODEL if model == choices.MODEL_AUTO else model  # the one ML_i fits
    if pattern == "log" and choices.FILTER_TERM in ml_model.split("+") and (method != "gmwm" or estimator == "mli"):
        raise InputError(
            f"--pattern log cannot fit --model {model} with ML_i: the log pattern's first intervals are shorter "
            f"than the device filter's (lp) memory; leave --pattern out (uniform is the default for lp), or "
            f"--pattern uniform"
        )
    from imustation.analysis.estimators.ml.mli import DEFAULT_COMPARISON
    from imustation.analysis.pipeline.parallel import AnalysisOptions
    from imustation.analysis.pipeline.warmup import check_warmup

    text = text_options(time_column, gyro_columns, accel_columns, gyro_unit, accel_unit)
    # field recordings are streamed into memory (no run file); other inputs are read by their tasks
    tasks, failures = plan_inputs(inputs, globs, rate_hz, quiet=as_json, topic=topic, time_unit=time_unit, text=text)
    check_warmup(warmup)  # a bad value fails before any channel is read
    opts = AnalysisOptions(
        pattern, m, model, DEFAULT_COMPARISON if compare else (), method, rate_hz, estimator, _needed(need), warmup
    )
    _analyze(tasks, failures, opts, as_json, workers, scheduler, memory_limit, verbose)


def _analyze(tasks, failures, opts, as_json, workers, scheduler, memory_limit, verbose: bool = False) -> None:
    """Run one task per channel (serially or on a cluster) and print the table or JSON."""
    from imustation.analysis.pipeline.channel import analysis_document
    from imustation.analysis.reports.analyzetable import results_table

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
        click.echo(results_table(done, verbose=verbose))
        cuts = {(r.channel.source, r.channel.meta["warmup"].device): r.channel.meta["warmup"] for r in done
                if "warmup" in r.channel.meta}  # fmt: skip
        sources = {src for src, _ in cuts}
        for (src, _), cut in cuts.items():  # what every command cuts for the same --warmup
            click.echo(f"warm-up {os.path.basename(src) + ' ' if len(sources) > 1 else ''}{cut.describe()}")
        skipped = [f for f in failures if f.skipped]
        for f in skipped:  # named in the table's output too: the table alone must say what is missing
            click.echo(f.error)
        if failures:
            counts = [f"{len(failures) - len(skipped)} failed" if len(failures) > len(skipped) else ""]
            counts.append(f"{len(skipped)} skipped" if skipped else "")
            click.echo(f"{', '.join(c for c in counts if c)} (see above); {len(done)} channels analysed", err=True)
