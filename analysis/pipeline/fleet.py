"""Fleet characterisation: one table over many runs and devices, repeatability, outliers.

* :class:`FleetRow` — one analysed axis of one run: device identity, the noise model's ``sigma_w``,
  ``sigma_b``, ``tau_b`` and the IEEE-952 ``N``, ``B``, ``K`` the model implies (its ``ieee952``
  block: the numbers ``analyze``, ``report``, the verdict and ``export`` give for the channel;
  a term the run does not show is its 90 % upper bound, flagged), SI, each with a 90 % interval
  and a standard error (built from the noise table's rows by
  :func:`imustation.analysis.reports.fleettable.fleet_rows`).
* :func:`common_models` — with ``--model auto``, one model for every run of the same
  driver, sensor and axis (each run chooses on its own; a table of sigma_b over runs
  that chose different models would compare different parameters).
* :func:`device_key` — which physical device a run's device is: its serial number
  where the chip reports one (ADIS16448 ``serial=``, Xsens ``device_id=``, or a
  ``serial`` device setting in the config), otherwise ``station/device name`` (chips
  such as the BMX055 or MPU-6500 only report a chip id, the same on every part).
* :func:`repeatability` — per device, axis and model, mean and standard deviation
  (``ddof=1``) of ``sigma_w``, ``sigma_b``, ``tau_b`` over its runs (the paper's Table III);
  runs of different models are not averaged together (``sigma_b`` of a random-walk model is
  its rate random walk, not a Gauss-Markov density). The run-to-run scatter against the
  per-run intervals is :mod:`.scatter`'s.
* :func:`flag_outliers` — robust z-score of ``log10`` of each of :data:`JUDGED` (``sigma_w``
  (= N), ``B``, ``K``, ``sigma_b``, ``tau_b``) against the fleet of the same driver, sensor and
  axis (and, for ``sigma_b`` and ``tau_b``, the same model: only comparable parameters are
  compared; N, B, K are model-independent quantities):
  ``z = (x - median) / sqrt(s^2 + se_i^2)`` with ``s = MAD / 0.6745`` (Iglewicz & Hoaglin)
  and ``se_i`` the run's own standard error of log10 x, from its own 90 % interval
  (``log10(hi / lo) / (2 x 1.645)``: the intervals are symmetric in the logarithm), from its
  standard error where it has no interval; ``|z| > 3.5`` is an outlier. A run whose own
  interval reaches the group's median is no outlier, however tight the others are (a 12 s
  run's sigma_w 25.4 +- 0.32 was 'z -5.2' against 25.6). ``s`` has a floor, the median
  stated standard error of the group's values, so values that agree to within their
  uncertainty (e.g. sigma_w equal to three digits, MAD ~ 0) are not called outliers. A value
  that is not an estimate is no candidate (z NaN): a B or K the run does not show (its upper
  bound), a parameter at its search bound, not identified or doubtful. Groups
  of fewer than :data:`MIN_GROUP` such estimates are not judged (``z`` NaN): the MAD of three or
  four values flags trivial differences.
* Too-short runs are listed and left out of both (:attr:`FleetRow.excluded`): shorter than
  :data:`MIN_RUN_S`, or than :data:`MIN_RUN_FRACTION` of the median length of their group.

The rows' text (CSV, Markdown, JSON) is :mod:`imustation.analysis.reports.fleettable`'s.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from imustation.analysis.pipeline.channel import ChannelAnalysis, split_channel_id
from imustation.analysis.pipeline.verdict import MIN_RECORD_S

#: quantities of the fleet table (SI): the noise model's parameters, then the IEEE-952 terms it implies
FLEET_QUANTITIES = ("sigma_w", "sigma_b", "tau_b", "N", "B", "K")
#: quantities summarised for repeatability (Table III)
MODEL_QUANTITIES = ("sigma_w", "sigma_b", "tau_b")
#: quantities judged for outliers (N is sigma_w: judged once)
JUDGED = ("sigma_w", "B", "K", "sigma_b", "tau_b")
#: ... of those, the ones with one meaning in every model (judged over all models of a group)
ANY_MODEL = ("sigma_w", "B", "K")
#: robust |z| above which a run is flagged
Z_LIMIT = 3.5
#: fewest runs of a driver/sensor/axis group for outlier flags (the MAD of 3-4 values is itself noise)
MIN_GROUP = 5
#: a run shorter than this (s) is left out of the fleet statistics: the verdict's shortest record
MIN_RUN_S = MIN_RECORD_S
#: ... and one shorter than this fraction of its group's median length: its estimates rest on
#: other scales than the rest of the group's
MIN_RUN_FRACTION = 0.1
#: consistency constant of the MAD for a normal distribution (Iglewicz & Hoaglin)
_MAD_K = 0.6745
#: two-sided 90 % normal quantile for intervals built from a standard error
Z90 = 1.6448536269514722
#: identity fields that name one physical part
UNIQUE_FIELDS = ("serial", "device_id", "lot", "uid")


def device_key(driver: str, identity: str, station: str, device: str, settings: dict | None = None) -> str:
    """A name for the physical device: ``driver:serial=...`` when the identity has a serial, else ``station/device``."""
    if settings and str(settings.get("serial", "")).strip():
        return f"{driver}:serial={str(settings['serial']).strip()}"
    fields = dict(re.findall(r"(\w+)=(\S+)", identity or ""))
    unique = [f"{k}={fields[k]}" for k in UNIQUE_FIELDS if k in fields]
    if unique:
        return f"{driver}:" + ",".join(unique)
    return f"{station}/{device}" if station else device


@dataclass(frozen=True)
class FleetRow:
    """One axis of one run; ``values``, ``stderr``, ``lo``, ``hi`` in SI keyed by :data:`FLEET_QUANTITIES`.

    ``z``: robust z-scores of :data:`JUDGED` (NaN when not judged);
    ``outliers``: the quantities with ``|z| > Z_LIMIT``; ``excluded``: why the run is left out
    of the outlier test and the repeatability ("" when it is not).
    """

    run: str
    station: str
    device: str
    driver: str
    identity: str
    key: str
    sensor: str
    axis: str
    n: int
    fs_hz: float
    model: str
    converged: bool
    values: dict[str, float]
    stderr: dict[str, float]
    lo: dict[str, float]
    hi: dict[str, float]
    z: dict[str, float] = field(default_factory=dict)
    outliers: tuple[str, ...] = ()
    #: quantities that are not plain estimates (tables.NOT_FITTED, AT_BOUND, NOT_IDENTIFIED, DOUBTFUL)
    flags: dict[str, str] = field(default_factory=dict)
    excluded: str = ""
    #: what ``--warmup`` cut from the run's device (:meth:`.warmup.WarmupCut.describe`; "" when not known)
    warmup: str = ""
    #: the identity as a table shows it (the part-naming fields, an import's source file; "" = ``identity``)
    short_identity: str = ""
    #: the model ``--model auto`` chose for this run alone ("" without a choice); differs from ``model``
    #: where :func:`common_models` gave the group another one, so analyze of this run alone shows other numbers
    own_model: str = ""

    @property
    def group(self) -> tuple[str, str, str]:
        """(driver, sensor, axis): the population an outlier is judged against."""
        return (self.driver, self.sensor, self.axis)

    @property
    def duration_s(self) -> float:
        """The run's length (s) from its sample count and rate."""
        return self.n / self.fs_hz if self.fs_hz > 0 else math.nan


