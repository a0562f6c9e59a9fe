"""The fleet table: one row per analysed axis of every run, as CSV and Markdown.

:func:`fleet_rows` builds :class:`~imustation.analysis.pipeline.fleet.FleetRow` from the noise
table's rows (so the fleet flags values as the per-run table does); :func:`fleet_csv` and
:func:`fleet_markdown` render them with the repeatability, outliers and failures. The statistics
(outliers, repeatability, one model per group) are :mod:`imustation.analysis.pipeline.fleet`'s.
Builders return text; writing files is :mod:`.fleetreport`'s business.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence

from imustation.analysis.pipeline.channel import ChannelAnalysis
from imustation.analysis.pipeline.fleet import (
    FLEET_QUANTITIES,
    MODEL_QUANTITIES,
    Z90,
    Z_LIMIT,
    FleetRow,
    RepeatRow,
    device_key,
)
from imustation.analysis.pipeline.parallel import TaskFailure
from imustation.analysis.reports.tables import TITLES, fmt_flagged, noise_rows, units_of


def _f(x) -> float:
    return float("nan") if x is None else float(x)


def fleet_rows(results: Sequence[ChannelAnalysis]) -> list[FleetRow]:
    """Rows of analysed channels (noise_model fits; run-file ``device/gyro|accel/axis`` ids), in the order given."""
    rows = []
    for res, nr in zip(results, noise_rows(list(results)), strict=True):
        meta = res.channel.meta
        mli, ieee = res.noise_model, res.ieee  # the default estimator, as in the noise table
        stderr = {q: _f(mli.stderr.get(q)) for q in MODEL_QUANTITIES}
        stderr |= {q: _f(getattr(ieee, f"{q}_stderr", None)) for q in ("N", "B", "K")}
        lo, hi = {}, {}
        for q in FLEET_QUANTITIES:
            ci = mli.ci90.get(q) if q in MODEL_QUANTITIES else None
            if ci is not None:
                lo[q], hi[q] = _f(ci[0]), _f(ci[1])
            else:
                lo[q], hi[q] = nr.values[q] - Z90 * stderr[q], nr.values[q] + Z90 * stderr[q]
        driver = str(meta.get("driver", ""))
        identity = str(meta.get("identity", ""))
        station = str(meta.get("station", ""))
        device = str(meta.get("device", nr.device))
        rows.append(
            FleetRow(
                run=res.channel.source,
                station=station,
                device=device,
                driver=driver,
                identity=identity,
                key=device_key(driver, identity, station, device, meta.get("settings")),
                sensor=nr.sensor,
                axis=nr.axis,
                n=nr.n,
                fs_hz=nr.fs_hz,
                model=nr.model,
                converged=bool(mli.converged),
                values={q: _f(nr.values[q]) for q in FLEET_QUANTITIES},
                stderr=stderr,
                lo=lo,
                hi=hi,
                flags=dict(nr.flags),
                warmup=meta["warmup"].describe() if "warmup" in meta else "",
            )
        )
    return rows


def _fmt(x: float, digits: int = 3) -> str:
    if x is None or math.isnan(x):
        return "–"
    if math.isinf(x):
        return "∞"
    return f"{x:.{digits}g}"


def fleet_csv(rows: Sequence[FleetRow], failures: Sequence[TaskFailure] = ()) -> str:
    """CSV, one line per run axis (SI; ``status`` ok/outlier/left out, ``left_out`` why, ``warmup`` what
    was cut) and one ``failed`` line per failure."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = ["status", "run", "station", "device", "driver", "identity", "device_key", "sensor", "axis"]
    head += ["n", "fs_hz", "model", "converged"]
    for q in FLEET_QUANTITIES:
        head += [q, f"{q}_stderr", f"{q}_lo90", f"{q}_hi90", f"{q}_unit"]
    head += [f"z_{q}" for q in MODEL_QUANTITIES] + ["outliers", "value_flags", "error", "left_out", "warmup"]
    w.writerow(head)
    for r in rows:
        status = "left out" if r.excluded else "outlier" if r.outliers else "ok"
        line = [status, r.run, r.station, r.device, r.driver, r.identity, r.key]
        line += [r.sensor, r.axis, r.n, f"{r.fs_hz:g}", r.model, r.converged]
        for q in FLEET_QUANTITIES:
            line += [repr(r.values[q]), repr(r.stderr[q]), repr(r.lo[q]), repr(r.hi[q]), units_of(r.sensor, q)[0]]
        line += [repr(r.z.get(q, math.nan)) for q in MODEL_QUANTITIES] + [" ".join(r.outliers)]
        line += ["; ".join(f"{q} {f}" for q, f in r.flags.items()), "", r.excluded, r.warmup]
        w.writerow(line)
    for f in failures:
        cells = dict.fromkeys(head, "")
        parts = (f.channel or "").split("/")
        cells |= {"status": "failed", "run": f.path, "error": f.error}
        if len(parts) >= 3:
            cells |= {"device": "/".join(parts[:-2]), "sensor": parts[-2], "axis": parts[-1]}
        w.writerow(cells.values())
    return buf.getvalue()


