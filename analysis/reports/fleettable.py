"""The fleet table: one row per analysed axis of every run, as CSV, Markdown and JSON.

:func:`fleet_rows` builds :class:`~imustation.analysis.pipeline.fleet.FleetRow` from the noise
table's rows (so the fleet gives the numbers and flags of the per-run table, the summary, ``analyze``
and ``export``: N, B, K from the noise model's ``ieee952`` block, with its 90 % intervals, a term
the run does not show as its upper bound); :func:`fleet_csv`, :func:`fleet_markdown` and
:func:`fleet_json` render them with the repeatability, the run-to-run scatter, outliers and
failures. The statistics (outliers, repeatability, scatter, one model per group) are
:mod:`imustation.analysis.pipeline.fleet`'s and :mod:`~imustation.analysis.pipeline.scatter`'s.
Builders return text; writing files is :mod:`.fleetreport`'s business.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
from collections.abc import Sequence

from imustation.analysis.pipeline.channel import ChannelAnalysis
from imustation.analysis.pipeline.fleet import (
    FLEET_QUANTITIES,
    JUDGED,
    MODEL_QUANTITIES,
    UNIQUE_FIELDS,
    Z_LIMIT,
    FleetRow,
    RepeatRow,
    device_key,
    interval_ln_se,
)
from imustation.analysis.pipeline.parallel import TaskFailure
from imustation.analysis.pipeline.scatter import ALPHA, Scatter
from imustation.analysis.reports.analyzetable import cell
from imustation.analysis.reports.numbers import p_value
from imustation.analysis.reports.tables import NBK, TITLES, Estimate, noise_rows, units_of

#: the fleet JSON document (docs/fleet.md)
FLEET_FORMAT = "imustation-fleet"
FLEET_VERSION = 1
#: longest identity shown in fleet.md (the CSV and JSON keep it whole)
IDENTITY_CHARS = 32


def _f(x) -> float:
    return float("nan") if x is None else float(x)


def short_identity(driver: str, identity: str, settings: dict | None = None) -> str:
    """The identity a person reads in a table cell: the fields that name a part (``serial=``, ``lot=``...)
    or a chip id; an imported device's source file and format (its identity is the whole column or
    topic mapping); else the identity cut to :data:`IDENTITY_CHARS` characters with "…"."""
    identity = (identity or "").strip()
    fields = dict(re.findall(r"(\w+)=(\S+)", identity))
    # the fields that name the part, else those that name the chip
    for keys in (UNIQUE_FIELDS, ("chip_id", "who_am_i", "prod_id")):
        named = [f"{k}={fields[k]}" for k in keys if k in fields]
        if named:
            return " ".join(named)
    if driver == "import" and settings and settings.get("source"):
        return f"{settings.get('source_format', 'import')}: {os.path.basename(str(settings['source']))}"
    return identity if len(identity) <= IDENTITY_CHARS else identity[: IDENTITY_CHARS - 1].rstrip() + "…"


def _stderr_from(value: float, lo: float, hi: float) -> float:
    """A standard error (SI) from a 90 % interval symmetric in the logarithm (delta method), NaN without one."""
    return value * interval_ln_se(lo, hi) if value > 0 else math.nan


def fleet_rows(results: Sequence[ChannelAnalysis]) -> list[FleetRow]:
    """Rows of analysed channels (noise_model fits; run-file ``device/gyro|accel/axis`` ids), in the order given."""
    rows = []
    for res, nr in zip(results, noise_rows(list(results)), strict=True):
        meta = res.channel.meta
        fit = res.noise_model  # the default estimator, as in the noise table
        stderr, lo, hi = {}, {}, {}
        for q in MODEL_QUANTITIES:
            ci = fit.ci90.get(q)
            stderr[q] = _f(fit.stderr.get(q))
            lo[q], hi[q] = (_f(ci[0]), _f(ci[1])) if ci is not None else (math.nan, math.nan)
        for q in NBK:  # the model's ieee952 block: its interval, nothing for an upper bound
            lo[q], hi[q] = _f(nr.lo.get(q)), _f(nr.hi.get(q))
            stderr[q] = _stderr_from(_f(nr.values[q]), lo[q], hi[q])
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
                converged=bool(fit.converged),
                values={q: _f(nr.values[q]) for q in FLEET_QUANTITIES},
                stderr=stderr,
                lo=lo,
                hi=hi,
                flags=dict(nr.flags),
                warmup=meta["warmup"].describe() if "warmup" in meta else "",
                short_identity=short_identity(driver, identity, meta.get("settings")),
                own_model=res.choice.chosen.model if res.choice is not None else "",
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
    head += [f"z_{q}" for q in JUDGED if q not in MODEL_QUANTITIES]  # added with B, K judged (issue 34)
    w.writerow(head)
    for r in rows:
        status = "left out" if r.excluded else "outlier" if r.outliers else "ok"
        line = [status, r.run, r.station, r.device, r.driver, r.identity, r.key]
        line += [r.sensor, r.axis, r.n, f"{r.fs_hz:g}", r.model, r.converged]
        for q in FLEET_QUANTITIES:
            line += [repr(r.values[q]), repr(r.stderr[q]), repr(r.lo[q]), repr(r.hi[q]), units_of(r.sensor, q)[0]]
        line += [repr(r.z.get(q, math.nan)) for q in MODEL_QUANTITIES] + [" ".join(r.outliers)]
        line += ["; ".join(f"{q} {f}" for q, f in r.flags.items()), "", r.excluded, r.warmup]
        w.writerow(line + [repr(r.z.get(q, math.nan)) for q in JUDGED if q not in MODEL_QUANTITIES])
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


def _value_cell(r: FleetRow, q: str, factor: float) -> str:
    """``value [90 % interval]`` in display units; "< x" for a term the run does not show, flags as the noise table."""
    return cell(Estimate(r.values[q], r.lo.get(q, math.nan), r.hi.get(q, math.nan), r.flags.get(q, "")), factor)


def fleet_markdown(
    rows: Sequence[FleetRow],
    repeat: Sequence[RepeatRow],
    failures: Sequence[TaskFailure] = (),
    scatter: Sequence[Scatter] = (),
) -> str:
    """Markdown: the fleet table, the repeatability and the run-to-run scatter per sensor kind (display units),
    outliers, failures."""
    parts = [f"# Fleet noise table\n\n{len({r.run for r in rows})} runs, {len(rows)} axes, "
             f"{len({r.key for r in rows})} devices, {len(failures)} failures."]  # fmt: skip
    sensors = list(dict.fromkeys(r.sensor for r in rows))
    for sensor in sensors:
        head = ["run", "device", "identity", "axis", "model"]
        for q in FLEET_QUANTITIES:
            head.append(f"{TITLES[q][0]} [{_sensor_units(sensor, q)[0]}]")
        head.append("flags")
        lines = [
            f"**{sensor}: every run (value [90 % interval]; N, B, K: the IEEE-952 terms of the run's noise "
            "model, < x: 90 % upper bound of a term the run does not show)**",
            "",
            "| " + " | ".join(head) + " |",
        ]
        lines.append("|" + "---|" * len(head))
        for r in (r for r in rows if r.sensor == sensor):
            # the group's common model: say so where the run alone (analyze, report) chose another
            model = r.model if r.own_model in ("", r.model) else f"{r.model} (fleet's; the run alone: {r.own_model})"
            cells = [r.run, r.key, r.short_identity or r.identity or "–", f"{r.axis}-{sensor}", model]
            cells += [_value_cell(r, q, _sensor_units(sensor, q)[1]) for q in FLEET_QUANTITIES]
            flags = [f"outlier {TITLES[q][0]} (z {r.z[q]:+.1f})" for q in r.outliers]
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
    for sensor in sensors:
        parts.append(scatter_markdown(sensor, [s for s in scatter if s.sensor == sensor]))
    out = [r for r in rows if r.outliers]
    lines = [f"**Outliers (robust z of log10 value vs. the same driver/sensor/axis (and model, for σ_b, τ_b), each "
             f"run with its own 90 % interval, |z| > {Z_LIMIT:g}; a B or K a run does not show is no candidate)**",
             ""]  # fmt: skip
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


def relative(x: float) -> str:
    """A relative spread (std of ln value): "3.1 %" while small, "x 4.2" (a factor) beyond 30 %."""
    if not math.isfinite(x):
        return "–"
    return f"{100 * x:.2g} %" if x <= 0.3 else f"× {math.exp(x):.2g}"


def scatter_markdown(sensor: str, scatter: Sequence[Scatter]) -> str:
    """The run-to-run scatter of each device's N, B, K (and σ_b, τ_b per model) beside the runs' own 90 %
    intervals, display units (:mod:`imustation.analysis.pipeline.scatter`)."""
    lines = [
        f"**{sensor}: run-to-run scatter per device beside the per-run 90 % intervals (scatter: std of ln value "
        "over the runs; interval: the median run's 90 % half-width; χ²: Cochran's Q of the runs about their "
        f"weighted mean; excess: the scatter the intervals do not explain; exceeds when p < {ALPHA:g})**",
        "",
    ]
    if not scatter:
        return "\n".join([*lines, "none (no device with an estimate in a run kept)"])
    head = ["device", "axis", "quantity", "model", "runs", "mean", "std", "scatter", "interval ±", "χ²/dof (p)",
            "excess", "verdict"]  # fmt: skip
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in scatter:
        unit, k = _sensor_units(sensor, s.quantity)
        chi = f"{s.chi2:.3g}/{s.dof} ({p_value(s.p_value)})" if s.dof else "–"
        runs = f"{s.runs}" + (f" (+{s.not_counted} not estimated)" if s.not_counted else "")
        cells = [s.key, f"{s.axis}-{sensor}", TITLES[s.quantity][0], s.model or "any", runs,
                 f"{_fmt(s.mean * k)} {unit}", f"{_fmt(s.std * k, 2)} {unit}", relative(s.scatter),
                 relative(s.halfwidth), chi, relative(s.excess) if s.dof else "–", s.verdict]  # fmt: skip
        lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    return "\n".join(lines)


def _row_dict(r: FleetRow) -> dict:
    status = "left out" if r.excluded else "outlier" if r.outliers else "ok"
    values = {
        q: {"value": r.values[q], "lo90": r.lo.get(q), "hi90": r.hi.get(q), "stderr": r.stderr.get(q),
            "unit": units_of(r.sensor, q)[0], "flag": r.flags.get(q, "")}
        for q in FLEET_QUANTITIES
    }  # fmt: skip
    return {
        "status": status, "run": r.run, "station": r.station, "device": r.device, "driver": r.driver,
        "identity": r.identity, "identity_short": r.short_identity, "device_key": r.key, "sensor": r.sensor,
        "axis": r.axis, "n": r.n, "fs_hz": r.fs_hz, "duration_s": r.duration_s, "model": r.model,
        "converged": r.converged, "values": values, "z": {q: r.z.get(q, math.nan) for q in JUDGED},
        "outliers": list(r.outliers), "left_out": r.excluded, "warmup": r.warmup,
    }  # fmt: skip


def _num(x):
    if isinstance(x, dict):
        return {k: _num(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_num(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def fleet_json(
    rows: Sequence[FleetRow],
    repeat: Sequence[RepeatRow],
    scatter: Sequence[Scatter],
    failures: Sequence[TaskFailure] = (),
) -> str:
    """The fleet as one JSON document (docs/fleet.md, "fleet.json"): SI values, NaN/inf as null."""
    doc = {
        "format": FLEET_FORMAT,
        "version": FLEET_VERSION,
        "outlier_rule": {"z_limit": Z_LIMIT, "judged": list(JUDGED)},
        "scatter_alpha": ALPHA,
        "rows": [_row_dict(r) for r in rows],
        "repeatability": [
            {
                "device_key": rr.key,
                "driver": rr.driver,
                "sensor": rr.sensor,
                "axis": rr.axis,
                "model": rr.model,
                "runs": rr.runs,
                "mean": rr.mean,
                "std": rr.std,
                "counted": rr.counted,
            }
            for rr in repeat
        ],  # fmt: skip
        "scatter": [s.as_dict() for s in scatter],
        "failures": [{"run": f.path, "channel": f.channel, "error": f.error} for f in failures],
    }
    return json.dumps(_num(doc), indent=1, ensure_ascii=False) + "\n"
