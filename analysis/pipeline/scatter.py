"""A device's run-to-run scatter beside its per-run intervals (issues 32 and 34).

Each run of a device states N, B, K (and its model's sigma_b, tau_b) with a 90 % interval. Over
the runs of one device the values scatter; the question an engineer asks is whether they scatter
more than those intervals explain (the sensor changes between power-ups: a noise density that
moves a few % from run to run is the device, not the estimator). Per device key, sensor, axis and
quantity (and model, for sigma_b and tau_b, whose meaning depends on it), over the runs kept by
the fleet statistics (:attr:`.fleet.FleetRow.excluded` empty) whose value is an estimate (no
flag: a term a run does not show, its upper bound, is not a value to scatter):

* ``mean``, ``std`` (``ddof=1``) of the values (SI) and ``scatter`` = the standard deviation of
  their natural logarithms (a relative scatter: 0.03 = 3 %);
* ``halfwidth`` = the median over the runs of the relative half-width of their 90 % intervals
  (``ln(hi / lo) / 2``) and ``se`` = the same as a standard error (``/ 1.645``);
* the chi-square of the log values about their inverse-variance weighted mean,
  ``Q = sum((ln x_i - m)^2 / se_i^2)`` with ``runs - 1`` degrees of freedom (Cochran's Q), its
  p-value, and ``excess`` = the between-run scatter the intervals leave unexplained, the
  DerSimonian-Laird estimate ``sqrt(max(0, (Q - dof) / (S1 - S2 / S1)))`` (``S1 = sum w_i``,
  ``S2 = sum w_i^2``, ``w_i = 1 / se_i^2``), relative;
* ``verdict``: ``"exceeds the per-run intervals"`` when ``p <`` :data:`ALPHA`, ``"within the
  per-run intervals"`` otherwise, ``"one run"`` for a single run (no scatter to state).

Units: ``mean``, ``std`` in SI of the quantity; ``scatter``, ``halfwidth``, ``se``, ``excess``
dimensionless (relative).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from imustation.analysis.pipeline.fleet import ANY_MODEL, Z90, FleetRow, interval_ln_se

#: quantities whose scatter is stated (N is sigma_w; sigma_b, tau_b per model)
SCATTER_QUANTITIES = ("N", "B", "K", "sigma_b", "tau_b")
#: a chi-square p-value below this says the runs scatter more than their intervals explain
ALPHA = 0.01
EXCEEDS = "exceeds the per-run intervals"
WITHIN = "within the per-run intervals"
ONE_RUN = "one run"


@dataclass(frozen=True)
class Scatter:
    """The run-to-run scatter of one quantity of one device axis (module docstring); ``model`` is ""
    for N, B, K (compared over every model), ``runs`` the values counted, ``not_counted`` the kept
    runs whose value is not an estimate (not detected, at a bound, not identified, doubtful)."""

    key: str
    driver: str
    sensor: str
    axis: str
    quantity: str
    model: str
    runs: int
    not_counted: int
    mean: float
    std: float
    scatter: float
    halfwidth: float
    se: float
    chi2: float
    dof: int
    p_value: float
    excess: float
    verdict: str

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _log_se(r: FleetRow, q: str) -> float:
    """Standard error of ln of ``q`` from the run's 90 % interval (NaN without a usable one)."""
    return interval_ln_se(r.lo.get(q, math.nan), r.hi.get(q, math.nan))


def _one(key, rows: list[FleetRow], q: str, model: str) -> Scatter:
    usable = [
        r for r in rows
        if not r.flags.get(q) and r.values.get(q, math.nan) > 0 and math.isfinite(r.values[q])
        and math.isfinite(_log_se(r, q))
    ]  # fmt: skip
    n = len(usable)
    v = np.array([r.values[q] for r in usable])
    ln = np.log(v) if n else v
    se = np.array([_log_se(r, q) for r in usable])
    mean = float(np.mean(v)) if n else math.nan
    std = float(np.std(v, ddof=1)) if n > 1 else math.nan
    scatter = float(np.std(ln, ddof=1)) if n > 1 else math.nan
    half = float(np.median(se)) * Z90 if n else math.nan
    q_stat, p, excess, verdict = math.nan, math.nan, math.nan, ONE_RUN
    if n > 1:
        w = 1.0 / se**2
        m = float(np.sum(w * ln) / np.sum(w))
        q_stat = float(np.sum(w * (ln - m) ** 2))
        p = float(chi2.sf(q_stat, n - 1))
        s1, s2 = float(np.sum(w)), float(np.sum(w**2))
        excess = math.sqrt(max(0.0, (q_stat - (n - 1)) / (s1 - s2 / s1)))
        verdict = EXCEEDS if p < ALPHA else WITHIN
    return Scatter(*key, q, model, n, len(rows) - n, mean, std, scatter, half, half / Z90 if n else math.nan,
                   q_stat, max(n - 1, 0), p, excess, verdict)  # fmt: skip


def run_scatter(rows: Sequence[FleetRow]) -> list[Scatter]:
    """Per device key, sensor, axis and quantity (and model for sigma_b, tau_b), in first-appearance
    order, the run-to-run scatter of the runs kept by the fleet statistics; a group none of whose runs
    gives the quantity an estimate is left out (nothing to state)."""
    groups: dict[tuple, list[FleetRow]] = {}
    for r in rows:
        if not r.excluded:
            groups.setdefault((r.key, r.driver, r.sensor, r.axis, "*"), []).append(r)
            groups.setdefault((r.key, r.driver, r.sensor, r.axis, r.model), []).append(r)
    out = []
    for (*key, model), rs in groups.items():
        for q in SCATTER_QUANTITIES:
            any_model = q in ANY_MODEL or q == "N"
            if any_model != (model == "*"):
                continue
            s = _one(tuple(key), rs, q, "" if any_model else model)
            if s.runs:
                out.append(s)
    return out
