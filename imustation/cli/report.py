"""``imustation report``: noise tables, figures and one HTML page per run."""

from __future__ import annotations

import dataclasses
import html
import os

import click

from imustation.cli import cli
from imustation.errors import InputError
from imustation.units import format_duration, parse_duration

#: bias block length of the temperature figure and regression, s
BIAS_BLOCK_S = 60.0


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-." else "_" for c in text)


def _exclude_start(ch, n0: int) -> None:
    """Drop the first ``n0`` samples from the channel's segments (warm-up)."""
    segs = [(max(a, n0), b) for a, b in ch.segments if b > n0]
    if not segs:
        raise InputError(f"{ch.id}: the warm-up exclusion ({format_duration(n0 / ch.fs_hz)}) leaves no data")
    ch.segments = segs


def _html_table(rows_md: str) -> str:
    """The Markdown tables of :func:`table_markdown` as HTML."""
    out, in_table = [], False
    for line in rows_md.splitlines():
        if line.startswith("**"):
            out.append(f"<h3>{html.escape(line.strip('*'))}</h3>")
        elif line.startswith("|---"):
            continue
        elif line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            tag = "td" if in_table else "th"
            if not in_table:
                out.append("<table>")
                in_table = True
            out.append("<tr>" + "".join(f"<{tag}>{html.escape(c)}</{tag}>" for c in cells) + "</tr>")
        elif in_table:
            out.append("</table>")
            in_table = False
    if in_table:
        out.append("</table>")
    return "\n".join(out)


_CSS = (
    "body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
    "table{border-collapse:collapse;font-size:12px;margin-bottom:1em}"
    "td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}"
    "img{max-width:100%;border:1px solid #ddd;margin:4px 0}figcaption{font-size:12px;color:#444}"
)


def _figure_html(name: str, caption: str) -> str:
    return (
        f'<figure><img src="{html.escape(name)}.png" alt="{html.escape(name)}">'
        f'<figcaption>{html.escape(caption)} (<a href="{html.escape(name)}.pdf">PDF</a>)</figcaption></figure>'
    )


