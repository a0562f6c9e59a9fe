"""The report of one run: noise tables, figures and an HTML page, written to one folder.

:func:`report_run` analyses every selected channel of a run file (after cutting each
device's warm-up: from its own temperature with ``"auto"``, or a given duration), and
writes the summary (one row per sensor axis: N, B, K, the bias model with intervals and
the verdicts), the noise tables (CSV, Markdown, LaTeX), Allan/PSD/attitude/temperature
figures (PNG, PDF), the bias temperature coefficients (``tempco.csv``: all of them) and
``index.html``: the summary first, then the figures, then the details (the noise table
and the temperature coefficients that pass the autocorrelation-aware significance test),
with relative links (a self-contained folder, no network). :func:`report_runs` does so for
several runs, one folder each, plus one table over all of them (docs/reports.md).
"""

from __future__ import annotations

import dataclasses
import html
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from imustation.analysis.estimators.classical.temperature import TEMPCO_FAMILY_ALPHA, fit_tempco, holm
from imustation.analysis.pipeline.channel import DegenerateChannel, analyze_channel
from imustation.analysis.pipeline.choices import DEFAULT_MODEL
from imustation.analysis.pipeline.loaders import device_temperature, load_run, thermometer_temperature
from imustation.analysis.pipeline.warmup import check_warmup, cut_channels
from imustation.analysis.reports import plots
from imustation.analysis.reports.pages import CSS, figure_html, html_table
from imustation.analysis.reports.summary import summary_csv, summary_markdown, summary_rows
from imustation.analysis.reports.tables import (
    NoiseRow,
    TempcoRow,
    noise_rows,
    table_csv,
    table_latex,
    table_markdown,
    tempco_csv,
    tempco_markdown,
    units_of,
)
from imustation.errors import InputError
from imustation.outputs import check_folder, fresh_folder
from imustation.runfile import open_series

#: bias block length of the temperature figure and regression, s
BIAS_BLOCK_S = 60.0
#: the noise tables written per run and over several runs
TABLES = (("noise.csv", table_csv), ("noise.md", table_markdown), ("noise.tex", table_latex))

#: under the summary table of the page
SUMMARY_LEGEND = (
    "<p>One row per sensor axis, in the display units of its sensor (gyroscopes °/h/√Hz, °/h, °/h/√h; "
    "accelerometers µg/√Hz, µg, µg/√s; SI in summary.csv), each value with its 90 % interval in brackets. "
    "N: white-noise density σ_w of the {estimator} fit of the {model} model; B, K: bias instability and rate "
    "random walk the noise model implies (its IEEE-952 terms; &lt; x: a 90 % upper bound where the record "
    "does not show the term); σ_b, τ_b: the bias model (Gauss-Markov: density of its driving noise "
    "and correlation time). —: not fitted or not given by the analysis; at bound: the fit stopped at its search "
    "bound; not identified: the 90 % interval is missing or spans more than two decades. fit: the model-adequacy "
    "verdict; enough data?: the record-length verdict (docs/import.md).</p>"
)
#: under the temperature coefficients of the page
TEMPCO_NOTE = (
    "<p>{shown} of {total} coefficients are listed: those that pass a significance test accounting for "
    "autocorrelated bias and temperature, at a family-wise level of {family:g} over the {tested} tested (Holm). "
    "The test inflates the OLS standard error by the effective number of independent 60 s blocks, "
    "n_eff = n / (1 + 2 Σ_k r_T(k) r_e(k)), from the autocorrelations of the temperature and of the residuals "
    "(Bretherton et al. 1999); a slow bias wander otherwise \u201cexplains\u201d a slow temperature drift. Every "
    'coefficient, with its test, is in <a href="tempco.csv">tempco.csv</a>.</p>'
)

#: receives one line of progress (a channel being analysed)
Progress = Callable[[str], None]


@dataclass(frozen=True)
class RunReport:
    """What :func:`report_run` wrote: the run file, its report folder, the files written,
    the noise-table rows and the warm-up cut per device (s)."""

    path: str
    folder: str
    files: tuple[str, ...]
    rows: tuple[NoiseRow, ...]
    warmup_s: dict[str, float]
    #: channels not analysed, each with its reason (degenerate: constant, stuck, ...)
    skipped: tuple[str, ...] = ()

    def summary(self) -> str:
        """One line for the operator: the run and where its report is (and how many channels were skipped)."""
        skip = f" ({len(self.skipped)} channels skipped)" if self.skipped else ""
        return f"{self.path}: {len(self.files)} files in {self.folder}{skip}"


