"""The per-device noise table (the paper's Table IV layout) in CSV, Markdown and LaTeX.

One row per axis: the ML_i parameters ``sigma_w``, ``sigma_b``, ``tau_b`` of the
standard model, the IEEE-952 Allan-fit coefficients ``N``, ``B``, ``K`` and the
measured Allan deviation at tau = 1 s, each in SI and in the usual display unit
side by side, and whether the model fits the measured Allan variance (and where not):

=========  ======================  ==============  ===================
quantity   SI (gyro / accel)       gyro display    accel display
=========  ======================  ==============  ===================
sigma_w,N  rad/s/√Hz, m/s²/√Hz     °/h/√Hz         µg/√Hz
sigma_b,K  rad/s²/√Hz, m/s³/√Hz    °/h/√h          µg/√s
B, ADEV1s  rad/s, m/s²             °/h             µg
tau_b      s                       s               s
=========  ======================  ==============  ===================

(°/h/√h: rad/s/√s x 3600·180/π x √3600; 1 g = 9.80665 m/s².) Builders take
:class:`~imustation.analysis.pipeline.channel.ChannelAnalysis` results and return text;
writing the files is the caller's business.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass

from imustation.analysis.pipeline.channel import ChannelAnalysis
from imustation.errors import InputError
from imustation.units import DPH2RADPS, G0

#: rad/s -> deg/h
RADPS_TO_DPH = 1.0 / DPH2RADPS
#: m/s^2 -> micro-g
MPS2_TO_UG = 1e6 / G0
#: sqrt(s) per sqrt(h): a rad/s/sqrt(s) figure times this is per sqrt(h)
SQRT_S_PER_SQRT_H = 60.0

#: sensor kind -> SI unit of its channel (run files)
_SENSORS = {"gyro": "rad/s", "accel": "m/s^2"}
QUANTITIES = ("sigma_w", "sigma_b", "tau_b", "N", "B", "K", "adev_1s")
TITLES = {
    "sigma_w": ("σ_w", r"$\sigma_w$"),
    "sigma_b": ("σ_b", r"$\sigma_b$"),
    "tau_b": ("τ_b", r"$\tau_b$"),
    "N": ("N", "$N$"),
    "B": ("B", "$B$"),
    "K": ("K", "$K$"),
    "adev_1s": ("σ(1 s)", r"$\sigma(1\,\mathrm{s})$"),
}
#: quantity -> dimension class: "density" (unit/sqrt(Hz)), "drift" (unit/s/sqrt(Hz)), "rate" (unit), "time"
_DIM = {"sigma_w": "density", "N": "density", "sigma_b": "drift", "K": "drift", "B": "rate", "adev_1s": "rate"}
_DIM["tau_b"] = "time"

#: (sensor, dimension) -> (SI unit, display unit, factor SI -> display)
UNITS: dict[tuple[str, str], tuple[str, str, float]] = {
    ("gyro", "density"): ("rad/s/√Hz", "°/h/√Hz", RADPS_TO_DPH),
    ("gyro", "drift"): ("rad/s²/√Hz", "°/h/√h", RADPS_TO_DPH * SQRT_S_PER_SQRT_H),
    ("gyro", "rate"): ("rad/s", "°/h", RADPS_TO_DPH),
    ("accel", "density"): ("m/s²/√Hz", "µg/√Hz", MPS2_TO_UG),
    ("accel", "drift"): ("m/s³/√Hz", "µg/√s", MPS2_TO_UG),
    ("accel", "rate"): ("m/s²", "µg", MPS2_TO_UG),
}
for _s in ("gyro", "accel"):
    UNITS[(_s, "time")] = ("s", "s", 1.0)
_LATEX_UNIT = {"√Hz": r"\sqrt{\mathrm{Hz}}", "√h": r"\sqrt{\mathrm{h}}", "√s": r"\sqrt{\mathrm{s}}"}


def units_of(sensor: str, quantity: str) -> tuple[str, str, float]:
    """(SI unit, display unit, SI->display factor) of ``quantity`` for a ``gyro`` or ``accel`` axis."""
    return UNITS[(sensor, _DIM[quantity])]


@dataclass(frozen=True)
class NoiseRow:
    """One axis of the table; ``values`` in SI, keyed by :data:`QUANTITIES`."""

    device: str
    sensor: str
    axis: str
    n: int
    fs_hz: float
    model: str
    values: dict[str, float]
    #: model adequacy of the fit against the measured Allan variance ("fits", "does not fit", ...)
    fit: str = ""
    fit_p: float = math.nan
    #: tau ranges where the model misses, e.g. "5.2-98 s model low"
    fit_where: str = ""

    def display(self, q: str) -> float:
        return self.values[q] * units_of(self.sensor, q)[2]


def _split_id(ch) -> tuple[str, str, str]:
    """(device, sensor, axis) of a ``device/gyro|accel/axis`` id, else the sensor from the units."""
    parts = ch.id.split("/")
    if len(parts) >= 3 and parts[-2] in _SENSORS:
        return "/".join(parts[:-2]), parts[-2], parts[-1]
    for sensor, units in _SENSORS.items():
        if ch.units == units:
            return ch.id, sensor, "-"
    raise InputError(
        f"channel {ch.id}: units {ch.units!r} name neither a gyroscope (rad/s) nor an accelerometer (m/s^2)"
    )


def noise_rows(results: list[ChannelAnalysis]) -> list[NoiseRow]:
    """Rows for every analysed channel: run-file ``device/gyro|accel/axis`` ids or channels with units."""
    rows = []
    for r in results:
        device, sensor, axis = _split_id(r.channel)
        vals = {
            "sigma_w": r.noise_model.sigma_w,
            "sigma_b": r.noise_model.sigma_b,
            "tau_b": r.noise_model.tau_b,
            "N": r.ieee.N,
            "B": r.ieee.B,
            "K": r.ieee.K,
            "adev_1s": r.ieee.adev_1s,
        }
        adq = r.adequacy_of(r.noise_model)
        fit = (adq.verdict, adq.p_value, "; ".join(m.describe() for m in adq.misfit)) if adq else ("", math.nan, "")
        rows.append(NoiseRow(device, sensor, axis, r.channel.n, r.channel.fs_hz, r.noise_model.model, vals, *fit))
    return rows


def _fmt(x: float, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    if math.isinf(x):
        return "∞"
    return f"{x:.{digits}g}"


def table_csv(rows: list[NoiseRow]) -> str:
    """CSV: identification columns, then per quantity its SI value, SI unit, display value, display unit."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = ["device", "sensor", "axis", "n", "fs_hz", "model"]
    for q in QUANTITIES:
        head += [q, f"{q}_unit", f"{q}_display", f"{q}_display_unit"]
    w.writerow(head + ["model_fit", "model_fit_p", "model_fit_where"])
    for r in rows:
        line = [r.device, r.sensor, r.axis, r.n, f"{r.fs_hz:g}", r.model]
        for q in QUANTITIES:
            si, disp, _ = units_of(r.sensor, q)
            line += [repr(float(r.values[q])), si, repr(float(r.display(q))), disp]
        w.writerow(line + [r.fit, repr(float(r.fit_p)), r.fit_where])
    return buf.getvalue()