def report_run(path: str, out_dir: str, globs: tuple[str, ...], model: str, warmup: str) -> tuple[list[str], list]:
    """Analyse one run and write its tables, figures and ``index.html``; returns the files written and table rows."""
    from imustation.analysis.pipeline.channel import analyze_channel
    from imustation.analysis.pipeline.loaders import load_run
    from imustation.analysis.reports import plots
    from imustation.analysis.reports.tables import noise_rows, table_csv, table_latex, table_markdown, units_of
    from imustation.analysis.reports.temperature import (
        detect_warmup,
        device_temperature,
        fit_tempco,
        thermometer_temperature,
    )
    from imustation.runfile import open_run

    os.makedirs(out_dir, exist_ok=True)
    channels = load_run(path, globs)
    with open_run(path) as run:
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
    # warm-up: per device, from its own temperature when 'auto'
    excluded: dict[str, float] = {}
    for ch in channels:
        dev = ch.meta["device"]
        if dev not in excluded:
            if warmup == "auto":
                excluded[dev] = detect_warmup(*temps[dev]) if dev in temps else 0.0
            else:
                excluded[dev] = 0.0 if warmup in ("0", "none") else parse_duration(warmup)
        if excluded[dev] > 0:
            _exclude_start(ch, int(round(excluded[dev] * ch.fs_hz)))
    results = []
    for ch in channels:
        click.echo(f"analysing {ch.id} ({ch.n} samples) ...", err=True)
        results.append(analyze_channel(ch, model=model))
    rows = noise_rows(results)
    for name, text in (
        ("noise.csv", table_csv(rows)),
        ("noise.md", table_markdown(rows)),
        ("noise.tex", table_latex(rows)),
    ):
        p = os.path.join(out_dir, name)
        with open(p, "w", encoding="utf-8") as fh:
            fh.write(text)
        written.append(p)
    sections.append("<h2>Noise table</h2>" + _html_table(table_markdown(rows)))
    sections.append(
        '<p>Files: <a href="noise.csv">noise.csv</a>, <a href="noise.md">noise.md</a>, '
        '<a href="noise.tex">noise.tex</a>. σ_w, σ_b, τ_b: ML_i fit of the '
        f"{html.escape(model)} model; N, B, K: IEEE-952 fit of the Allan deviation; σ(1 s): measured.</p>"
    )

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
        return _figure_html(name, caption)

    tempco_rows = []
    figs = []
    by_group: dict[tuple[str, str], list] = {}
    for res in results:
        ch = res.channel
        dev = ch.meta["device"]
        by_group.setdefault((dev, ch.id.split("/")[1]), []).append(res)
        settings = plots.settings_line(ch, span(dev))
        slug = _slug(ch.id)
        figs.append(save(plots.allan_figure(res, settings), f"allan_{slug}", f"Allan deviation of {ch.id}: {settings}"))
        figs.append(save(plots.psd_figure(res, settings), f"psd_{slug}", f"PSD near Nyquist of {ch.id}: {settings}"))
        if ch.id.split("/")[1] == "gyro":
            cap = f"attitude-error growth of {ch.id}: {settings}"
            figs.append(save(plots.attitude_figure(res, settings), f"attitude_{slug}", cap))
    for (dev, sensor), group in by_group.items():
        if len(group) > 1:
            settings = plots.settings_line(group[0].channel, span(dev))
            name = f"allan_{_slug(dev)}_{sensor}"
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
        si_unit = units_of(sensor, "B")[0]
        biases = []
        for r in group:
            ch = r.channel
            bt, b = plots.bias_track(ch.data, ch.fs_hz, BIAS_BLOCK_S, ch.scale)
            keep = bt >= excluded.get(dev, 0.0)
            biases.append((ch.id, bt, (b - b[keep].mean() if keep.any() else b) * factor))
            for src, t, c in srcs:
                try:
                    tc = fit_tempco(bt[keep], b[keep], t, c)
                    tempco_rows.append((ch.id, src, tc, factor, disp_unit, si_unit))
                except InputError as exc:
                    tempco_rows.append((ch.id, src, None, factor, disp_unit, str(exc)))
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
        name = f"temperature_{_slug(dev)}_{sensor}"
        figs.append(save(fig, name, f"{src} temperature and {sensor} bias of {dev}: {settings}"))
    if tempco_rows:
        lines = [
            "<h2>Bias temperature coefficient</h2><table><tr><th>channel</th><th>temperature</th>"
            "<th>slope [SI/K]</th><th>slope [display/K]</th><th>± (OLS, lower bound)</th><th>span [K]</th>"
            "<th>R²</th></tr>"
        ]
        for cid, src, tc, factor, disp, si in tempco_rows:
            cells = f"<tr><td>{html.escape(cid)}</td><td>{html.escape(src)}</td>"
            if tc is None:
                lines.append(cells + f"<td colspan=5>{html.escape(si)}</td></tr>")
                continue
            lines.append(
                cells + f"<td>{tc.slope:.3g} {html.escape(si)}/K</td>"
                f"<td>{tc.slope * factor:.3g} {html.escape(disp)}/K</td><td>{tc.slope_stderr * factor:.2g}</td>"
                f"<td>{tc.span_c:.2f}</td><td>{tc.r2:.2f}</td></tr>"
            )
        sections.append("\n".join(lines) + "</table>")
    sections.append("<h2>Figures</h2>" + "\n".join(figs))
    warm = ", ".join(f"{d}: {format_duration(s) if s > 0 else 'none'}" for d, s in excluded.items())
    esc = html.escape
    name = esc(os.path.basename(path))
    att = {k: esc(str(run_attrs.get(k, d))) for k, d in (("station", ""), ("started_utc", ""), ("ended_utc", "open"))}
    head = (
        f"<p>Run file: {esc(os.path.abspath(path))}<br>station {att['station']}, started {att['started_utc']}, "
        f"ended {att['ended_utc']}{', simulated' if run_attrs.get('simulated') else ''}<br>"
        f"warm-up excluded ({esc(warmup)}): {esc(warm)}</p>"
    )
    page = (
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'>"
        f"<title>imustation report — {name}</title><style>{_CSS}</style></head><body>"
        f"<h1>Noise report — {name}</h1>" + head + "\n".join(sections) + "</body></html>\n"
    )
    p = os.path.join(out_dir, "index.html")
    with open(p, "w", encoding="utf-8") as fh:
        fh.write(page)
    written.append(p)
    return written, rows


@cli.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out_dir", required=True, help="Directory for the report (one folder per run).")
@click.option(
    "--channel", "globs", multiple=True, metavar="GLOB", help="Channels to report (default: gyro/accel axes)."
)
@click.option("--model", default="wn+gm", show_default=True, help="ML_i noise model.")
@click.option(
    "--warmup",
    default="auto",
    show_default=True,
    help="Start of the record to exclude: 'auto' (from the device temperature), 0, or a duration such as 1h.",
)
def report(runs: tuple[str, ...], out_dir: str, globs: tuple[str, ...], model: str, warmup: str) -> None:
    """Noise tables (CSV, Markdown, LaTeX), Allan/PSD/temperature figures (PNG, PDF) and an HTML page per run.

    Writes OUTPUT/<run name>/index.html with relative links to its tables and
    figures (self-contained folder, no network), plus OUTPUT/noise.* over all runs.
    """
    if warmup not in ("auto", "0", "none"):
        parse_duration(warmup)
    from imustation.analysis.reports.tables import table_csv, table_latex, table_markdown

    all_rows = []
    for path in runs:
        if not path.lower().endswith((".h5", ".hdf5")):
            raise InputError(f"{path}: report needs run files (.h5)")
        stem = _slug(os.path.splitext(os.path.basename(path))[0])
        written, rows = report_run(path, os.path.join(out_dir, stem), globs, model, warmup)
        click.echo(f"{path}: {len(written)} files in {os.path.join(out_dir, stem)}")
        all_rows += [dataclasses.replace(r, device=f"{stem}:{r.device}") for r in rows]
    if len(runs) > 1:  # one table over every run, devices named run:device
        for name, fn in (("noise.csv", table_csv), ("noise.md", table_markdown), ("noise.tex", table_latex)):
            with open(os.path.join(out_dir, name), "w", encoding="utf-8") as fh:
                fh.write(fn(all_rows))
