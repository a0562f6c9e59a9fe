"""The text table ``imustation analyze`` prints: one block per sensor kind, every column with its unit.

The CLI parses and prints; the table is built here from the per-channel analyses
(:class:`~imustation.analysis.pipeline.channel.ChannelAnalysis`), beside the report's tables.
"""

from __future__ import annotations

import math


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
    import os

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
