"""The report's detail tables: the noise table (the paper's Table IV layout) and the temperature coefficients.

(The summary a report opens with is :mod:`.summary`.)

* :func:`noise_rows` / :func:`table_csv` / :func:`table_markdown` /
  :func:`table_latex` — the noise-model parameters ``sigma_w``, ``sigma_b``,
  ``tau_b``, the IEEE-952 coefficients ``N``, ``B``, ``K`` the noise model implies (its
  ``ieee952`` block, :func:`model_nbk`: the numbers ``analyze``, the report's summary, the
  "enough data?" verdict, ``export`` and ``fleet`` give, with their 90 % intervals; a term the
  record does not show is its 90 % upper bound, "< x") and the
  measured Allan deviation at tau = 1 s, each in SI and in the display unit side
  by side, and whether the model fits the measured Allan variance (and where not).
  The classical IEEE-952 fit of the Allan curve (``ChannelAnalysis.ieee``) is kept beside
  them as a comparison, labelled so (Markdown: its own table; CSV: ``N_allan``...):

=========  ======================  ==============  ===================
quantity   SI (gyro / accel)       gyro display    accel display
=========  ======================  ==============  ===================
sigma_w,N  rad/s/√Hz, m/s²/√Hz     °/h/√Hz         µg/√Hz
sigma_b,K  rad/s²/√Hz, m/s³/√Hz    °/h/√h          µg/√s
B, ADEV1s  rad/s, m/s²             °/h             µg
tau_b      s                       s               s
=========  ======================  ==============  ===================

(:func:`imustation.units.display_units` defines them; °/h/√h: rad/s/√s x
3600·180/π x √3600; 1 g = 9.80665 m/s².)

A number is never printed plainly when it is not an estimate: a B or K the record does
not show is its upper bound ("< x"); a coefficient the classical
IEEE-952 fit set to zero (its term not needed by the curve) is "not fitted" and
shows as "—", as are ``sigma_b`` and ``tau_b`` of a model without a Gauss-Markov
bias (a random walk's K is not a sigma_b: every column keeps one meaning); a
noise-model parameter at its search bound shows as "at bound"; one whose 90 %
interval is missing, infinite or spans more than
:data:`UNIDENTIFIED_RATIO` (two decades) is "not identified". The CSV gives the
number with a ``<q>_flag`` column (and an empty cell for "not fitted").

Builders take :class:`~imustation.analysis.pipeline.channel.ChannelAnalysis` results
and return text; writing the files is the caller's business.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field

from imustation.analysis.pipeline.channel import ChannelAnalysis, split_channel_id
from imustation.analysis.reports.numbers import EXTREME_FACTOR, interval
from imustation.units import MPS2_TO_UG, RADPS_TO_DPH, SQRT_S_PER_SQRT_H, display_units

__all__ = [
    "MPS2_TO_UG",
    "RADPS_TO_DPH",
    "SQRT_S_PER_SQRT_H",
    "Estimate",
    "NoiseRow",
    "model_nbk",
    "nbk_estimate",
    "noise_rows",
    "param_flag",
    "param_key",
    "has_gauss_markov",
    "ieee_flag",
    "density_flag",
    "by_sensor",
    "split_channel_id",
    "table_csv",
    "table_latex",
    "table_markdown",
    "units_of",
    "TempcoRow",
    "tempco_csv",
    "tempco_markdown",
]

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
#: quantity -> dimension class of :func:`imustation.units.display_units`
_DIM = {"sigma_w": "density", "N": "density", "sigma_b": "drift", "K": "drift", "B": "rate", "adev_1s": "rate"}
_DIM["tau_b"] = "time"
_LATEX_UNIT = {"√Hz": r"\sqrt{\mathrm{Hz}}", "√h": r"\sqrt{\mathrm{h}}", "√s": r"\sqrt{\mathrm{s}}"}
#: a parameter whose 90 % interval spans more than this ratio (hi/lo) is "not identified"
UNIDENTIFIED_RATIO = 100.0
#: two-sided 90 % normal quantile, for intervals built from a standard error
Z90 = 1.6448536269514722

#: a noise density (sigma_w) whose 90 % interval spans more than this ratio is "doubtful": the
#: slow terms reach the fine scales, where sigma_w rests on a shape nothing measures
#: (docs/noise-model.md, "Intervals"); the IEEE-952 N of that channel has the same limit
DOUBTFUL_RATIO = 1.1

#: value flags (the CSV's ``<q>_flag``)
NOT_FITTED = "not fitted"
AT_BOUND = "at bound"
NOT_IDENTIFIED = "not identified"
DOUBTFUL = "doubtful"
#: a term the record does not show: the value is its 90 % upper bound (classical/allan_bounds.py)
UPPER_BOUND = "upper bound"
#: what a table cell shows for a value that is absent or not fitted
DASH = "—"


def units_of(sensor: str | None, quantity: str) -> tuple[str, str, float]:
    """(SI unit, display unit, SI->display factor) of ``quantity`` for a ``gyro`` or ``accel`` axis."""
    return display_units(sensor, _DIM[quantity])


def param_key(fit, name: str) -> str:
    """Key of ``fit``'s params/intervals behind the summary name ``name``: the slowest of several
    Gauss-Markov terms (``sigma_b2``...) or a random walk's ``sigma_k`` for ``sigma_b``."""
    if name in ("sigma_b", "tau_b"):
        value = getattr(fit, name)
        numbered = [k for k in fit.params if k.startswith(name) and k[len(name) :].isdigit()]
        for k in numbered:
            if fit.params[k] == value:
                return k
        if name == "sigma_b" and "sigma_b" not in fit.params and "sigma_k" in fit.params:
            return "sigma_k"
    return name