def by_model(candidates) -> dict:
    """One converged candidate per model name: a model fitted with and without a flicker cut-off
    (:mod:`imustation.analysis.estimators.selection.model_choice`) is represented by the fit that passes the
    adequacy test with the smallest BIC (the smallest BIC when none passes); the cut-off is that
    run's setting of the model, like its filter's time constant."""
    groups: dict[str, list] = {}
    for c in candidates:
        if c.result.converged:
            groups.setdefault(c.result.model, []).append(c)
    out = {}
    for model, group in groups.items():
        group.sort(key=lambda c: c.result.bic)
        out[model] = group[0] if len(group) == 1 else next((c for c in group if c.passes), group[0])
    return out


def common_models(results: Sequence[ChannelAnalysis]) -> list[ChannelAnalysis]:
    """``results`` with one noise model per (driver, sensor, axis) where ``--model auto`` chose.

    Every run's choice fitted the same candidates (:mod:`imustation.analysis.estimators.selection.model_choice`);
    per group the model kept is, among the candidates every run fitted and converged, the one
    the adequacy test passes on every run with the smallest BIC summed over the runs (the
    likelihood of the group); when none passes everywhere, the smallest summed BIC. Each run
    then reports its own fit of that model (its intervals, adequacy). Results without an
    automatic choice, and groups of one run, are returned unchanged.
    """
    groups: dict[tuple[str, str, str], list[int]] = {}
    for i, r in enumerate(results):
        if r.choice is not None and r.noise_method == "mli-f":
            _, sensor, axis = split_channel_id(r.channel)
            groups.setdefault((str(r.channel.meta.get("driver", "")), sensor, axis), []).append(i)
    out = list(results)
    for members in groups.values():
        if len(members) < 2:
            continue
        cands = [by_model(results[i].choice.candidates) for i in members]
        shared = set.intersection(*(set(c) for c in cands))
        if not shared:
            continue
        by_bic = sorted(shared, key=lambda m: (sum(c[m].result.bic for c in cands), m))
        # tested in that order: candidates the choice did not need are tested only when reached
        model = next((m for m in by_bic if all(c[m].passes for c in cands)), by_bic[0])
        for i, c in zip(members, cands, strict=True):
            res = results[i]
            if res.noise_model.model == model:
                continue
            fit = c[model]
            adequacy = {**res.adequacy, "noise_model": fit.check}
            out[i] = replace(res, noise_model=fit.result, adequacy=adequacy)
    return out


