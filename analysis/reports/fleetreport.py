"""The fleet report: one table over many runs and devices, written to one folder.

:func:`write_fleet_report` turns the per-channel analyses of many runs (and the runs or
channels that failed) into fleet.csv, fleet.md, fleet.json, fleet.html (self-contained: the Allan
figure embedded) and fleet_allan.png, with repeatability per device, each device's run-to-run
scatter beside its runs' intervals and outliers against the fleet (the statistics are
:mod:`imustation.analysis.pipeline.fleet`'s and :mod:`~imustation.analysis.pipeline.scatter`'s, the
tables :mod:`.fleettable`'s).
"""

from __future__ import annotations

import base64
import html
import os
from collections.abc import Sequence
from dataclasses import dataclass

from imustation.analysis.pipeline.channel import ChannelAnalysis
from imustation.analysis.pipeline.fleet import (
    MIN_GROUP,
    MIN_RUN_S,
    Z_LIMIT,
    FleetRow,
    common_models,
    flag_outliers,
    repeatability,
)
from imustation.analysis.pipeline.parallel import TaskFailure
from imustation.analysis.pipeline.scatter import ALPHA, EXCEEDS, Scatter, run_scatter
from imustation.analysis.reports import plots
from imustation.analysis.reports.fleettable import fleet_csv, fleet_json, fleet_markdown, fleet_rows, relative
from imustation.analysis.reports.numbers import p_value
from imustation.analysis.reports.pages import CSS, html_table
from imustation.errors import InputError

#: what :func:`write_fleet_report` writes in its folder
FLEET_FILES = ("fleet.csv", "fleet.md", "fleet.json", "fleet.html", "fleet_allan.png")


#: left-out axes of one run and reason listed one by one on stderr up to this many (one device's six)
LEFT_OUT_AXES = 6


@dataclass(frozen=True)
class FleetReport:
    """What :func:`write_fleet_report` wrote: the folder, the table rows, the failures (in run
    order), a one-line summary and the files."""

    out_dir: str
    rows: tuple[FleetRow, ...]
    failures: tuple[TaskFailure, ...]
    summary: str
    files: tuple[str, ...]
    #: each device's run-to-run scatter per quantity (:func:`.scatter.run_scatter`)
    scatter: tuple[Scatter, ...] = ()

    def outlier_lines(self) -> list[str]:
        """One line per axis flagged against the fleet, with its robust z-scores."""
        out = []
        for r in self.rows:
            if r.outliers:
                z = ", ".join(f"{q} z {r.z[q]:+.1f}" for q in r.outliers)
                out.append(f"outlier: {r.run} {r.key} {r.sensor}/{r.axis}: {z}")
        return out

    def scatter_lines(self) -> list[str]:
        """One line per device quantity whose runs scatter more than their own intervals explain."""
        return [
            f"scatter: {s.key} {s.sensor}/{s.axis} {s.quantity}"
            + (f" ({s.model})" if s.model else "")
            + f": {s.runs} runs scatter {relative(s.scatter)} against intervals of ± {relative(s.halfwidth)} "
            f"(chi2 {s.chi2:.3g}/{s.dof}, p {p_value(s.p_value)}): {s.verdict}, excess {relative(s.excess)}"
            for s in self.scatter
            if s.verdict == EXCEEDS
        ]

    def left_out_lines(self) -> list[str]:
        """One line per run axis left out of the statistics (too short), with why; a run with more than
        :data:`LEFT_OUT_AXES` such axes of one reason gets one line for them (a 12 s run of the whole lab
        printed 31 lines; fleet.md and the CSV list every axis)."""
        groups: dict[tuple[str, str], list[FleetRow]] = {}
        for r in self.rows:
            if r.excluded:
                groups.setdefault((r.run, r.excluded), []).append(r)
        out = []
        for (run, why), rows in groups.items():
            if len(rows) > LEFT_OUT_AXES:
                out.append(f"left out: {run}: {len(rows)} axes of {len({r.key for r in rows})} devices: {why}")
            else:
                out += [f"left out: {run} {r.key} {r.sensor}/{r.axis}: {why}" for r in rows]
        return out

    def summary_line(self) -> str:
        """The summary and where the files are."""
        return f"{self.summary} -> {self.out_dir}/fleet.{{csv,md,json,html}}, fleet_allan.png"