def slug(text: str) -> str:
    """``text`` as a file-name part: letters, digits, ``-`` and ``.`` kept, the rest ``_``."""
    return "".join(c if c.isalnum() or c in "-." else "_" for c in text)


def _write(path: str, text: str) -> str:
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text)
    return path


def write_tables(rows: Sequence[NoiseRow], folder: str) -> list[str]:
    """Write noise.csv, noise.md and noise.tex of ``rows`` in ``folder``; returns their paths."""
    written = []
    for name, fn in TABLES:
        p = os.path.join(folder, name)
        with open(p, "w", encoding="utf-8") as fh:
            fh.write(fn(list(rows)))
        written.append(p)
    return written


def report_run(
    path: str,
    out_dir: str,
    *,
    globs: Sequence[str] = (),
    model: str = DEFAULT_MODEL,
    warmup: str = "auto",
    progress: Progress | None = None,
) -> RunReport:
    """Analyse the run file ``path`` and write its tables, figures and ``index.html`` in ``out_dir``.

    ``globs``: channels to report (default: every gyro/accel axis); ``model``: the noise
    model fitted; ``warmup``: ``"auto"``, ``"0"``/``"none"`` or a duration (``"20m"``),
    cut from the start of every device; ``progress`` gets a line per channel analysed.
    """
    check_warmup(warmup)
    if not path.lower().endswith((".h5", ".hdf5")):
        raise InputError(f"{path}: report needs run files (.h5)")
    os.makedirs(out_dir, exist_ok=True)
    channels = load_run(path, globs)
    with open_series(path) as run:
        run_attrs = dict(run.attrs)
        temp_devices = [d for d, info in run.devices.items() if "temp" in info.channels and info.n > 0]
        thermometer_names = list(run.thermometers)
    temps = {d: device_temperature(path, d) for d in temp_devices}
    therms = {}
    for name in thermometer_names:
        t, c = thermometer_temperature(path, name)
        if len(t) >= 2:
            therms[name] = (t, c)
    written: list[str] = []
    sections: list[str] = []
    # warm-up: the cut every command makes for this option (analysis/pipeline/warmup.py)
    cuts = cut_channels(channels, warmup)
    excluded = {dev: cut.cut_s for dev, cut in cuts.items()}
    results = []
    skipped: list[str] = []
    for ch in channels:
        if progress is not None:
            progress(f"analysing {ch.id} ({ch.n} samples) ...")
        try:
            results.append(analyze_channel(ch, model=model))
        except DegenerateChannel as exc:  # named with its reason; the other channels go on
            skipped.append(str(exc))
            ch.release()
            if progress is not None:
                progress(str(exc))
    rows = noise_rows(results)
    written += write_tables(rows, out_dir)
    summary = summary_rows(results)
    for name, text in (("summary.csv", summary_csv(summary)), ("summary.md", summary_markdown(summary))):
        written.append(_write(os.path.join(out_dir, name), text))
    estimator = results[0].noise_model.estimator if results else ""
    sections.append("<h2>Summary</h2>" + (html_table(summary_markdown(summary)) if results else
                    "<p>No channel could be analysed.</p>") + SUMMARY_LEGEND.format(
        estimator=html.escape(estimator), model=html.escape(model)))  # fmt: skip
    if skipped:
        items = "".join(f"<li>{html.escape(s)}</li>" for s in skipped)
        sections.append(f"<h2>Skipped channels</h2><ul>{items}</ul>")
    details = [
        "<h2>Details</h2><h3>Noise table (Table IV layout)</h3>" + html_table(table_markdown(rows)),
        '<p>Files: <a href="noise.csv">noise.csv</a>, <a href="noise.md">noise.md</a>, '
        f'<a href="noise.tex">noise.tex</a>. σ_w, σ_b, τ_b: {html.escape(estimator)} fit of the '
        f"{html.escape(model)} model; N, B, K: the IEEE-952 terms that model implies (as in the summary), "
        "with their 90 % interval, “< x” the 90 % upper bound of a term the record does not show; σ(1 s): "
        "measured. Under each table, for comparison only, the classical IEEE-952 fit of the Allan curve. "
        "—: not fitted (no such term in the model; in the comparison, the Allan fit did not need it); "
        "at bound: the fit stopped at its search bound; "
        "not identified: the 90 % interval is missing or spans more than two decades; doubtful: σ_w's 90 % "
        "interval spans more than a factor 1.1, because slow terms reach the fine scales (σ_w and N of that axis "
        "rest on a shape nothing measures; the summary gives the interval, docs/noise-model.md “Intervals”). "
        "Model fit: does the fitted model explain the measured Allan variance within its sampling "
        "uncertainty, correlations across τ included (a generalised χ² test at 1 %, docs/noise-model.md "
        "“Model adequacy”); where it does not, the τ ranges and whether the model is low or high there "
        "(the residual panel under each Allan plot).</p>",
    ]

    def sources(dev):
        """Temperatures to show and regress on: the device's own, then the room thermometers."""
        own = [("internal", *temps[dev])] if dev in temps else []
        return own + [(name, t, c) for name, (t, c) in therms.items()]

    def span(dev):
        if not sources(dev):
            return None
        _, t, c = sources(dev)[0]
        keep = t >= excluded.get(dev, 0.0)
        return (float(c[keep].min()), float(c[keep].max())) if keep.any() else None

    def save(fig, name, caption):
        written.extend(plots.save_figure(fig, os.path.join(out_dir, name)))
        return figure_html(name, caption)

    tempco_rows = []
    figs = []
    by_group: dict[tuple[str, str], list] = {}
    for res in results:
        ch = res.channel
        dev = ch.meta["device"]
        by_group.setdefault((dev, ch.id.split("/")[1]), []).append(res)
        settings = plots.settings_line(ch, span(dev))
        name_id = slug(ch.id)
        figs.append(
            save(plots.allan_figure(res, settings), f"allan_{name_id}", f"Allan deviation of {ch.id}: {settings}")
        )
        figs.append(save(plots.psd_figure(res, settings), f"psd_{name_id}", f"PSD near Nyquist of {ch.id}: {settings}"))
        if ch.id.split("/")[1] == "gyro":
            cap = f"attitude-error growth of {ch.id}: {settings}"
            figs.append(save(plots.attitude_figure(res, settings), f"attitude_{name_id}", cap))
    for (dev, sensor), group in by_group.items():
        if len(group) > 1:
            settings = plots.settings_line(group[0].channel, span(dev))
            name = f"allan_{slug(dev)}_{sensor}"
            figs.append(
                save(plots.allan_multi_figure(group, f"Allan deviation — {dev} {sensor}", settings), name, settings)
            )
    gyros = [r for r in results if r.channel.id.split("/")[1] == "gyro"]
    if len({r.channel.meta["device"] for r in gyros}) > 1:  # Fig. 8: the devices side by side
        fig = plots.allan_multi_figure(gyros, "Allan deviation — all gyroscopes")
        figs.append(save(fig, "allan_all_gyro", "all gyroscopes of the run"))
    for (dev, sensor), group in by_group.items():
        srcs = sources(dev)
        if not srcs:
            continue
        _, disp_unit, factor = units_of(sensor, "B")
        biases = []
        for r in group:
            ch = r.channel
            bt, b = plots.bias_track(ch.data, ch.fs_hz, BIAS_BLOCK_S, ch.scale)
            keep = bt >= excluded.get(dev, 0.0)
            biases.append((ch.id, bt, (b - b[keep].mean() if keep.any() else b) * factor))
            for src, t, c in srcs:
                try:
                    tempco_rows.append(TempcoRow(ch.id, sensor, src, fit_tempco(bt[keep], b[keep], t, c)))
                except InputError as exc:
                    tempco_rows.append(TempcoRow(ch.id, sensor, src, None, str(exc)))
            ch.release()
        src, t, c = srcs[0]
        settings = plots.settings_line(group[0].channel, span(dev))
        fig = plots.temperature_figure(
            t,
            c,
            biases,
            label=f"{dev} {sensor} ({src} temperature)",
            bias_unit=disp_unit + " (mean removed)",
            settings=settings,
            warmup_s=excluded.get(dev, 0.0),
        )
        name = f"temperature_{slug(dev)}_{sensor}"
        figs.append(save(fig, name, f"{src} temperature and {sensor} bias of {dev}: {settings}"))
    if tempco_rows:
        tested = [r for r in tempco_rows if r.result is not None]
        listed = holm(np.array([r.result.p_value for r in tested]), TEMPCO_FAMILY_ALPHA)
        keep = {id(r) for r, ok in zip(tested, listed, strict=True) if ok}
        tempco_rows = [dataclasses.replace(r, listed=id(r) in keep) for r in tempco_rows]
        written.append(_write(os.path.join(out_dir, "tempco.csv"), tempco_csv(tempco_rows)))
        shown = tempco_markdown(tempco_rows)
        details.append(
            "<h3>Bias temperature coefficients</h3>" + (html_table(shown) if shown else "")
            + TEMPCO_NOTE.format(shown=len(keep), total=len(tempco_rows), tested=len(tested),
                                 family=TEMPCO_FAMILY_ALPHA)
        )  # fmt: skip
    sections.append("<h2>Figures</h2>" + "\n".join(figs))
    sections += details
    warm = "; ".join(cut.describe() for cut in cuts.values())
    esc = html.escape
    name = esc(os.path.basename(path))
    att = {k: esc(str(run_attrs.get(k, d))) for k, d in (("station", ""), ("started_utc", ""), ("ended_utc", "open"))}
    head = (
        f"<p>Run file: {esc(os.path.abspath(path))}<br>station {att['station']}, started {att['started_utc']}, "
        f"ended {att['ended_utc']}{', simulated' if run_attrs.get('simulated') else ''}<br>"
        f"warm-up (--warmup {esc(warmup)}): {esc(warm)}</p>"
    )
    page = (
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'>"
        f"<title>imustation report — {name}</title><style>{CSS}</style></head><body>"
        f"<h1>Noise report — {name}</h1>" + head + "\n".join(sections) + "</body></html>\n"
    )
    p = os.path.join(out_dir, "index.html")
    with open(p, "w", encoding="utf-8") as fh:
        fh.write(page)
    written.append(p)
    return RunReport(path, out_dir, tuple(written), tuple(rows), excluded, tuple(skipped))


