"""Damped Newton on a box for batched objectives: ``fun`` takes (K, d) points, returns (K,) values.

Gradient and Hessian come from one batched central-difference stencil per step
(:func:`stencil`, :func:`fd_derivatives`), so each step costs one call of ``fun``
on 2 d^2 + 1 points, which the likelihoods of this package evaluate as one
vectorised pass. Used by :func:`~.fitting.optimise` for ML_i, ML_i-F and ML on rates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class NewtonResult:
    """End point ``x`` of a Newton run, ``fun`` there, whether it ``converged``, why it stopped."""

    x: np.ndarray
    fun: float
    converged: bool
    message: str
    iterations: int


#: finite-difference step in log-parameters: the nll is computed to ~1e-7 nats,
#: so curvature from h = 0.02 is good to ~1e-3 relative
FD_STEP = 0.02
#: converged when the predicted decrease of a Newton step is below this (nats);
#: it moves the optimum by < 0.01 standard errors
TOL = 1e-5


def stencil(d: int) -> np.ndarray:
    """Offsets (2 d^2 + 1, d) of the central-difference stencil: centre, +-e_i, +-e_i +-e_j."""
    rows = [np.zeros(d)]
    for i in range(d):
        for s in (1, -1):
            v = np.zeros(d)
            v[i] = s
            rows.append(v)
    for i in range(d):
        for j in range(i + 1, d):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                v = np.zeros(d)
                v[i], v[j] = si, sj
                rows.append(v)
    return np.array(rows)


def fd_derivatives(f: np.ndarray, d: int, h: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Value, central-difference gradient and Hessian from values on ``stencil(d) * h``."""
    f0 = float(f[0])
    g = np.empty(d)
    H = np.empty((d, d))
    k = 1
    for i in range(d):
        g[i] = (f[k] - f[k + 1]) / (2 * h)
        H[i, i] = (f[k] - 2 * f0 + f[k + 1]) / h**2
        k += 2
    for i in range(d):
        for j in range(i + 1, d):
            fpp, fpm, fmp, fmm = f[k : k + 4]
            H[i, j] = H[j, i] = (fpp - fpm - fmp + fmm) / (4 * h * h)
            k += 4
    return f0, g, H


def newton(
    fun, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, stop=None, max_iter: int = 50, probe: tuple[int, ...] = ()
) -> NewtonResult:
    """Damped Newton on a box; gradient and Hessian from one batched stencil per step.

    Non-positive-definite Hessians are shifted to positive definite; steps are
    capped at 2 (log units), projected on the box and halved until the function
    decreases. ``stop(x, f, it)`` may end the run early (returns a message).
    ``probe``: coordinates (log variance ratios) that may vanish: each step also
    evaluates them at their lower bound and jumps there when that is no worse
    (a term absent from the data otherwise creeps down one log unit per step).
    """
    d = len(x0)
    S = stencil(d) * FD_STEP
    x = np.clip(np.asarray(x0, float), lo, hi)
    for it in range(1, max_iter + 1):
        probes = [j for j in probe if x[j] > lo[j]]
        P = np.repeat(x[None, :], len(probes), axis=0)
        for row, j in enumerate(probes):
            P[row, j] = lo[j]
        fa = fun(np.vstack([x[None, :] + S, P]))
        f_probe = fa[len(S) :]
        if len(probes) and float(f_probe.min()) <= float(fa[0]) + 1e-6:
            x = P[int(np.argmin(f_probe))]
            continue
        f0, g, H = fd_derivatives(fa[: len(S)], d, FD_STEP)
        if not np.isfinite(f0):
            return NewtonResult(x, f0, False, "likelihood not finite at start", it)
        if stop is not None:
            msg = stop(x, f0, it)
            if msg:
                return NewtonResult(x, f0, False, msg, it)
        # freeze coordinates at a bound whose gradient pushes outwards
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
        w, V = np.linalg.eigh(H[np.ix_(free, free)]) if free.any() else (np.ones(0), np.eye(0))
        pd = bool(np.all(w > 0))
        wmod = np.maximum(np.abs(w), 1e-3 * max(1.0, float(np.abs(w).max(initial=0.0))))
        step = np.zeros(d)
        gv = V.T @ g[free]
        step[free] = -V @ (gv / wmod)
        predicted = 0.5 * float(np.sum(gv * gv / wmod))  # decrease predicted by the (shifted) model
        if predicted < TOL:
            msg = "converged" if pd else "stationary but flat or curved down along a parameter (not identifiable)"
            return NewtonResult(x, f0, pd, msg, it)
        norm = float(np.linalg.norm(step))
        if norm > 2.0:
            step *= 2.0 / norm
        # backtracking line search, four step lengths per batched evaluation
        x_new = None
        for alphas in (1.0 / 2.0 ** np.arange(0, 4), 1.0 / 2.0 ** np.arange(4, 8), 1.0 / 2.0 ** np.arange(8, 12)):
            cand = np.clip(x[None, :] + alphas[:, None] * step[None, :], lo, hi)
            f_new = fun(cand)
            ok = f_new <= f0 + 1e-4 * alphas * float(g @ step)
            if ok.any():
                x_new = cand[int(np.argmax(ok))]
                break
        if x_new is None:
            ok = pd and float(np.abs(g[free]).max(initial=0.0)) < 1e-2
            return NewtonResult(x, f0, ok, "converged (flat optimum)" if ok else "no further decrease", it)
        if np.allclose(x_new, x, rtol=0, atol=1e-9):
            return NewtonResult(x, f0, pd, "converged at a search bound", it)
        x = x_new
    return NewtonResult(x, f0, False, f"no convergence in {max_iter} Newton steps", max_iter)