def fleet_page(md: str, png: bytes, summary: str) -> str:
    """Self-contained HTML: the Markdown tables as HTML and the Allan figure embedded as base64 PNG."""
    img = base64.b64encode(png).decode("ascii")
    rule = (
        f"Values: the noise-model fit (σ_w, σ_b, τ_b) and the IEEE-952 terms that model implies (N, B, K: the "
        "numbers analyze, report, the verdict and export give), each with its 90 % interval; “< x”: the 90 % "
        "upper bound of a term the run does not show. "
        f"Outliers: robust z = (x − median)/√(s² + se²) of log10 σ_w (= N), B, K, σ_b, τ_b, s = MAD/0.6745 of every "
        f"run of the same driver, sensor and axis (and model, for σ_b and τ_b), se the run's own, from its 90 % "
        f"interval; |z| > {Z_LIMIT:g} is flagged (groups of at least {MIN_GROUP} estimates); a B or K a run does not "
        f"show (an upper bound) is no candidate. Runs shorter than {MIN_RUN_S:g} s or a tenth of their group's "
        "median length are listed and left out. Scatter: per device, the spread of its runs beside their own "
        f"intervals; it exceeds them when Cochran's χ² gives p < {ALPHA:g}."
    )
    return (
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>imustation fleet</title>"
        f"<style>{CSS}</style></head><body><h1>Fleet noise report</h1><p>{html.escape(summary)}</p>"
        f"<p>{html.escape(rule)}</p>"
        f'<figure><img src="data:image/png;base64,{img}" alt="fleet Allan deviation">'
        '<figcaption>Allan deviation of every run, one panel per axis group (<a href="fleet_allan.png">PNG</a>); '
        'outliers in colour. Tables: <a href="fleet.csv">fleet.csv</a>, <a href="fleet.md">fleet.md</a>.'
        "</figcaption></figure>" + html_table(md) + "</body></html>\n"
    )


def write_fleet_report(
    runs: Sequence[str],
    results: Sequence[ChannelAnalysis | None],
    failures: Sequence[TaskFailure],
    out_dir: str,
) -> FleetReport:
    """Write the fleet report of ``results`` (None where a task failed) in ``out_dir``.

    ``runs``: the run paths in the order given, which orders the failures. Raises
    :class:`InputError` when every run failed.
    """
    order = {p: i for i, p in enumerate(runs)}
    failures = sorted(failures, key=lambda f: (order.get(f.path, len(order)), f.channel or ""))
    done = [r for r in results if r is not None]
    if not done:
        first = failures[0].error if failures else "no channels"
        raise InputError(f"every run failed ({len(failures)} failures; first: {first})")
    done = common_models(done)  # with --model auto: one model per driver, sensor and axis
    rows = flag_outliers(fleet_rows(done))
    rep = repeatability(rows)
    scatter = run_scatter(rows)
    os.makedirs(out_dir, exist_ok=True)
    md = fleet_markdown(rows, rep, failures, scatter)
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
    n_left = sum(1 for r in rows if r.excluded)
    n_scatter = sum(1 for s in scatter if s.verdict == EXCEEDS)
    summary = (
        f"{len(rows)} axes of {n_runs} runs, {len({r.key for r in rows})} devices; "
        f"{n_out} outlier axes; {n_scatter} device quantities scatter beyond their runs' intervals; "
        f"{n_left} axes left out (too short); {len(failures)} failures"
    )
    files = [png_path]
    for name, text in (
        ("fleet.csv", fleet_csv(rows, failures)),
        ("fleet.md", md),
        ("fleet.json", fleet_json(rows, rep, scatter, failures)),
        ("fleet.html", fleet_page(md, png, summary)),
    ):
        path = os.path.join(out_dir, name)
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(text)
        files.append(path)
    return FleetReport(out_dir, tuple(rows), tuple(failures), summary, tuple(files), tuple(scatter))