def _sensor_units(sensor: str, q: str) -> tuple[str, float]:
    _, disp, factor = units_of(sensor, q)
    return disp, factor


def fleet_markdown(rows: Sequence[FleetRow], repeat: Sequence[RepeatRow], failures: Sequence[TaskFailure] = ()) -> str:
    """Markdown: the fleet table and the repeatability table per sensor kind (display units), outliers, failures."""
    parts = [f"# Fleet noise table\n\n{len({r.run for r in rows})} runs, {len(rows)} axes, "
             f"{len({r.key for r in rows})} devices, {len(failures)} failures."]  # fmt: skip
    sensors = list(dict.fromkeys(r.sensor for r in rows))
    for sensor in sensors:
        head = ["run", "device", "identity", "axis", "model"]
        for q in FLEET_QUANTITIES:
            head.append(f"{TITLES[q][0]} [{_sensor_units(sensor, q)[0]}]")
        head.append("flags")
        lines = [f"**{sensor}: every run (value ± standard error)**", "", "| " + " | ".join(head) + " |"]
        lines.append("|" + "---|" * len(head))
        for r in (r for r in rows if r.sensor == sensor):
            cells = [r.run, r.key, r.identity or "–", f"{r.axis}-{sensor}", r.model]
            for q in FLEET_QUANTITIES:
                _, k = _sensor_units(sensor, q)
                f = r.flags.get(q, "")
                se = f" ± {_fmt(r.stderr[q] * k, 2)}" if not f and math.isfinite(r.stderr[q]) else ""
                cells.append(fmt_flagged(r.values[q] * k, f) + se)
            flags = [f"outlier {q} (z {r.z[q]:+.1f})" for q in r.outliers]
            flags += [f"left out: {r.excluded}"] if r.excluded else []
            cells.append("; ".join(flags + ([] if r.converged else ["not converged"])) or "ok")
            lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
        parts.append("\n".join(lines))
    for sensor in sensors:
        head = ["device", "axis", "model", "runs"]
        for q in MODEL_QUANTITIES:
            u = _sensor_units(sensor, q)[0]
            head += [f"{TITLES[q][0]} mean [{u}]", f"{TITLES[q][0]} std [{u}]"]
        lines = [f"**{sensor}: repeatability per device and model (Table III layout: mean and std over runs, ddof=1; "
                 "runs left out and flagged values not counted)**", ""]  # fmt: skip
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for rr in (rr for rr in repeat if rr.sensor == sensor):
            cells = [rr.key, f"{rr.axis}-{sensor}", rr.model, str(rr.runs)]
            for q in MODEL_QUANTITIES:
                _, k = _sensor_units(sensor, q)
                cells += [_fmt(rr.mean[q] * k), _fmt(rr.std[q] * k, 2)]
            lines.append("| " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
    out = [r for r in rows if r.outliers]
    lines = [f"**Outliers (robust z of log10 value vs. the same driver/sensor/axis and model, each run with its own "
             f"standard error, |z| > {Z_LIMIT:g})**", ""]  # fmt: skip
    if out:
        lines += ["| run | device | axis | quantity | z |", "|---|---|---|---|---|"]
        for r in out:
            for q in r.outliers:
                lines.append(f"| {r.run} | {r.key} | {r.axis}-{r.sensor} | {TITLES[q][0]} | {r.z[q]:+.1f} |")
    else:
        lines.append("none")
    parts.append("\n".join(lines))
    left = [r for r in rows if r.excluded]
    lines = ["**Left out of the repeatability and the outlier test**", ""]
    if left:
        lines += ["| run | device | axis | why |", "|---|---|---|---|"]
        lines += [f"| {r.run} | {r.key} | {r.axis}-{r.sensor} | {r.excluded} |" for r in left]
    else:
        lines.append("none")
    parts.append("\n".join(lines))
    lines = ["**Failures**", ""]
    if failures:
        lines += ["| run | channel | error |", "|---|---|---|"]
        lines += [f"| {f.path} | {f.channel or '(whole run)'} | {f.error.replace('|', '/')} |" for f in failures]
    else:
        lines.append("none")
    parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"
