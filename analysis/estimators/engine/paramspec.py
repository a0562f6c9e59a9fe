"""Parameter layout of a noise model: search vector theta <-> physical parameters <-> filter blocks.

The search runs over ``theta``: every variance relative to ``sigma_w^2`` (which the
likelihoods profile in closed form) and the logs of correlation times, so the
standard model is searched in 2 dimensions. Physical log-parameters ``phi``
(``log sigma_w`` first) are what results report. :class:`ParamSpec` maps between
the two, gives the search box for a record, the Kalman blocks of a parameter
point (:mod:`.kalman`), the model's Allan variance with ``sigma_w = 1``
(vectorised over parameter points, for the fine-scale terms of :mod:`.composite`)
and the :class:`~.noise_models.NoiseModel` of a fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from imustation.analysis.estimators.models.noise_models import (
    GaussMarkov,
    NoiseModel,
    RandomWalk,
    TermBlock,
    WhiteAngle,
    WhiteRate,
    gm_unit_avar,
    model_name,
    parse_model,
)
from imustation.analysis.estimators.models.sensor_terms import (
    BiasInstability,
    LowPass,
    flicker_times,
    flicker_weights,
)
from imustation.errors import InputError

#: a flicker term's Gauss-Markov components with correlation times below this fraction of
#: the shortest pattern interval are folded into white rate noise plus an angle deficit
#: (their neighbouring intervals are then uncorrelated to e^-10)
FOLD_FRACTION = 0.1

#: physical parameter name and search-coordinate kind of each single-coordinate term
_ONE = {"rw": ("sigma_k", "r_rw"), "wa": ("sigma_a", "r_wa"), "fl": ("B", "r_fl"), "lp": ("tau_lp", "t_lp")}


@dataclass(frozen=True)
class ParamSpec:
    """Parameter layout of a model.

    Search vector ``theta``: for each Gauss-Markov term ``log(sigma_b^2/sigma_w^2)``
    and ``log tau_b``; random walk ``log(sigma_k^2/sigma_w^2)``; white angle
    ``log(sigma_a^2/sigma_w^2)``; bias instability ``log(B^2/sigma_w^2)``; device
    filter ``log tau_lp``. Physical vector ``phi``: ``log sigma_w`` followed by the
    logs of ``sigma_b, tau_b`` / ``sigma_k`` / ``sigma_a`` / ``B`` / ``tau_lp`` in
    the same order. ``flicker_times`` (s): the correlation times of the bias
    instability's Gauss-Markov sum for the record (:func:`for_record`).
    """

    def _scale(self, code: str) -> float:
        return self.angle_scale if code in ("wa", "lp") else 1.0

    #: term codes as :func:`~.noise_models.parse_model` returns them, ``"wn"`` first
    codes: tuple[str, ...]
    flicker_times: tuple[float, ...] = ()
    #: the bias instability's cut-off, s (0: none): its sum starts there (sensor_terms)
    flicker_cut_s: float = 0.0
    #: the angle-noise coordinate (``wa``, ``lp``) is ``log(x) / angle_scale``: the two fine
    #: scales pin it down to ~1/z in log, far below the Newton's finite-difference step, so
    #: it is stretched to a comparable curvature (ML_i-F sets it from the filter test)
    angle_scale: float = 1.0

    @staticmethod
    def for_record(
        model: str | tuple[str, ...], fs_hz: float, duration_s: float, flicker_cut_s: float = 0.0
    ) -> ParamSpec:
        """The layout of ``model`` (a name or codes) for a record of ``duration_s`` s at ``fs_hz``;
        ``flicker_cut_s`` (s): the bias instability's cut-off (0: none)."""
        codes = parse_model(model) if isinstance(model, str) else tuple(model)
        if "fl" not in codes:
            return ParamSpec(codes)
        return ParamSpec(codes, flicker_times(fs_hz, duration_s, flicker_cut_s), flicker_cut_s)

    def with_record(self, fs_hz: float, duration_s: float) -> ParamSpec:
        """This layout with the flicker grid of the record filled in (if the model needs one)."""
        if "fl" in self.codes and not self.flicker_times:
            return replace(self, flicker_times=flicker_times(fs_hz, duration_s, self.flicker_cut_s))
        return self

    @property
    def name(self) -> str:
        """Canonical model name (``"wn+gm"``, ...)."""
        return model_name(self.codes)

    @property
    def fast(self) -> bool:
        """The standard model, which the prefix-scan filter of :mod:`.scan` evaluates."""
        return self.codes == ("wn", "gm")

    @property
    def others(self) -> tuple[str, ...]:
        """Codes of the terms besides the white rate noise, in search order."""
        return tuple(c for c in self.codes if c != "wn")

    @property
    def d(self) -> int:
        """Dimension of the search vector theta."""
        return sum(2 if c == "gm" else 1 for c in self.others)

    def phi_names(self) -> list[str]:
        """Names of the physical parameters, in the order of phi."""
        names = ["sigma_w"]
        k = 0
        ngm = self.codes.count("gm")
        for c in self.others:
            if c == "gm":
                k += 1
                sfx = "" if ngm == 1 else str(k)
                names += [f"sigma_b{sfx}", f"tau_b{sfx}"]
            else:
                names.append(_ONE[c][0])
        return names

    def theta_kinds(self) -> list[str]:
        """Kind of each search coordinate: ``r``/``tau`` (Gauss-Markov), ``r_rw``, ``r_wa``, ``r_fl``, ``t_lp``."""
        out = []
        for c in self.others:
            out += ["r", "tau"] if c == "gm" else [_ONE[c][1]]
        return out

    def bounds(self, inc) -> tuple[np.ndarray, np.ndarray]:
        """Search box ``(lo, hi)`` of theta for the record ``inc`` (:class:`~.pattern.Increments`)."""
        total = inc.duration
        dt_min = float(inc.dt.min())
        box = {
            # r = sigma^2/sigma_w^2 from "invisible over the record" to "dominates at one
            # interval"; a Gauss-Markov term can hide the white noise even with long
            # intervals (angle variance r tau^2 dt vs dt), so its bound uses tau >= 1/fs
            "r": (math.log(1e-6 / total**2), math.log(10.0 * inc.fs_hz**2)),
            "r_rw": (math.log(1e-6 / total**2), math.log(10.0 / dt_min**2)),
            "tau": (math.log(2.0 / inc.fs_hz), math.log(100.0 * total)),
            # white angle noise: from a ten-thousandth of a sample (the two fine scales see it) up
            "r_wa": (math.log(1e-4 / inc.fs_hz), math.log(10.0 * total)),
            # flicker floor B^2 vs the white level sigma_w^2/tau: invisible at the record length .. dominant
            # at one sample
            "r_fl": (math.log(1e-4 / total), math.log(100.0 * inc.fs_hz)),
            # the angle deficit: from a thousandth of a sample to a tenth of the shortest interval
            "t_lp": (math.log(1e-3 / inc.fs_hz), math.log(0.1 * dt_min)),
        }
        lo, hi = zip(*(box[k] for k in self.theta_kinds()), strict=True)
        stretch = np.array([self.angle_scale if k in ("r_wa", "t_lp") else 1.0 for k in self.theta_kinds()])
        return np.array(lo) / stretch, np.array(hi) / stretch

    def _require_grid(self) -> None:
        if "fl" in self.codes and not self.flicker_times:
            raise InputError(f"model {self.name!r}: the bias instability needs the record's grid (for_record)")

    def blocks(self, theta: np.ndarray, fold_below: float = 0.0) -> tuple[list[TermBlock], np.ndarray]:
        """Kalman blocks (sigma_w = 1 units) and angle-noise ratio (s) for theta (K, d).

        Flicker components with correlation time at most ``fold_below`` (s) are folded:
        white rate ``q T^2`` plus angle noise ``-q T^3 / 2`` (exact for intervals long
        against T, like a device filter: module docstring of :mod:`.sensor_terms`).
        """
        self._require_grid()
        K = theta.shape[0]
        wn = np.ones(K)
        blocks = []
        r_angle = np.zeros(K)
        j = 0
        for c in self.others:
            if c == "gm":
                blocks.append(TermBlock("gm", np.exp(theta[:, j]), np.exp(theta[:, j + 1])))
                j += 2
                continue
            v = np.exp(theta[:, j] * self._scale(c))
            j += 1
            if c == "rw":
                blocks.append(TermBlock("rw", v))
            elif c == "wa":
                r_angle = r_angle + v
            elif c == "lp":
                r_angle = r_angle - 0.5 * v
            else:  # fl
                weights = flicker_weights(self.flicker_times, self.flicker_cut_s)
                for T, w in zip(self.flicker_times, weights, strict=True):
                    q = v * w
                    if T <= fold_below:
                        wn = wn + q * T * T
                        r_angle = r_angle - 0.5 * q * T**3
                    else:
                        blocks.append(TermBlock("gm", q, T))
        return [TermBlock("wn", wn), *blocks], r_angle

    def unit_avar(self, theta: np.ndarray, taus: np.ndarray, fs_hz: float) -> np.ndarray:
        """Allan variance with sigma_w = 1 at cluster times ``taus`` (s) of the sampled model, (K, J)."""
        self._require_grid()
        taus = np.atleast_1d(np.asarray(taus, dtype=float))
        K = theta.shape[0]
        out = np.tile(1.0 / taus, (K, 1))
        dt = 1.0 / fs_hz
        j = 0
        for c in self.others:
            if c == "gm":
                q, T = np.exp(theta[:, j]), np.exp(theta[:, j + 1])
                out += q[:, None] * np.column_stack([gm_unit_avar(T, t, fs_hz) for t in taus])
                j += 2
                continue
            v = np.exp(theta[:, j] * self._scale(c))
            j += 1
            if c == "rw":
                out += v[:, None] * (taus / 3.0 + dt * dt / (6.0 * taus))[None, :]
            elif c == "wa":
                out += 3.0 * v[:, None] / taus[None, :] ** 2
            elif c == "lp":  # beyond the filter's memory, whatever its shape (sensor_terms)
                out -= 1.5 * v[:, None] / taus[None, :] ** 2
            else:  # fl: the fixed sum's AVAR per unit B^2
                times = np.array(self.flicker_times)
                w = flicker_weights(times, self.flicker_cut_s)
                unit = np.array([float(np.sum(w * gm_unit_avar(times, t, fs_hz))) for t in taus])
                out += v[:, None] * unit[None, :]
        return out

    def theta_of_phi(self, phi: np.ndarray) -> np.ndarray:
        """phi (K, 1 + d) -> theta (K, d): variance ratios relative to sigma_w^2."""
        out = np.empty((phi.shape[0], self.d))
        j = 0
        for c in self.others:
            out[:, j] = (phi[:, j + 1] if c == "lp" else 2.0 * (phi[:, j + 1] - phi[:, 0])) / self._scale(c)
            if c == "gm":
                out[:, j + 1] = phi[:, j + 2]
                j += 2
            else:
                j += 1
        return out

    def phi_of_theta(self, theta: np.ndarray, sigma_w: float) -> np.ndarray:
        """theta (d,) and sigma_w (rate unit/sqrt(Hz)) -> phi (1 + d,)."""
        phi = np.empty(1 + self.d)
        phi[0] = math.log(sigma_w)
        j = 0
        for c in self.others:
            x = theta[j] * self._scale(c)
            phi[j + 1] = x if c == "lp" else phi[0] + 0.5 * x
            if c == "gm":
                phi[j + 2] = theta[j + 1]
                j += 2
            else:
                j += 1
        return phi

    def model(self, phi: np.ndarray, b_on: float, memory_s: float = 0.0) -> NoiseModel:
        """The :class:`~.noise_models.NoiseModel` at phi (1 + d,) with turn-on bias ``b_on`` (rate unit);
        ``memory_s`` (s): the device filter's memory, for an ``lp`` term."""
        self._require_grid()
        v = np.exp(phi)
        terms: list = [WhiteRate(float(v[0]))]
        j = 1
        for c in self.others:
            if c == "gm":
                terms.append(GaussMarkov(float(v[j]), float(v[j + 1])))
                j += 2
                continue
            x = float(v[j])
            j += 1
            if c == "rw":
                terms.append(RandomWalk(x))
            elif c == "wa":
                terms.append(WhiteAngle(x))
            elif c == "lp":
                terms.append(LowPass(float(v[0]), x, memory_s))
            else:
                terms.append(BiasInstability(x, self.flicker_times, self.flicker_cut_s))
        return NoiseModel(tuple(terms), b_on, name=self.name)