def _fit_text(r: NoiseRow) -> str:
    """``fits`` / ``does not fit: 5.2-98 s model low`` / ``–`` (no adequacy)."""
    if not r.fit:
        return "–"
    return f"{r.fit}: {r.fit_where}" if r.fit_where else r.fit


def _by_sensor(rows: list[NoiseRow]) -> dict[str, list[NoiseRow]]:
    out: dict[str, list[NoiseRow]] = {}
    for r in rows:
        out.setdefault(r.sensor, []).append(r)
    return out


def table_markdown(rows: list[NoiseRow]) -> str:
    """One Markdown table per sensor kind; each quantity in SI and display units."""
    parts = []
    for sensor, rs in _by_sensor(rows).items():
        head = ["device", "axis"]
        for q in QUANTITIES:
            si, disp, _ = units_of(sensor, q)
            t = TITLES[q][0]
            head += [f"{t} [{si}]"] if si == disp else [f"{t} [{si}]", f"{t} [{disp}]"]
        head.append("model fit")
        lines = [f"**{sensor}**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in rs:
            cells = [r.device, f"{r.axis}-{sensor}"]
            for q in QUANTITIES:
                si, disp, _ = units_of(sensor, q)
                cells += [_fmt(r.values[q])] if si == disp else [_fmt(r.values[q]), _fmt(r.display(q))]
            cells.append(_fit_text(r))
            lines.append("| " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"


def _latex_unit(u: str) -> str:
    for k, v in _LATEX_UNIT.items():
        u = u.replace(k, v)
    u = u.replace("°", r"^\circ").replace("µ", r"\mu ").replace("²", "^2").replace("³", "^3")
    return rf"$[\mathrm{{{u}}}]$".replace(r"\mathrm{^\circ", r"\mathrm{{}^\circ")


def _latex_num(x: float) -> str:
    if math.isnan(x):
        return "--"
    if math.isinf(x):
        return r"$\infty$"
    m, e = f"{x:.2e}".split("e")
    e = int(e)
    return f"${m}$" if e == 0 else rf"${m}\times10^{{{e}}}$"


def _latex_text(s: str) -> str:
    return s.replace("\\", r"\textbackslash{}").replace("_", r"\_").replace("&", r"\&").replace("%", r"\%")


def table_latex(rows: list[NoiseRow]) -> str:
    """One ``tabular`` per sensor kind (booktabs rules), SI and display columns."""
    parts = []
    for sensor, rs in _by_sensor(rows).items():
        cols, head, units = [], ["Device", "Axis"], ["", ""]
        for q in QUANTITIES:
            si, disp, _ = units_of(sensor, q)
            for u in [si] if si == disp else [si, disp]:
                head.append(TITLES[q][1])
                units.append(_latex_unit(u))
                cols.append("r")
        head.append("Fit")
        units.append("")
        cols.append("l")
        lines = [
            rf"% {sensor}: ML_i sigma_w, sigma_b, tau_b; IEEE-952 N, B, K; Allan deviation at 1 s;"
            " model adequacy (fits / does not fit the measured Allan variance)",
            r"\begin{tabular}{ll" + "".join(cols) + "}",
            r"\toprule",
            " & ".join(head) + r" \\",
            " & ".join(units) + r" \\",
            r"\midrule",
        ]
        for r in rs:
            cells = [_latex_text(r.device), _latex_text(f"{r.axis}-{sensor}")]
            for q in QUANTITIES:
                si, disp, _ = units_of(sensor, q)
                cells += [_latex_num(r.values[q])] + ([] if si == disp else [_latex_num(r.display(q))])
            cells.append(_latex_text(r.fit) if r.fit else "--")
            lines.append(" & ".join(cells) + r" \\")
        lines += [r"\bottomrule", r"\end{tabular}"]
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"
