"""The text table ``imustation analyze`` prints: one row per channel, then what needs attention.

One block per sensor kind, in the display units of that kind (the paper's Table IV units;
:func:`imustation.units.display_units`). Every column keeps one meaning on every row, the
report's summary table's (:func:`.summary.channel_estimates`: the same numbers): N (the noise
model's sigma_w), B and K (bias instability and rate random walk the noise model implies, its
``ieee952`` block, as the verdict and ``export`` read them; "< x" a 90 % upper bound where the
record does not show the term),
the bias model's Gauss-Markov sigma_b and tau_b ("—" for a model without one: a random walk's
K is not a sigma_b), each with its 90 % interval; then the model, whether it fits the Allan
deviation and the "enough data?" verdict. A value that is not an estimate is printed as such
("—", "at bound (...)", "not identified", an interval reaching its search range as
"[~0, unbounded]": :mod:`.numbers`).

Below the table one short line per channel that needs attention (the model does not fit, a
parameter at its bound or not identified, the fit did not converge, not enough data), its
first reasons; ``verbose`` adds every fitted block (the comparison fits, the automatic choice,
the adequacy of each, every reason). The JSON (``--json``) has all of it.
"""

from __future__ import annotations

import math
import os

from imustation.analysis.estimators.selection.adequacy import NO_FIT
from imustation.analysis.reports.numbers import EXTREME_FACTOR, interval
from imustation.analysis.reports.summary import SUMMARY_QUANTITIES, Estimate, channel_estimates
from imustation.analysis.reports.tables import (
    AT_BOUND,
    NOT_IDENTIFIED,
    fmt_estimate,
    fmt_flagged,
    fmt_number,
    nbk_estimate,
    param_flag,
)
from imustation.analysis.reports.wording import user_text
from imustation.units import display_units, sensor_kind

#: sensor kind -> the heading of its block in the text table
_KIND_TITLES = {"gyro": "gyroscopes", "accel": "accelerometers", None: "plain arrays, in their own unit"}
#: reasons shown per channel in the attention list (the rest: --verbose, --json)
ATTENTION_REASONS = 1
#: channels with the same attention text from this many on share one line
SHARED_ATTENTION = 3
#: what the columns are, printed under the table
KEY = (
    "N: the noise model's sigma_w; B, K: the model's IEEE-952 terms (< x: 90 % upper bound, not detected); "
    "sigma_b, tau_b: the model's Gauss-Markov bias; "
    "[90 % interval]; fit: the model against the Allan deviation"
)
#: what the flags in the table mean, printed under it when one occurs
LEGEND = (
    "—: no such term in the model; at bound: the fit stopped at its search "
    "bound (no estimate); not identified: the 90 % interval is missing or spans more than two decades"
)


def cell(e: Estimate, factor: float = 1.0) -> str:
    """``35.1 [35.0, 35.2]`` (times ``factor``); a flagged value as :func:`.tables.fmt_flagged`; an
    interval reaching its search range as :func:`.numbers.interval` (``[~0, unbounded]``)."""
    v = e.value * factor
    if e.flag or not math.isfinite(v):
        return fmt_flagged(v, e.flag)
    lo, hi = e.lo * factor, e.hi * factor
    if not (math.isfinite(lo) and math.isfinite(hi)) and math.isnan(lo) and math.isnan(hi):
        return fmt_number(v)
    if not (lo > v / EXTREME_FACTOR and hi < v * EXTREME_FACTOR):
        return f"{fmt_number(v)} {interval(v, lo, hi)}"
    # enough digits that a narrow interval does not print as [x, x]; an end equal to the value (a
    # degenerate interval) stays equal at any precision, so it does not ask for more digits
    distinct = len({lo, v, hi})
    digits = 3
    while digits < 6 and len({fmt_number(lo, digits), fmt_number(v, digits), fmt_number(hi, digits)}) < distinct:
        digits += 1
    return f"{fmt_number(v, digits)} [{fmt_number(lo, digits)}, {fmt_number(hi, digits)}]"


def _fit_word(r) -> str:
    adq = r.adequacy_of(r.noise_model)
    word = "—" if adq is None else adq.verdict
    return word if r.noise_model.converged or r.noise_model.at_bound else f"{word}, not converged"


def attention(r) -> list[str]:
    """What needs attention on one channel (empty when nothing): the model does not fit, parameters
    at their bound or not identified, no convergence, the verdict's problems."""
    fit = r.noise_model
    out = []
    adq = r.adequacy_of(fit)
    if adq is not None and adq.verdict == NO_FIT:
        where = adq.misfit[0].describe() + (" ..." if len(adq.misfit) > 1 else "") if adq.misfit else ""
        out.append(f"{fit.model} does not fit the Allan deviation" + (f" ({where})" if where else ""))
    flagged = {q: param_flag(fit, q) for q in ("sigma_b", "tau_b")}
    bound = [q for q, f in flagged.items() if f == AT_BOUND]
    unident = [q for q, f in flagged.items() if f == NOT_IDENTIFIED]
    if bound:
        out.append(f"{', '.join(bound)} at the search bound")
    if unident:
        out.append(f"{', '.join(unident)} not identified")
    if not fit.converged and not fit.at_bound:
        out.append("fit not converged")
    v = r.verdict
    if v is not None and v.verdict != "enough":
        more = len(v.problems) - ATTENTION_REASONS
        first = "; ".join(v.problems[:ATTENTION_REASONS])
        out.append(f"{v.verdict} data: {first}" + (f" (+{more} more)" if more > 0 else ""))
    return out


