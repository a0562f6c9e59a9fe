"""``imustation fleet``: one noise table over many runs and devices, repeatability, outliers."""

from __future__ import annotations

import base64
import html
import os

import click

from imustation.cli import cli
from imustation.cli._parallel import cluster_options, execute, report_failures
from imustation.cli.report import _CSS, _html_table
from imustation.errors import InputError


def _page(md: str, png: bytes, summary: str) -> str:
    """Self-contained HTML: the Markdown tables as HTML and the Allan figure embedded as base64 PNG."""
    from imustation.analysis.pipeline.fleet import MIN_GROUP, Z_LIMIT

    img = base64.b64encode(png).decode("ascii")
    rule = (
        f"Outliers: robust z = 0.6745 (x − median)/MAD of log10 σ_w, σ_b, τ_b against every run of the same "
        f"driver, sensor and axis; |z| > {Z_LIMIT:g} is flagged (groups of at least {MIN_GROUP} runs). "
        "Values: ML_i fit of the standard model (σ_w, σ_b, τ_b), IEEE-952 Allan fit (N, B, K), ± standard error."
    )
    return (
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>imustation fleet</title>"
        f"<style>{_CSS}</style></head><body><h1>Fleet noise report</h1><p>{html.escape(summary)}</p>"
        f"<p>{html.escape(rule)}</p>"
        f'<figure><img src="data:image/png;base64,{img}" alt="fleet Allan deviation">'
        '<figcaption>Allan deviation of every run, one panel per axis group (<a href="fleet_allan.png">PNG</a>); '
        'outliers in colour. Tables: <a href="fleet.csv">fleet.csv</a>, <a href="fleet.md">fleet.md</a>.'
        "</figcaption></figure>" + _html_table(md) + "</body></html>\n"
    )


@cli.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path())
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False), help="Output directory.")
@click.option(
    "--channel", "globs", multiple=True, metavar="GLOB", help="Channels to include (default: every gyro/accel axis)."
)
@click.option("--model", default="wn+gm", show_default=True, help="ML_i noise model (sigma_w, sigma_b, tau_b).")
@cluster_options
def fleet(
    runs: tuple[str, ...],
    out_dir: str,
    globs: tuple[str, ...],
    model: str,
    workers: int | None,
    scheduler: str | None,
    memory_limit: str,
) -> None:
    """One noise table over every run and device of RUNS (run files), with repeatability and outliers.

    \b
    Writes OUTPUT/fleet.csv, fleet.md, fleet.html (self-contained) and
    fleet_allan.png: per run and axis the device identity, ML_i sigma_w,
    sigma_b, tau_b and IEEE-952 N, B, K with standard errors and 90 %
    intervals; per device and axis the mean and std over its runs (Table III);
    runs flagged against the fleet (robust z > 3.5). Channels are analysed
    in parallel with --workers N or --scheduler ADDR (docs/fleet.md). A run
    that fails is reported and listed; the exit status is 2 only when every
    run failed.
    """
    from imustation.analysis.pipeline.fleet import flag_outliers, fleet_csv, fleet_markdown, fleet_rows, repeatability
    from imustation.analysis.pipeline.parallel import AnalysisOptions, plan_tasks
    from imustation.analysis.reports import plots

    tasks, failures = plan_tasks(runs, globs)
    report_failures(failures)
    results, failed = execute(
        tasks, AnalysisOptions(model=model), workers=workers, scheduler=scheduler, memory_limit=memory_limit
    )
    order = {p: i for i, p in enumerate(runs)}
    failures = sorted(failures + failed, key=lambda f: (order.get(f.path, len(order)), f.channel or ""))
    done = [r for r in results if r is not None]
    if not done:
        first = failures[0].error if failures else "no channels"
        raise InputError(f"every run failed ({len(failures)} failures; first: {first})")
    rows = flag_outliers(fleet_rows(done))
    rep = repeatability(rows)
    os.makedirs(out_dir, exist_ok=True)
    md = fleet_markdown(rows, rep, failures)
    curves = [
        (f"{r.driver} {r.sensor} {r.axis}", r.sensor, f"{r.key} ({os.path.basename(r.run)})", res.allan.tau,
         res.allan.adev, bool(r.outliers))
        for r, res in zip(rows, done, strict=True)
    ]  # fmt: skip
    png_path = os.path.join(out_dir, "fleet_allan.png")
    plots.fleet_allan_figure(curves).savefig(png_path, dpi=110)
    with open(png_path, "rb") as fh:
        png = fh.read()
    n_runs = len({r.run for r in rows})
    n_out = sum(1 for r in rows if r.outliers)
    summary = (
        f"{len(rows)} axes of {n_runs} runs, {len({r.key for r in rows})} devices; "
        f"{n_out} outlier axes; {len(failures)} failures"
    )
    for name, text in (
        ("fleet.csv", fleet_csv(rows, failures)),
        ("fleet.md", md),
        ("fleet.html", _page(md, png, summary)),
    ):
        with open(os.path.join(out_dir, name), "w", encoding="utf-8") as fh:
            fh.write(text)
    for r in rows:
        if r.outliers:
            z = ", ".join(f"{q} z {r.z[q]:+.1f}" for q in r.outliers)
            click.echo(f"outlier: {r.run} {r.key} {r.sensor}/{r.axis}: {z}", err=True)
    click.echo(f"{summary} -> {out_dir}/fleet.{{csv,md,html}}, fleet_allan.png")