def robust_z(x: np.ndarray, se: np.ndarray | None = None, own_se: np.ndarray | None = None) -> np.ndarray:
    """Modified z-scores ``(x - median) / s`` of finite ``x`` (NaN stays NaN), ``s = MAD / 0.6745``.

    With MAD = 0 (over half the values equal) the mean absolute deviation
    scaled by 1.2533 (its normal consistency factor, 0.7979) stands in.
    ``se``: standard errors of ``x`` (same units); the spread is then at least
    their median (a floor: values that agree within their stated uncertainty get
    small z however tight the group; the median, as the MAD, is not moved by a
    few fits with a degenerate standard error). Equal values without a floor get 0.
    ``own_se``: each value's own standard error, added in quadrature to ``s`` for that value:
    ``(x_i - median) / sqrt(s^2 + own_se_i^2)`` (an unusable one counts as 0).
    """
    x = np.asarray(x, dtype=np.float64)
    z = np.full(x.shape, np.nan)
    ok = np.isfinite(x)
    if not ok.any():
        return z
    med = np.median(x[ok])
    dev = np.abs(x[ok] - med)
    mad = np.median(dev)
    spread = mad / _MAD_K if mad > 0 else 1.253314 * dev.mean()
    if se is not None:
        floor = np.asarray(se, dtype=np.float64)[ok]
        floor = floor[np.isfinite(floor) & (floor > 0)]
        if len(floor):
            spread = max(spread, float(np.median(floor)))
    scale = np.full(int(ok.sum()), spread)
    if own_se is not None:
        own = np.asarray(own_se, dtype=np.float64)[ok]
        own = np.where(np.isfinite(own) & (own > 0), own, 0.0)
        scale = np.hypot(scale, own)
    with np.errstate(divide="ignore", invalid="ignore"):  # scale 0: every value equal
        z[ok] = np.where(scale > 0, (x[ok] - med) / np.where(scale > 0, scale, 1.0), 0.0)
    return z


def interval_ln_se(lo: float, hi: float) -> float:
    """Standard error of the natural log of a quantity from its 90 % interval ``lo``..``hi`` (any one unit),
    taken as symmetric in the logarithm: ``ln(hi / lo) / (2 x 1.645)``; NaN without a usable interval."""
    if lo > 0 and hi > lo and math.isfinite(hi):
        return math.log(hi / lo) / (2.0 * Z90)
    return math.nan


def log10_se(row: FleetRow, q: str) -> float:
    """Standard error of log10 of quantity ``q`` of ``row``: from its own 90 % interval (symmetric in
    the logarithm), else from its standard error (delta method); NaN when neither is usable."""
    se = interval_ln_se(row.lo.get(q, math.nan), row.hi.get(q, math.nan))
    if math.isfinite(se):
        return se / math.log(10.0)
    v, se = row.values.get(q, math.nan), row.stderr.get(q, math.nan)
    if v > 0 and math.isfinite(se) and se > 0:
        return se / (v * math.log(10.0))
    return math.nan


def too_short(rows: Sequence[FleetRow]) -> list[FleetRow]:
    """Rows with ``excluded`` set for runs too short for the fleet statistics: shorter than
    :data:`MIN_RUN_S`, or than :data:`MIN_RUN_FRACTION` of their group's median length."""
    lengths: dict[tuple[str, str, str], list[float]] = {}
    for r in rows:
        lengths.setdefault(r.group, []).append(r.duration_s)
    median = {g: float(np.median(v)) for g, v in lengths.items()}
    out = []
    for r in rows:
        d = r.duration_s
        why = ""
        if not d >= MIN_RUN_S:
            why = f"too short ({d:.3g} s < {MIN_RUN_S:g} s)"
        elif d < MIN_RUN_FRACTION * median[r.group]:
            why = f"too short ({d:.3g} s < {MIN_RUN_FRACTION:g} x the group's median {median[r.group]:.3g} s)"
        out.append(replace(r, excluded=why) if why else r)
    return out


