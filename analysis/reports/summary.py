"""The summary a run report opens with: one row per sensor and axis.

N (the noise model's sigma_w), B and K (bias instability and rate random walk the noise
model implies: its ``ieee952`` block, the numbers the "enough data?" verdict judges and
``export`` writes; a term the record does not show is its 90 % upper bound, "< x"), the bias
model's sigma_b and tau_b, each with its 90 % interval, the
fit verdict and the "enough data?" verdict, in the display units of the axis's own
sensor (:func:`imustation.units.display_units`). Values that are not estimates are
flagged as in :mod:`.tables` ("—", "at bound", "not identified").
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass

from imustation.analysis.pipeline.channel import ChannelAnalysis
from imustation.analysis.reports.tables import (
    DASH,
    NOT_FITTED,
    Estimate,
    by_sensor,
    fmt_estimate,
    model_estimate,
    model_nbk,
    split_channel_id,
)
from imustation.units import display_units

__all__ = ["Estimate", "SummaryRow", "channel_estimates", "fit_verdict", "fmt_estimate", "summary_csv",
           "summary_markdown", "summary_rows", "SUMMARY_QUANTITIES"]  # fmt: skip

#: summary quantities: (key, title, dimension)
SUMMARY_QUANTITIES = (
    ("N", "N", "density"),
    ("B", "B", "rate"),
    ("K", "K", "drift"),
    ("sigma_b", "σ_b", "drift"),
    ("tau_b", "τ_b", "time"),
)


@dataclass(frozen=True)
class SummaryRow:
    """One sensor axis: N (the noise model's sigma_w), B and K (the model's IEEE-952 terms or their upper
    bounds), the bias model's ``sigma_b`` and ``tau_b`` (:class:`Estimate` each, SI), the model's name,
    the fit verdict and the "enough data?" verdict (with its reasons); ``"—"`` for a verdict the analysis
    did not give."""

    device: str
    sensor: str
    axis: str
    n: int
    fs_hz: float
    model: str
    estimator: str
    values: dict[str, Estimate]
    fit: str
    enough: str
    enough_reasons: tuple[str, ...] = ()


def fit_verdict(res: ChannelAnalysis) -> str:
    """The model-adequacy verdict of the default fit ("fits", "does not fit: <where>"), or "—"
    for a fit without one (docs/noise-model.md, "Model adequacy"). A fit that did not
    converge says so.
    """
    fit = res.noise_model
    adq = res.adequacy_of(fit)
    text = DASH if adq is None else adq.verdict
    if adq is not None and adq.misfit:
        text += ": " + "; ".join(m.describe() for m in adq.misfit)
    if not fit.converged and not fit.at_bound:
        text += " (not converged)"
    return text


def channel_estimates(r: ChannelAnalysis) -> dict[str, Estimate]:
    """The summary's quantities of one analysed channel (SI, keys of :data:`SUMMARY_QUANTITIES`):
    the same numbers wherever a channel is summarised (the report's summary, ``analyze``'s table)."""
    fit = r.noise_model
    # the verdict's, the export's, the noise table's and fleet's N, B, K: one answer (issue 34)
    return {**model_nbk(r), "sigma_b": model_estimate(fit, "sigma_b"), "tau_b": model_estimate(fit, "tau_b")}


def summary_rows(results: list[ChannelAnalysis]) -> list[SummaryRow]:
    """One :class:`SummaryRow` per analysed channel, in the order given."""
    rows = []
    for r in results:
        device, sensor, axis = split_channel_id(r.channel)
        fit = r.noise_model
        values = channel_estimates(r)
        v = r.verdict
        rows.append(
            SummaryRow(
                device, sensor, axis, r.channel.n, r.channel.fs_hz, fit.model, fit.estimator, values,
                fit_verdict(r), v.verdict if v is not None else DASH, tuple(v.reasons) if v is not None else (),
            )
        )  # fmt: skip
    return rows


def summary_markdown(rows: list[SummaryRow]) -> str:
    """One Markdown table per sensor kind, display units, each value with its 90 % interval."""
    parts = []
    for sensor, rs in by_sensor(rows).items():
        head = ["device", "axis", "model"]
        head += [f"{title} [{display_units(sensor, dim)[1]}]" for _, title, dim in SUMMARY_QUANTITIES]
        head += ["fit", "enough data?"]
        lines = [f"**{sensor}**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in rs:
            cells = [r.device, f"{r.axis}-{sensor}", f"{r.model} ({r.estimator})"]
            for key, _, dim in SUMMARY_QUANTITIES:
                cells.append(fmt_estimate(r.values[key], display_units(sensor, dim)[2]))
            cells += [r.fit, r.enough]
            lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"


def summary_csv(rows: list[SummaryRow]) -> str:
    """CSV of the summary, SI: per quantity value, 90 % interval, unit, flag; the two verdicts."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = ["device", "sensor", "axis", "n", "fs_hz", "model", "estimator"]
    for key, _, _ in SUMMARY_QUANTITIES:
        head += [key, f"{key}_lo90", f"{key}_hi90", f"{key}_unit", f"{key}_flag"]
    head += ["fit", "enough_data", "enough_data_reasons"]
    w.writerow(head)
    for r in rows:
        line = [r.device, r.sensor, r.axis, r.n, f"{r.fs_hz:g}", r.model, r.estimator]
        for key, _, dim in SUMMARY_QUANTITIES:
            e = r.values[key]
            value = "" if e.flag == NOT_FITTED else repr(float(e.value))
            line += [value, repr(float(e.lo)), repr(float(e.hi)), display_units(r.sensor, dim)[0], e.flag]
        line += [r.fit, r.enough, "; ".join(r.enough_reasons)]
        w.writerow(line)
    return buf.getvalue()