def has_gauss_markov(fit) -> bool:
    """Whether ``fit``'s model has a Gauss-Markov bias term (``sigma_b``/``tau_b`` mean that term)."""
    return any(k.startswith("tau_b") for k in fit.params)


def param_flag(fit, name: str) -> str:
    """``AT_BOUND``, ``NOT_IDENTIFIED`` or "" for the noise-model parameter ``name`` (sigma_w, sigma_b, tau_b);
    ``NOT_FITTED`` for ``sigma_b``/``tau_b`` of a model without a Gauss-Markov term: a column of sigma_b
    holds Gauss-Markov densities only (the fit's ``sigma_b`` of a random-walk model is its K, ``tau_b`` inf)."""
    if name in ("sigma_b", "tau_b") and not has_gauss_markov(fit):
        return NOT_FITTED
    key = param_key(fit, name)
    if key in fit.at_bound or name in fit.at_bound:
        return AT_BOUND
    value = float(getattr(fit, name))
    if not math.isfinite(value):
        return ""  # an infinite tau_b (random walk) or no such term: shown as it is
    ci = fit.ci90.get(name) or fit.ci90.get(key)
    if ci is None:
        return NOT_IDENTIFIED
    lo, hi = float(ci[0]), float(ci[1])
    if not (math.isfinite(lo) and math.isfinite(hi) and lo > 0 and hi / lo <= UNIDENTIFIED_RATIO):
        return NOT_IDENTIFIED
    return ""


def density_flag(fit) -> str:
    """:data:`DOUBTFUL` when ``fit``'s sigma_w has a 90 % interval wider than :data:`DOUBTFUL_RATIO`, else ""."""
    lo, hi = (float(v) for v in fit.ci90.get("sigma_w", (math.nan, math.nan)))
    return DOUBTFUL if lo > 0 and math.isfinite(hi) and hi / lo > DOUBTFUL_RATIO else ""


def ieee_flag(value: float) -> str:
    """IEEE-952 terms the Allan fit did not need are 0: "not fitted", not a measurement of zero."""
    return NOT_FITTED if value == 0.0 else ""


