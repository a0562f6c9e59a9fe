"""Fleet characterisation: one table over many runs and devices, repeatability, outliers.

* :class:`FleetRow` — one analysed axis of one run: device identity, ML_i ``sigma_w``,
  ``sigma_b``, ``tau_b`` and IEEE-952 ``N``, ``B``, ``K`` (SI), each with its standard error
  and a 90 % interval (built from the noise table's rows by
  :func:`imustation.analysis.reports.fleettable.fleet_rows`).
* :func:`common_models` — with ``--model auto``, one model for every run of the same
  driver, sensor and axis (each run chooses on its own; a table of sigma_b over runs
  that chose different models would compare different parameters).
* :func:`device_key` — which physical device a run's device is: its serial number
  where the chip reports one (ADIS16448 ``serial=``, Xsens ``device_id=``, or a
  ``serial`` device setting in the config), otherwise ``station/device name`` (chips
  such as the BMX055 or MPU-6500 only report a chip id, the same on every part).
* :func:`repeatability` — per device and axis, mean and standard deviation
  (``ddof=1``) of ``sigma_w``, ``sigma_b``, ``tau_b`` over its runs (the paper's Table III).
* :func:`flag_outliers` — robust z-score of ``log10`` of each of ``sigma_w``,
  ``sigma_b``, ``tau_b`` against the fleet of the same driver, sensor and axis:
  ``z = 0.6745 (x - median) / MAD`` (Iglewicz & Hoaglin); ``|z| > 3.5`` is an outlier.
  The spread has a floor, the median stated standard error of the group's
  values (in log10: ``se / (x ln 10)``), so values that agree to within their
  uncertainty (e.g. sigma_w equal to three digits, MAD ~ 0) are not called outliers. Groups of fewer than
  :data:`MIN_GROUP` values are not judged (``z`` NaN).

The rows' text (CSV, Markdown) is :mod:`imustation.analysis.reports.fleettable`'s.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from imustation.analysis.pipeline.channel import ChannelAnalysis, split_channel_id

#: quantities of the fleet table (SI): ML_i standard model, then IEEE-952
FLEET_QUANTITIES = ("sigma_w", "sigma_b", "tau_b", "N", "B", "K")
#: quantities judged for outliers and summarised for repeatability
MODEL_QUANTITIES = ("sigma_w", "sigma_b", "tau_b")
#: robust |z| above which a run is flagged
Z_LIMIT = 3.5
#: fewest runs of a driver/sensor/axis group for outlier flags
MIN_GROUP = 3
#: consistency constant of the MAD for a normal distribution (Iglewicz & Hoaglin)
_MAD_K = 0.6745
#: two-sided 90 % normal quantile for intervals built from a standard error
Z90 = 1.6448536269514722
#: identity fields that name one physical part
_UNIQUE_FIELDS = ("serial", "device_id", "lot", "uid")


def device_key(driver: str, identity: str, station: str, device: str, settings: dict | None = None) -> str:
    """A name for the physical device: ``driver:serial=...`` when the identity has a serial, else ``station/device``."""
    if settings and str(settings.get("serial", "")).strip():
        return f"{driver}:serial={str(settings['serial']).strip()}"
    fields = dict(re.findall(r"(\w+)=(\S+)", identity or ""))
    unique = [f"{k}={fields[k]}" for k in _UNIQUE_FIELDS if k in fields]
    if unique:
        return f"{driver}:" + ",".join(unique)
    return f"{station}/{device}" if station else device


@dataclass(frozen=True)
class FleetRow:
    """One axis of one run; ``values``, ``stderr``, ``lo``, ``hi`` in SI keyed by :data:`FLEET_QUANTITIES`.

    ``z``: robust z-scores of :data:`MODEL_QUANTITIES` (NaN when not judged);
    ``outliers``: the quantities with ``|z| > Z_LIMIT``.
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

    @property
    def group(self) -> tuple[str, str, str]:
        """(driver, sensor, axis): the population an outlier is judged against."""
        return (self.driver, self.sensor, self.axis)


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


