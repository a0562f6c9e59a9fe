"""Allan deviation and model overlay of gyro counts as a capture grows.

:class:`GyroBuffer` keeps one device's gyro counts in memory, appended block
by block as the watcher reads them. Its size is capped: past ``max_rows`` rows
it halves itself into means of 2 (then 4, 8, ...) samples, so a 12 h, 400 Hz
record costs at most ``max_rows x 3 x 8`` bytes (48 MiB by default) and the
shortest cluster time shown grows from 1/fs to ``decimation``/fs. Until the
first halving the counts stay integers and ``oadev`` integrates them exactly.

:func:`allan_curves` and :func:`model_curves` do the work of the analysis
thread: the project's ``oadev`` (log-spaced taus, pooled over the segments
between logged gaps) and the ML_i fit of the paper's standard model
(``wn+gm``, log pattern, m = 1000) with its closed-form Allan curve.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from imustation.analysis.estimators.classical.allan import oadev
from imustation.analysis.estimators.engine.pattern import integrate
from imustation.analysis.estimators.ml.mli import fit_integrated
from imustation.errors import ImustationError
from imustation.units import display_units

#: rows kept per device before the buffer halves itself (x 3 axes x 8 bytes at most)
MAX_ROWS = 1 << 21
#: fewest buffered rows an Allan curve is computed from
MIN_ROWS = 64
#: the overlay model: the paper's standard model (white rate noise + Gauss-Markov bias)
MODEL = "wn+gm"


@dataclass(frozen=True)
class Snapshot:
    """A consistent view of a buffer for the analysis thread (never modified afterwards).

    ``data`` (n, 3): integer counts (``decimation`` 1) or means of ``decimation``
    counts (float64); ``fs_hz`` the rate of the rows (Hz); ``scale`` rad/s per
    count; ``segments`` contiguous row ranges between logged gaps; ``raw_rows``
    samples of the file the rows stand for.
    """

    data: np.ndarray
    fs_hz: float
    scale: float
    decimation: int
    segments: list[tuple[int, int]]
    raw_rows: int
    axes: tuple[str, ...]


class GyroBuffer:
    """Append-only, size-capped copy of one device's gyro counts (see module docstring).

    fs_hz : the device's configured rate (Hz); scale : rad/s per count;
    axes : axis names (``x, y, z``); max_rows : rows kept before halving.
    """

    def __init__(self, fs_hz: float, scale: float, dtype: np.dtype, axes: tuple[str, ...], max_rows: int = MAX_ROWS):
        self.fs_hz = float(fs_hz)
        self.scale = float(scale)
        self.axes = axes
        self.max_rows = max(2 * MIN_ROWS, int(max_rows) - int(max_rows) % 2)  # even: halving keeps every row
        self.decimation = 1
        self._data = np.empty((min(1 << 16, self.max_rows), len(axes)), dtype=dtype)
        self.n = 0
        #: raw sample indices where the record breaks (logged gaps), from the watcher
        self.breaks: list[int] = []
        self._lock = threading.Lock()

    @property
    def consumed(self) -> int:
        """Raw rows of the file the buffer holds: the next block starts here."""
        return self.n * self.decimation

    def wanted(self, available: int) -> int:
        """Rows to read now from ``available`` rows on disk: whole groups of ``decimation``."""
        k = available - self.consumed
        return max(0, k - k % self.decimation)

    def append(self, raw: np.ndarray) -> None:
        """Append ``raw`` (k, 3) counts starting at raw row :attr:`consumed`; k a multiple of ``decimation``.

        When the rows do not all fit, the buffer is filled, halved, and the rest
        of the block is left to be read again (at the new decimation): callers
        loop on :meth:`wanted`.
        """
        d = self.decimation
        if len(raw) % d:
            raise ValueError(f"{len(raw)} rows is not a multiple of the decimation {d}")
        rows = raw if d == 1 else raw.reshape(-1, d, raw.shape[1]).mean(axis=1)
        with self._lock:
            room = self.max_rows - self.n
            self._put(rows[:room])
            if len(rows) > room:
                self._halve()

    def _put(self, rows: np.ndarray) -> None:
        need = self.n + len(rows)
        if need > len(self._data):
            cap = min(self.max_rows, max(need, 2 * len(self._data)))
            grown = np.empty((cap, self._data.shape[1]), dtype=self._data.dtype)
            grown[: self.n] = self._data[: self.n]
            self._data = grown  # a snapshot holding the old array keeps it intact
        if rows.dtype != self._data.dtype:
            self._data[self.n : need] = rows.astype(self._data.dtype)
        else:
            self._data[self.n : need] = rows
        self.n = need

    def _halve(self) -> None:
        """Means of pairs of rows: half the rows, twice the decimation (a new array)."""
        pairs = self.n // 2
        halved = np.empty((self.max_rows, self._data.shape[1]), dtype=np.float64)
        halved[:pairs] = self._data[: 2 * pairs].astype(np.float64).reshape(pairs, 2, -1).mean(axis=1)
        self._data = halved
        self.n = pairs
        self.decimation *= 2

    def snapshot(self) -> Snapshot | None:
        """The rows so far (``None`` while fewer than :data:`MIN_ROWS`)."""
        with self._lock:
            if self.n < MIN_ROWS:
                return None
            n, d = self.n, self.decimation
            # _put writes past n and growing or halving makes a new array: these rows never change
            data = self._data[:n]
            edges = sorted({b // d for b in self.breaks if 0 < b // d < n})
        bounds = [0, *edges, n]
        segments = [(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]
        return Snapshot(data, self.fs_hz / d, self.scale, d, segments, n * d, self.axes)


def allan_curves(snap: Snapshot) -> dict:
    """Overlapping Allan deviation of every axis: ``tau`` (s) and per axis ``adev``, ``lo``, ``hi`` (rad/s)."""
    t0 = time.perf_counter()
    out: dict = {"tau": [], "axes": {}}
    longest = max(b - a for a, b in snap.segments)
    if longest < 3:
        return out
    for j, axis in enumerate(snap.axes):
        col = np.ascontiguousarray(snap.data[:, j])
        res = oadev(col, snap.fs_hz, scale=snap.scale, segments=snap.segments)
        out["tau"] = res.tau
        out["axes"][axis] = {"adev": res.adev, "lo": res.adev_lo, "hi": res.adev_hi}
    out["compute_s"] = time.perf_counter() - t0
    return out


def parameter_units(kind: str = "gyro") -> dict:
    """Units of the overlay's fitted values, for the page to print beside them: per parameter its SI
    unit, display unit and SI -> display factor (:func:`imustation.units.display_units`)."""
    dims = {"sigma_w": "density", "sigma_b": "drift", "tau_b": "time", "b_on": "rate"}
    out = {}
    for name, dim in dims.items():
        si, display, factor = display_units(kind, dim)
        out[name] = {"si": si, "display": display, "factor": factor}
    return out


def model_curves(snap: Snapshot, tau: np.ndarray) -> dict:
    """ML_i fit of :data:`MODEL` per axis and its Allan deviation at ``tau`` (s).

    Per axis: ``sigma_w`` (rad s^-1/sqrt(Hz)), ``sigma_b`` (rad s^-2/sqrt(Hz)),
    ``tau_b`` (s), ``b_on`` (rad/s), ``converged``, ``at_bound`` (parameters that ended at their
    search bound: no estimate) and ``adev`` (rad/s); an axis
    whose fit fails holds ``error`` instead. ``units``: :func:`parameter_units` of a gyro.
    """
    t0 = time.perf_counter()
    axes: dict = {}
    tau = np.asarray(tau, dtype=float)
    for j, axis in enumerate(snap.axes):
        col = np.ascontiguousarray(snap.data[:, j])
        try:
            inc = integrate(col, snap.fs_hz, m=1000, pattern="log", scale=snap.scale, segments=snap.segments)
            res = fit_integrated(inc, MODEL)
        except (ImustationError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            axes[axis] = {"error": str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__}
            continue
        curve = res.noise_model.adev(tau) if res.noise_model is not None and len(tau) else np.zeros(0)
        axes[axis] = {
            "sigma_w": res.sigma_w,
            "sigma_b": res.sigma_b,
            "tau_b": res.tau_b if math.isfinite(res.tau_b) else None,
            "b_on": res.b_on,
            "converged": bool(res.converged),
            "at_bound": list(res.at_bound),
            "adev": curve,
        }
    return {
        "model": MODEL,
        "axes": axes,
        "units": parameter_units("gyro"),
        "fit_s": time.perf_counter() - t0,
        "raw_rows": snap.raw_rows,
    }