@dataclass(frozen=True)
class NoiseRow:
    """One axis of the table; ``values`` in SI, keyed by :data:`QUANTITIES`; ``flags`` the
    quantities that are not plain estimates (:data:`NOT_FITTED`, :data:`AT_BOUND`, :data:`NOT_IDENTIFIED`,
    :data:`DOUBTFUL`)."""

    device: str
    sensor: str
    axis: str
    n: int
    fs_hz: float
    model: str
    values: dict[str, float]
    flags: dict[str, str] = field(default_factory=dict)
    #: model adequacy of the fit against the measured Allan variance ("fits", "does not fit", ...)
    fit: str = ""
    fit_p: float = math.nan
    #: tau ranges where the model misses, e.g. "5.2-98 s model low"
    fit_where: str = ""
    #: 90 % intervals (SI) of N, B, K where they have one (NaN otherwise)
    lo: dict[str, float] = field(default_factory=dict)
    hi: dict[str, float] = field(default_factory=dict)
    #: the classical IEEE-952 fit of the Allan curve (comparison only): N, B, K (SI; 0 = not fitted)
    #: and why a term is unusable (:func:`.allan_bounds.ieee_usability`), keyed "N", "B"
    allan: dict[str, float] = field(default_factory=dict)
    allan_unusable: dict[str, str] = field(default_factory=dict)

    def display(self, q: str) -> float:
        return self.values[q] * units_of(self.sensor, q)[2]

    def flag(self, q: str) -> str:
        return self.flags.get(q, "")


@dataclass(frozen=True)
class Estimate:
    """A value with its 90 % interval (SI; NaN where there is none) and its flag."""

    value: float
    lo: float = math.nan
    hi: float = math.nan
    flag: str = ""


def nbk_estimate(block: dict, q: str) -> Estimate:
    """B or K of a fit's ``ieee952`` block: the value and its interval where the model carries the term
    (``<q>_detected``; an upper end the fit left open is the Allan deviation's bound ``<q>_upper90``), its 90 %
    upper bound from the Allan deviation where it does not (flag :data:`UPPER_BOUND`; "not identified" without
    one)."""
    upper = block.get(f"{q}_upper90")
    if block.get(f"{q}_detected"):
        ci = block.get(f"{q}_ci90") or (math.nan, math.nan)
        value, (lo, hi) = float(block[q]), (math.nan if v is None else float(v) for v in ci)
        if upper is not None and math.isfinite(upper) and not hi < value * EXTREME_FACTOR:
            # the Allan curve bounds every term: its bound, not "unbounded", ends an interval the fit left open
            hi = max(float(upper), value)
        return Estimate(value, lo, hi)
    if upper is not None and math.isfinite(upper):
        return Estimate(float(upper), flag=UPPER_BOUND)
    return Estimate(math.nan, flag=NOT_IDENTIFIED)


def model_estimate(fit, name: str) -> Estimate:
    """A noise-model parameter (sigma_w, sigma_b, tau_b) with its 90 % interval and :func:`param_flag`."""
    value = float(getattr(fit, name))
    ci = fit.ci90.get(name) or fit.ci90.get(param_key(fit, name)) or (math.nan, math.nan)
    return Estimate(value, float(ci[0]), float(ci[1]), param_flag(fit, name))


def model_nbk(r: ChannelAnalysis) -> dict[str, Estimate]:
    """N, B, K of one analysed channel as its noise model gives them (the fit's ``ieee952`` block; N is
    sigma_w): the one answer every output prints for the channel (issue 34)."""
    fit = r.noise_model
    block = r.ieee952(fit)
    return {"N": model_estimate(fit, "sigma_w"), "B": nbk_estimate(block, "B"), "K": nbk_estimate(block, "K")}


def noise_rows(results: list[ChannelAnalysis]) -> list[NoiseRow]:
    """Rows for every analysed channel: run-file ``device/gyro|accel/axis`` ids or channels with units."""
    rows = []
    for r in results:
        device, sensor, axis = split_channel_id(r.channel)
        fit = r.noise_model
        nbk = model_nbk(r)
        vals = {
            "sigma_w": fit.sigma_w,
            "sigma_b": fit.sigma_b,
            "tau_b": fit.tau_b,
            **{q: e.value for q, e in nbk.items()},
            "adev_1s": r.ieee.adev_1s,
        }
        flags = {q: param_flag(fit, q) for q in ("sigma_b", "tau_b")}
        flags |= {q: e.flag for q, e in nbk.items()}
        # sigma_w and N read the same fine scales: a doubt about one is a doubt about the other
        flags["sigma_w"] = density_flag(fit)
        flags["N"] = flags["N"] or flags["sigma_w"]
        flags = {q: f for q, f in flags.items() if f}
        adq = r.adequacy_of(r.noise_model)
        verdict = (adq.verdict, adq.p_value, "; ".join(m.describe() for m in adq.misfit)) if adq else ("", math.nan, "")
        ie = r.ieee
        rows.append(
            NoiseRow(
                device, sensor, axis, r.channel.n, r.channel.fs_hz, fit.model, vals, flags, *verdict,
                lo={q: e.lo for q, e in nbk.items()}, hi={q: e.hi for q, e in nbk.items()},
                allan={"N": ie.N, "B": ie.B, "K": ie.K},
                allan_unusable={q: w for q, w in (("N", ie.N_unusable), ("B", ie.B_unusable)) if w},
            )
        )  # fmt: skip
    return rows