def flag_outliers(rows: Sequence[FleetRow], z_limit: float = Z_LIMIT, min_group: int = MIN_GROUP) -> list[FleetRow]:
    """Rows with ``excluded`` (:func:`too_short`), ``z`` and ``outliers`` set: robust z of log10 of each
    model quantity within its group of comparable runs, with each run's own standard error (module docstring)."""
    rows = too_short(rows)
    groups: dict[tuple, list[int]] = {}
    for i, r in enumerate(rows):
        if not r.excluded:
            groups.setdefault((*r.group, "*"), []).append(i)  # sigma_w, B, K: one meaning in every model
            groups.setdefault((*r.group, r.model), []).append(i)
    zs: list[dict[str, float]] = [{q: math.nan for q in JUDGED} for _ in rows]
    for key, idx in groups.items():
        if len(idx) < min_group:
            continue
        for q in ANY_MODEL if key[-1] == "*" else ("sigma_b", "tau_b"):
            v = np.array([rows[i].values.get(q, math.nan) for i in idx])
            with np.errstate(divide="ignore", invalid="ignore"):
                logv = np.where(v > 0, np.log10(np.where(v > 0, v, 1.0)), np.nan)
            logv[~np.isfinite(v)] = np.nan
            # at a bound / not identified / not detected (an upper bound): no estimate; doubtful: an interval
            # far wider than the group spread
            logv[[bool(rows[i].flags.get(q)) for i in idx]] = np.nan
            if np.isfinite(logv).sum() < min_group:  # e.g. K detected on two runs of five: no median to judge by
                continue
            se = np.array([log10_se(rows[i], q) for i in idx])
            for i, z in zip(idx, robust_z(logv, se, own_se=se), strict=True):
                zs[i][q] = float(z)
    out = []
    for r, z in zip(rows, zs, strict=True):
        flags = tuple(q for q in JUDGED if math.isfinite(z[q]) and abs(z[q]) > z_limit)
        flags += tuple(q for q in JUDGED if math.isinf(z[q]))
        out.append(replace(r, z=z, outliers=flags))
    return out


@dataclass(frozen=True)
class RepeatRow:
    """Repeatability of one device axis over its runs of one ``model``: mean and std (ddof=1) per
    model quantity (SI)."""

    key: str
    driver: str
    sensor: str
    axis: str
    runs: int
    mean: dict[str, float]
    std: dict[str, float]
    model: str = ""
    #: per quantity, the runs whose value entered the mean: a flagged value (at its search bound, not
    #: identified, doubtful) is left out, as in the outlier test; an infinite tau_b (a random walk)
    #: is the mean only when every run has it
    counted: dict[str, int] = field(default_factory=dict)


def repeatability(rows: Sequence[FleetRow]) -> list[RepeatRow]:
    """Table III: per device key, axis and model (runs of different models are different
    parameters), in first-appearance order; std NaN for a single run. Runs left out
    (:attr:`FleetRow.excluded`) are not counted, nor flagged values (:attr:`RepeatRow.counted`)."""
    groups: dict[tuple[str, str, str, str], list[FleetRow]] = {}
    for r in rows:
        if not r.excluded:
            groups.setdefault((r.key, r.sensor, r.axis, r.model), []).append(r)
    out = []
    for (key, sensor, axis, model), rs in groups.items():
        mean, std, counted = {}, {}, {}
        for q in MODEL_QUANTITIES:
            v = np.array([r.values[q] for r in rs if not r.flags.get(q)])
            counted[q] = len(v)
            if len(v) and np.all(np.isinf(v)) and len(set(v.tolist())) == 1:
                mean[q], std[q] = float(v[0]), math.nan  # e.g. tau_b inf on every run: a random walk
            elif len(v) and np.all(np.isfinite(v)):
                mean[q] = float(np.mean(v))
                std[q] = float(np.std(v, ddof=1)) if len(v) > 1 else math.nan
            else:
                mean[q] = std[q] = math.nan
        out.append(RepeatRow(key, rs[0].driver, sensor, axis, len(rs), mean, std, model, counted))
    return out
