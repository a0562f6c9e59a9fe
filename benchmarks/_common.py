"""Shared pieces of the analysis benchmarks (imported by the bench_*.py scripts run from this folder)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

import numpy as np

from imustation.analysis.estimators.models.noise_models import standard
from imustation.analysis.estimators.models.reference import TABLE_III_MEAN

T = TypeVar("T")
#: rate units per count of the int16 copy of the benchmark record (rad/s)
COUNT_SCALE = 6.1e-5


def best_of(fn: Callable[[], T], repeat: int) -> tuple[float, T]:
    """Best wall time (s) of ``repeat`` calls of ``fn`` and the last result."""
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def table_iii_record(hours: float, fs: float = 400.0) -> tuple[int, np.ndarray, np.ndarray]:
    """``hours`` of the paper's Table III standard model at ``fs`` Hz (seed 1), rad/s and int16 counts.

    Returns ``(n, rate, counts)``; ``counts * COUNT_SCALE`` approximates ``rate``.
    """
    n = int(hours * 3600 * fs)
    t = TABLE_III_MEAN
    x = standard(t.sigma_w, t.sigma_b, t.tau_b, 0.01).simulate(n, fs, 1)
    return n, x, np.rint(x / COUNT_SCALE).astype(np.int16)