def fmt_number(x: float | None, digits: int = 3) -> str:
    """``x`` to ``digits`` significant digits; "—" for None/NaN, "∞" for infinity."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return DASH
    if math.isinf(x):
        return "∞" if x > 0 else "−∞"
    return f"{x:.{digits}g}"


def fmt_flagged(x: float | None, flag: str, digits: int = 3) -> str:
    """A table cell: the number, "—" when not fitted, "at bound (…)" / "not identified" otherwise."""
    if flag == NOT_FITTED:
        return DASH
    if flag == AT_BOUND:
        return f"at bound ({fmt_number(x, digits)})"
    if flag == NOT_IDENTIFIED:
        return NOT_IDENTIFIED
    if flag == DOUBTFUL:
        return f"doubtful ({fmt_number(x, digits)})"
    if flag == UPPER_BOUND:
        return f"< {fmt_number(x, digits)}"
    return fmt_number(x, digits)


def fmt_estimate(e: Estimate, factor: float = 1.0, digits: int = 3) -> str:
    """``35.0 [34.8, 35.2]`` (times ``factor``); flags as :func:`fmt_flagged` ("< x" for an upper bound)."""
    if e.flag or not math.isfinite(e.value):
        return fmt_flagged(e.value * factor, e.flag, digits)
    v, lo, hi = e.value * factor, e.lo * factor, e.hi * factor
    if math.isnan(lo) and math.isnan(hi):
        return fmt_number(v, digits)
    if not (lo > v / EXTREME_FACTOR and hi < v * EXTREME_FACTOR):
        # an interval reaching its search range: '[~0, unbounded]', as analyze prints it (the summary and
        # the noise table printed '0.797 [5.25e-26, 1.12e+25]' for a B the record does not pin down)
        return f"{fmt_number(v, digits)} {interval(v, lo, hi, f'.{digits}g')}"
    # enough digits that a narrow interval does not print as [x, x]; an end equal to the value stays equal
    distinct = len({lo, v, hi})
    while digits < 6 and len({fmt_number(lo, digits), fmt_number(v, digits), fmt_number(hi, digits)}) < distinct:
        digits += 1
    return f"{fmt_number(v, digits)} [{fmt_number(lo, digits)}, {fmt_number(hi, digits)}]"


#: the IEEE-952 terms with a 90 % interval in the table
NBK = ("N", "B", "K")


def _cell(r: NoiseRow, q: str, factor: float) -> str:
    """A Markdown cell: N, B, K with their 90 % interval, the other quantities as :func:`fmt_flagged`."""
    if q in NBK:
        e = Estimate(r.values[q], r.lo.get(q, math.nan), r.hi.get(q, math.nan), r.flag(q))
        return fmt_estimate(e, factor)
    return fmt_flagged(r.values[q] * factor, r.flag(q))


def _allan_cell(r: NoiseRow, q: str, factor: float) -> str:
    """The classical Allan fit's ``q``: "—" when the fit set it to 0, "unusable" with the reason's key."""
    v = r.allan.get(q, math.nan)
    if q in r.allan_unusable:
        return f"unusable ({fmt_number(v * factor)})"
    return fmt_flagged(v * factor, ieee_flag(v))


def table_csv(rows: list[NoiseRow]) -> str:
    """CSV: identification columns, then per quantity its SI value, SI unit, display value, display unit, flag;
    then the model fit; then (added) the 90 % interval of N, B, K (SI) and the classical Allan-curve fit's
    N, B, K (SI, ``N_allan``...; empty when that fit set the term to 0) with ``allan_note`` (why unusable)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = ["device", "sensor", "axis", "n", "fs_hz", "model"]
    for q in QUANTITIES:
        head += [q, f"{q}_unit", f"{q}_display", f"{q}_display_unit", f"{q}_flag"]
    tail = [f"{q}_{end}90" for q in NBK for end in ("lo", "hi")] + [f"{q}_allan" for q in NBK] + ["allan_note"]
    w.writerow(head + ["model_fit", "model_fit_p", "model_fit_where"] + tail)
    for r in rows:
        line = [r.device, r.sensor, r.axis, r.n, f"{r.fs_hz:g}", r.model]
        for q in QUANTITIES:
            si, disp, _ = units_of(r.sensor, q)
            if r.flag(q) == NOT_FITTED:
                line += ["", si, "", disp, r.flag(q)]
            else:
                line += [repr(float(r.values[q])), si, repr(float(r.display(q))), disp, r.flag(q)]
        line += [r.fit, repr(float(r.fit_p)), r.fit_where]
        line += [repr(float(d.get(q, math.nan))) for q in NBK for d in (r.lo, r.hi)]
        line += ["" if not r.allan.get(q) else repr(float(r.allan[q])) for q in NBK]
        w.writerow(line + ["; ".join(f"{q}: {why}" for q, why in r.allan_unusable.items())])
    return buf.getvalue()