def attention_lines(todo: list[tuple[str, list[str]]]) -> list[str]:
    """The "needs attention" list: one line per channel, except that channels with the very same
    text share one line (:data:`SHARED_ATTENTION` or more): a 12 s record of the whole lab printed
    31 lines of the same "record of 12 s is shorter than 60 s", the table's rows hidden above them."""
    texts: dict[str, list[str]] = {}
    for lab, items in todo:
        texts.setdefault("; ".join(items), []).append(lab)
    out = []
    for lab, items in todo:
        text = "; ".join(items)
        labs = texts[text]
        if len(labs) < SHARED_ATTENTION:
            out.append(f"  {lab}: {text}")
        elif lab == labs[0]:
            named = ", ".join(labs[:2]) + (f" and {len(labs) - 2} more" if len(labs) > 2 else "")
            out.append(f"  {len(labs)} channels ({named}): {text}")
    return out


def _details(r, label: str) -> list[str]:
    """--verbose: every fitted block, the automatic choice, each adequacy and every verdict reason."""
    lines = [f"{label}:"]
    for key, fit in r.blocks().items():
        flag = "converged" if fit.converged else user_text(fit.message)
        adq = r.adequacy_of(fit)
        s = r.ieee952(fit)
        # B and K as every other output gives them: "< x" where the record does not show the term
        shown = [q for q in ("B", "K") if s[q] is not None or s.get(f"{q}_upper90") is not None]
        nbk = "  ".join(
            [f"N {fmt_number(s['N'])} {interval(s['N'], *s['N_ci90'])}"] * (s["N"] is not None)
            + [f"{q} {fmt_estimate(nbk_estimate(s, q))}" for q in shown]
        )
        lines.append(f"  {key}: {fit.estimator} {fit.model}  {nbk}  ({flag}; {adq.summary() if adq else 'not tested'})")
    if r.choice is not None:
        lines.append(f"  choice: {r.choice.reason}")
    if r.verdict is not None:
        lines.append(f"  enough data? {r.verdict.verdict}: " + "; ".join(r.verdict.reasons))
    return lines


def results_table(results, verbose: bool = False) -> str:
    """The text of ``analyze``: the table (one row per channel), what needs attention, and with
    ``verbose`` every block's details (module docstring)."""
    inputs = {r.channel.source: os.path.basename(r.channel.source) for r in results}
    if len(set(inputs.values())) < len(inputs):  # same file name in two folders
        inputs = {src: src for src in inputs}
    several = len(inputs) > 1

    def label(r) -> str:
        return f"{inputs[r.channel.source]}: {r.channel.id}" if several else r.channel.id

    groups: dict = {}
    for r in results:
        groups.setdefault(sensor_kind(r.channel.units, r.channel.id), []).append(r)
    lines: list[str] = []
    flagged = False
    for kind, rs in groups.items():
        factors = {key: display_units(kind, dim) for key, _, dim in SUMMARY_QUANTITIES}
        head = (["input"] if several else []) + ["channel", "model"]
        head += [f"{title} [{factors[key][1]}]" for key, title, _ in SUMMARY_QUANTITIES] + ["fit", "enough data?"]
        body = []
        for r in rs:
            est = channel_estimates(r)
            cells = ([inputs[r.channel.source]] if several else []) + [r.channel.id, r.noise_model.model]
            cells += [cell(est[key], factors[key][2]) for key, _, _ in SUMMARY_QUANTITIES]
            cells += [_fit_word(r), r.verdict.verdict if r.verdict is not None else "—"]
            flagged |= any(e.flag for e in est.values())
            body.append(cells)
        widths = [max(len(row[i]) for row in [head, *body]) for i in range(len(head))]
        if lines:
            lines.append("")
        # the columns are in display units (°/h..., µg...): the title names those, and where SI is given
        si, shown, _ = display_units(kind, "rate")
        lines.append(_KIND_TITLES[kind] + (f" (in {shown} units; --json in SI, {si})" if kind else ""))
        for row in [head, *body]:
            lines.append("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())
            if row is head:
                lines.append("-" * len(lines[-1]))
    lines.append(KEY)
    if flagged:
        lines.append(LEGEND)
    todo = [(label(r), attention(r)) for r in results]
    todo = [(lab, items) for lab, items in todo if items]
    if todo:
        head = f"needs attention ({len(todo)} of {len(results)} channels; --verbose or --json for every reason):"
        lines += ["", head]
        lines += attention_lines(todo)
    if verbose:
        lines += ["", "details:"]
        for r in results:
            lines += _details(r, label(r))
    return "\n".join(lines)
