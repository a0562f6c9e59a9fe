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


def _g(x: float, fmt: str = ".3e") -> str:
    return format(x, fmt) if math.isfinite(x) else ("inf" if x == math.inf else "-")


#: sensor kind -> the heading of its block in the text table
_KIND_TITLES = {"gyro": "gyroscopes", "accel": "accelerometers", None: "plain arrays, in their own unit"}


def results_table(results) -> str:
    """The text table of ``analyze``: one block per sensor kind, every column with its own unit.

    sigma_w and sigma_b in SI and in the display units of the paper's Table IV
    (deg/h/sqrt(Hz), deg/h/sqrt(h) for gyros; micro-g/sqrt(Hz), micro-g/sqrt(s) for
    accelerometers; imustation.units.display_units); a parameter at its search bound or
    not identified is printed as such (analysis/reports/tables.py).
    """

    from imustation.analysis.reports.tables import AT_BOUND, NOT_IDENTIFIED, param_flag
    from imustation.units import display_units, sensor_kind

    # channels of several inputs: every row starts with its input's name
    inputs = {r.channel.source: os.path.basename(r.channel.source) for r in results}
    if len(set(inputs.values())) < len(inputs):  # same file name in two folders
        inputs = {src: src for src in inputs}
    width = max(map(len, inputs.values()), default=0) if len(inputs) > 1 else 0

    def where(r) -> str:
        return f"{inputs[r.channel.source]:<{width}} " if width else ""

    def cell(fit, name: str, value: float, fmt: str) -> str:
        flag = param_flag(fit, name)
        return {AT_BOUND: "at bound", NOT_IDENTIFIED: "not ident."}.get(flag) or _g(value, fmt)

    groups: dict = {}
    for r in results:
        groups.setdefault(sensor_kind(r.channel.units, r.channel.id), []).append(r)
    lines: list[str] = []
    flagged = False
    for kind, rs in groups.items():
        dens, dens_d, kd = display_units(kind, "density")
        drift, drift_d, kb = display_units(kind, "drift")
        rate = display_units(kind, "rate")[0]
        # a channel of unknown kind (a plain array) has no display unit: those columns stay empty
        shown = kind is not None
        w_d, b_d = ("sigma_w", "sigma_b") if shown else ("", "")
        names = ("channel", "n", "fs Hz", "sigma_w", w_d, "sigma_b", b_d, "tau_b", "b_on", "ADEV(1s)", "model fit")
        units = ("", "", "", dens, dens_d if shown else "", drift, drift_d if shown else "", "s", rate, rate, "")
        widths = (22, 9, 7, 10, 9, 11, 9, 10, 10, 10, 12)
        row = "{:<22} {:>9} {:>7} {:>10} {:>9} {:>11} {:>9} {:>10} {:>10} {:>10} {:>12}  {}"
        pad = f"{'':<{width}} " if width else ""
        head = (f"{'input':<{width}} " if width else "") + row.format(*names, "fit")
        if lines:
            lines.append("")
        lines += [f"{_KIND_TITLES[kind]} ({rate})", head, pad + row.format(*units, ""), "-" * len(head)]
        for r in rs:
            adev1 = _interp_adev(r.allan, 1.0)
            fits = [f for f in (r.noise_model, r.mli, r.gmwm) if f is not None]
            fits = [f for k, f in enumerate(fits) if all(f is not g for g in fits[:k])]
            for m in fits:
                flag = "ok" if m.converged else f"! {m.message}"
                name = r.channel.id if m is r.noise_model else f"  {m.estimator}"
                sb = cell(m, "sigma_b", m.sigma_b, ".3e")
                sb_d = cell(m, "sigma_b", m.sigma_b * kb, ".4g") if shown else ""
                sw_d = _g(m.sigma_w * kd, ".4g") if shown else ""
                tb = cell(m, "tau_b", m.tau_b, ".1f")
                adq = r.adequacy_of(m)
                flagged |= any(c in ("at bound", "not ident.") for c in (sb, tb))
                lines.append(
                    where(r)
                    + row.format(
                        name[: widths[0]] if len(name) > widths[0] and m is not r.noise_model else name,
                        r.channel.n, f"{r.channel.fs_hz:g}", _g(m.sigma_w), sw_d,
                        sb, sb_d, tb, _g(m.b_on), _g(adev1), adq.verdict if adq else "-", f"{m.estimator} {flag}",
                    )
                )  # fmt: skip
            if r.choice is not None:
                lines += [where(r) + line for line in _choice_lines(r)]
            for alt in r.models:
                lines.append(where(r) + f"    {alt.model:<18} nll {alt.nll:.2f}  AIC {alt.aic:.2f}  BIC {alt.bic:.2f}")
    for r in results:
        for m in {id(f): f for f in r.blocks().values()}.values():
            adq = r.adequacy_of(m)
            if adq is not None and not adq.fits:
                lines.append(f"model fit? {r.channel.id} {m.estimator} {m.model}: {adq.summary()}")
    for r in results:
        if r.verdict is not None:
            label = f"{inputs[r.channel.source]}: {r.channel.id}" if width else r.channel.id
            lines.append(f"enough data? {label}: {r.verdict.verdict} - {'; '.join(r.verdict.reasons)}")
    if flagged:
        lines.append(
            "at bound: the fit stopped at its search bound (no estimate); not ident.: the 90 % interval is "
            "missing or spans more than two decades (--json has the numbers)"
        )
    return "\n".join(lines)


def _needed(text: str | None) -> tuple[str, ...] | None:
    """``--need`` as parameter names; InputError for a name no model has."""
    if text is None:
        return None
    import re

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if not re.fullmatch(r"B|sigma_w|sigma_k|sigma_a|(sigma_b|tau_b)\d?", n)]
    if not names or bad:
        raise InputError(f"--need {text!r}: use model parameter names (sigma_w, sigma_b, tau_b, ...) or B")
    return names


def _choice_lines(r) -> list[str]:
    """The automatic choice of one channel: chosen model with N, B, K (90 % intervals), the paper's model."""

    def nbk(fit) -> str:
        s = r.ieee952(fit)
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
    "tau_b, sigma_k, ...) and B (IEEE-952 bias instability). Default: the model's sigma_w, sigma_b, tau_b.",
)
@click.option("--warmup", default=choices.DEFAULT_WARMUP, show_default=True, help=choices.WARMUP_HELP)
@click.option("--json", "as_json", is_flag=True, help="Print the imustation-analysis JSON document.")
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

    \b
    --model, --estimator, --method:
      --model      WHAT is fitted: auto (default) or terms, e.g. wn+gm, wn+fl+rw+lp
      --estimator  HOW the reported fit is made: mli-f (default), mli, gmwm
      --method     which comparison fits are shown beside it: mli (default), gmwm, both
    Every combination works; a model with a device filter (lp) is fitted by
    ML_i on the uniform pattern (--pattern log is refused for it).
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
    from imustation.analysis.estimators.mli import DEFAULT_COMPARISON
    from imustation.analysis.pipeline.parallel import AnalysisOptions
    from imustation.analysis.pipeline.warmup import check_warmup

    text = text_options(time_column, gyro_columns, accel_columns, gyro_unit)
    # field recordings are streamed into memory (no run file); other inputs are read by their tasks
    tasks, failures = plan_inputs(inputs, globs, rate_hz, quiet=as_json, topic=topic, time_unit=time_unit, text=text)
    check_warmup(warmup)  # a bad value fails before any channel is read
    opts = AnalysisOptions(
        pattern, m, model, DEFAULT_COMPARISON if compare else (), method, rate_hz, estimator, _needed(need), warmup
    )
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