def report_runs(
    paths: Sequence[str],
    out_dir: str,
    *,
    globs: Sequence[str] = (),
    model: str = DEFAULT_MODEL,
    warmup: str = "auto",
    progress: Progress | None = None,
    on_report: Callable[[RunReport], None] | None = None,
    overwrite: bool = False,
) -> list[RunReport]:
    """:func:`report_run` for every run, each in ``out_dir/<run name>``; with several runs also
    noise.csv/.md/.tex over all of them in ``out_dir`` (devices named ``run:device``).

    ``on_report`` gets each run's :class:`RunReport` as soon as it is written. Before any
    analysis ``out_dir`` is checked (:func:`~imustation.outputs.check_folder`: a run's folder
    or the tables over all runs that exist are refused unless ``overwrite``); a run that
    fails leaves no folder of its own behind, and ``out_dir`` only if something is in it.
    """
    check_warmup(warmup)  # a bad value fails before the first run is analysed
    folders = [slug(os.path.splitext(os.path.basename(path))[0]) for path in paths]
    twice = sorted({f for f in folders if folders.count(f) > 1})
    if twice:
        raise InputError(f"{', '.join(paths)}: two runs would share the report folder {twice[0]}; rename one")
    tables = [name for name, _ in TABLES] if len(paths) > 1 else []
    check_folder(out_dir, overwrite=overwrite, writes=[*folders, *tables])
    reports = []
    with fresh_folder(out_dir, discard=False):
        for path, stem in zip(paths, folders, strict=True):
            with fresh_folder(os.path.join(out_dir, stem)) as folder:
                rep = report_run(path, folder, globs=globs, model=model, warmup=warmup, progress=progress)
            reports.append(rep)
            if on_report is not None:
                on_report(rep)
    if len(reports) > 1:
        stems = [os.path.basename(r.folder) for r in reports]
        write_tables(
            [dataclasses.replace(row, device=f"{stem}:{row.device}") for stem, r in zip(stems, reports, strict=True)
             for row in r.rows],
            out_dir,
        )  # fmt: skip
    return reports