def _fit_text(r: NoiseRow) -> str:
    """``fits`` / ``does not fit: 5.2-98 s model low`` / ``–`` (no adequacy)."""
    if not r.fit:
        return "–"
    return f"{r.fit}: {r.fit_where}" if r.fit_where else r.fit


def by_sensor(rows: list[NoiseRow]) -> dict[str, list[NoiseRow]]:
    out: dict[str, list[NoiseRow]] = {}
    for r in rows:
        out.setdefault(r.sensor, []).append(r)
    return out


def table_markdown(rows: list[NoiseRow]) -> str:
    """One Markdown table per sensor kind; each quantity in SI and display units."""
    parts = []
    for sensor, rs in by_sensor(rows).items():
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
                si, disp, k = units_of(sensor, q)
                cells.append(_cell(r, q, 1.0))
                if si != disp:
                    cells.append(_cell(r, q, k))
            cells.append(_fit_text(r))
            lines.append("| " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
        parts.append(_allan_markdown(sensor, rs))
    return "\n\n".join(parts) + "\n"


def _allan_markdown(sensor: str, rs: list[NoiseRow]) -> str:
    """The classical IEEE-952 fit of the Allan curve, display units: a comparison, not the table's N, B, K."""
    head = ["device", "axis"] + [f"{q} [{units_of(sensor, q)[1]}]" for q in NBK] + ["note"]
    lines = [f"**{sensor}: classical IEEE-952 fit of the Allan curve (comparison only; the N, B, K above are the "
             "noise model's)**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]  # fmt: skip
    for r in rs:
        cells = [r.device, f"{r.axis}-{sensor}"] + [_allan_cell(r, q, units_of(sensor, q)[2]) for q in NBK]
        note = "; ".join(f"{q}: {why}" for q, why in r.allan_unusable.items()) or "–"
        lines.append("| " + " | ".join(c.replace("|", "/") for c in [*cells, note]) + " |")
    return "\n".join(lines)


def _latex_unit(u: str) -> str:
    for k, v in _LATEX_UNIT.items():
        u = u.replace(k, v)
    u = u.replace("°", r"^\circ").replace("µ", r"\mu ").replace("²", "^2").replace("³", "^3")
    return rf"$[\mathrm{{{u}}}]$".replace(r"\mathrm{^\circ", r"\mathrm{{}^\circ")


def _latex_num(x: float, flag: str = "") -> str:
    if flag == NOT_FITTED or math.isnan(x):
        return "--"
    if flag == NOT_IDENTIFIED:
        return r"\textit{n.i.}"
    if flag == UPPER_BOUND:
        return "$<$" + _latex_num(x)
    if math.isinf(x):
        return r"$\infty$"
    m, e = f"{x:.2e}".split("e")
    e = int(e)
    num = f"${m}$" if e == 0 else rf"${m}\times10^{{{e}}}$"
    return num + {AT_BOUND: r"\textsuperscript{b}", DOUBTFUL: r"\textsuperscript{d}"}.get(flag, "")


def _latex_text(s: str) -> str:
    return s.replace("\\", r"\textbackslash{}").replace("_", r"\_").replace("&", r"\&").replace("%", r"\%")


def table_latex(rows: list[NoiseRow]) -> str:
    """One ``tabular`` per sensor kind (booktabs rules), SI and display columns."""
    parts = []
    for sensor, rs in by_sensor(rows).items():
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
            rf"% {sensor}: noise model sigma_w, sigma_b, tau_b; the IEEE-952 N, B, K the noise model implies;"
            " Allan deviation at 1 s; model adequacy (fits / does not fit the measured Allan variance)",
            r"% --: not fitted (no such term); $<$x: 90 % upper bound (term not detected); b: at the search bound;"
            " n.i.: not identified",
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
                f = r.flag(q)
                cells += [_latex_num(r.values[q], f)] + ([] if si == disp else [_latex_num(r.display(q), f)])
            cells.append(_latex_text(r.fit) if r.fit else "--")
            lines.append(" & ".join(cells) + r" \\")
        lines += [r"\bottomrule", r"\end{tabular}"]
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"


# -- bias temperature coefficients ----------------------------------------------------------------


@dataclass(frozen=True)
class TempcoRow:
    """The bias of one axis regressed on one temperature: ``result`` (a
    :class:`~.temperature.TempcoResult`, slope in SI unit/K) or None with the ``reason``."""

    channel: str
    sensor: str
    source: str
    result: object | None
    reason: str = ""
    #: passes the report's family-wise test (Holm over all its coefficients; temperature.holm)
    listed: bool = False


def tempco_csv(rows: list[TempcoRow]) -> str:
    """Every coefficient (significant or not), SI and display, with the autocorrelation test."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        ["channel", "temperature", "slope", "slope_unit", "slope_display", "slope_display_unit", "stderr_ols",
         "stderr_eff", "n_blocks", "n_eff", "rho_temp", "rho_resid", "p_value", "significant", "listed", "span_k",
         "r2", "note"]
    )  # fmt: skip
    for r in rows:
        si, disp, k = display_units(r.sensor, "rate")
        tc = r.result
        if tc is None:
            w.writerow([r.channel, r.source, "", f"{si}/K", "", f"{disp}/K", *[""] * 11, r.reason])
            continue
        w.writerow(
            [r.channel, r.source, repr(tc.slope), f"{si}/K", repr(tc.slope * k), f"{disp}/K", repr(tc.slope_stderr),
             repr(tc.slope_stderr_eff), tc.n, f"{tc.n_eff:.4g}", f"{tc.rho_temp:.4f}", f"{tc.rho_resid:.4f}",
             f"{tc.p_value:.3g}", tc.significant, r.listed, f"{tc.span_c:.4g}", f"{tc.r2:.4f}", r.reason]
        )  # fmt: skip
    return buf.getvalue()


def tempco_markdown(rows: list[TempcoRow]) -> str:
    """The listed coefficients only (display units, inflated standard error); an empty string when none."""
    sig = [r for r in rows if r.result is not None and r.listed]
    if not sig:
        return ""
    head = ["channel", "temperature", "slope", "± (autocorrelation-corrected)", "p", "n_eff / blocks", "span [K]", "R²"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in sig:
        tc = r.result
        _, disp, k = display_units(r.sensor, "rate")
        cells = [r.channel, r.source, f"{tc.slope * k:.3g} {disp}/K", f"{tc.slope_stderr_eff * k:.2g}",
                 f"{tc.p_value:.2g}", f"{tc.n_eff:.0f} / {tc.n}", f"{tc.span_c:.2f}", f"{tc.r2:.2f}"]  # fmt: skip
        lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    return "\n".join(lines) + "\n"