def robust_z(x: np.ndarray, se: np.ndarray | None = None) -> np.ndarray:
    """Modified z-scores ``(x - median) / s`` of finite ``x`` (NaN stays NaN), ``s = MAD / 0.6745``.

    With MAD = 0 (over half the values equal) the mean absolute deviation
    scaled by 1.2533 (its normal consistency factor, 0.7979) stands in.
    ``se``: standard errors of ``x`` (same units); the spread is then at least
    their median (a floor: values that agree within their stated uncertainty get
    small z however tight the group; the median, as the MAD, is not moved by a
    few fits with a degenerate standard error). Equal values without a floor get 0.
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
    z[ok] = (x[ok] - med) / spread if spread > 0 else 0.0  # spread 0: every value equal
    return z


def _log10_se(row: FleetRow, q: str) -> float:
    """Standard error of log10 of quantity ``q`` of ``row``: from its standard error (delta method),
    else from its 90 % interval; NaN when neither is usable."""
    v, se = row.values[q], row.stderr.get(q, math.nan)
    if v > 0 and math.isfinite(se) and se > 0:
        return se / (v * math.log(10.0))
    lo, hi = row.lo.get(q, math.nan), row.hi.get(q, math.nan)
    if lo > 0 and hi > lo and math.isfinite(hi):
        return (math.log10(hi) - math.log10(lo)) / (2.0 * Z90)
    return math.nan


def flag_outliers(rows: Sequence[FleetRow], z_limit: float = Z_LIMIT, min_group: int = MIN_GROUP) -> list[FleetRow]:
    """Rows with ``z`` and ``outliers`` set: robust z of log10 of each model quantity within its group,
    its spread floored by the group's median standard error (module docstring)."""
    groups: dict[tuple[str, str, str], list[int]] = {}
    for i, r in enumerate(rows):
        groups.setdefault(r.group, []).append(i)
    zs: list[dict[str, float]] = [{q: math.nan for q in MODEL_QUANTITIES} for _ in rows]
    for idx in groups.values():
        if len(idx) < min_group:
            continue
        for q in MODEL_QUANTITIES:
            v = np.array([rows[i].values[q] for i in idx])
            with np.errstate(divide="ignore", invalid="ignore"):
                logv = np.where(v > 0, np.log10(np.where(v > 0, v, 1.0)), np.nan)
            logv[~np.isfinite(v)] = np.nan
            # at a bound / not identified: no estimate; doubtful: an interval far wider than the group spread
            logv[[bool(rows[i].flags.get(q)) for i in idx]] = np.nan
            se = np.array([_log10_se(rows[i], q) for i in idx])
            for i, z in zip(idx, robust_z(logv, se), strict=True):
                zs[i][q] = float(z)
    out = []
    for r, z in zip(rows, zs, strict=True):
        flags = tuple(q for q in MODEL_QUANTITIES if math.isfinite(z[q]) and abs(z[q]) > z_limit)
        flags += tuple(q for q in MODEL_QUANTITIES if math.isinf(z[q]))
        out.append(replace(r, z=z, outliers=flags))
    return out


@dataclass(frozen=True)
class RepeatRow:
    """Repeatability of one device axis over its runs: mean and std (ddof=1) per model quantity (SI)."""

    key: str
    driver: str
    sensor: str
    axis: str
    runs: int
    mean: dict[str, float]
    std: dict[str, float]


def repeatability(rows: Sequence[FleetRow]) -> list[RepeatRow]:
    """Table III: per device key and axis, in first-appearance order; std NaN for a single run."""
    groups: dict[tuple[str, str, str], list[FleetRow]] = {}
    for r in rows:
        groups.setdefault((r.key, r.sensor, r.axis), []).append(r)
    out = []
    for (key, sensor, axis), rs in groups.items():
        mean, std = {}, {}
        for q in MODEL_QUANTITIES:
            v = np.array([r.values[q] for r in rs])
            mean[q] = float(np.mean(v))
            std[q] = float(np.std(v, ddof=1)) if len(v) > 1 else math.nan
        out.append(RepeatRow(key, rs[0].driver, sensor, axis, len(rs), mean, std))
    return out
