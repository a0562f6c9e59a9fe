"""The standard inertial noise model (Nikolic et al. 2016, eq. 1a / 22a).

Rate ``z = b + v + b_on`` with ``db/dt = -b/tau_b + w``; ``v`` and ``w`` white
with densities ``sigma_w`` (rad s^-1/sqrt(Hz)) and ``sigma_b`` (rad s^-2/sqrt(Hz)).
This module holds the parameter dataclass, its simulator (Algorithm 1, exact
discretisation of eq. 8) and its closed-form Allan variance (eqs. 4, 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StandardModel:
    """Parameters of the standard model, SI units.

    sigma_w : white rate noise density, rad s^-1/sqrt(Hz) (or m s^-2/sqrt(Hz))
    sigma_b : bias diffusion, rad s^-2/sqrt(Hz) (or m s^-3/sqrt(Hz))
    tau_b   : bias correlation time, s (``inf`` for a random-walk bias)
    b_on    : turn-on bias, rad/s (or m/s^2)
    """

    sigma_w: float
    sigma_b: float
    tau_b: float
    b_on: float = 0.0

    def avar(self, tau: np.ndarray) -> np.ndarray:
        """Allan variance at cluster times ``tau`` (s), continuous-time model.

        White part eq. (4): sigma_w^2 / tau. Bias part eq. (6) (the paper prints
        sigma_w in eq. 6 where sigma_b is meant; IEEE 952 Table B.1):
        sigma_b^2 tau_b^2 / tau * [1 - tau_b/(2 tau) (3 - 4 e^{-tau/tau_b} + e^{-2 tau/tau_b})].
        """
        tau = np.asarray(tau, dtype=float)
        white = self.sigma_w**2 / tau
        if not np.isfinite(self.tau_b):
            return white + self.sigma_b**2 * tau / 3.0
        a = tau / self.tau_b
        # 1 - (3 - 4e^-a + e^-2a)/(2a) loses digits for small a; use its series there
        bracket = np.where(
            a > 1e-3,
            1.0 - (3.0 - 4.0 * np.exp(-a) + np.exp(-2.0 * a)) / (2.0 * np.where(a > 1e-3, a, 1.0)),
            a**2 / 3.0 - a**3 / 4.0 + 7.0 * a**4 / 60.0,
        )
        return white + self.sigma_b**2 * self.tau_b**2 / tau * bracket

    def adev(self, tau: np.ndarray) -> np.ndarray:
        return np.sqrt(self.avar(tau))

    def to_noise_model(self):
        """The same model as a :class:`.noise_models.NoiseModel` (PSD, discretisation)."""
        from imustation.analysis.estimators.models.noise_models import standard

        return standard(self.sigma_w, self.sigma_b, self.tau_b, self.b_on)


class StandardNoiseStream:
    """Seeded, block-wise simulator of the standard model (Algorithm 1).

    Successive :meth:`next` calls continue one realisation, so a chip
    simulator can draw samples as its virtual clock advances. Discretisation
    (eq. 8-9): ``b_k = phi b_{k-1} + w_k``, ``phi = exp(-dt/tau_b)``,
    ``Var w_k = sigma_b^2 tau_b/2 (1 - phi^2)`` (exact, eq. 8b);
    ``Var v_k = sigma_w^2 / dt`` (white noise band-limited to Nyquist, eq. 9);
    ``b_0 ~ N(0, sigma_b^2 tau_b / 2)`` (stationary start).

    Parameters
    ----------
    model : the parameters (SI units).
    fs_hz : sampling rate, Hz.
    rng : numpy Generator (seeded by the caller).
    """

    def __init__(self, model: StandardModel, fs_hz: float, rng: np.random.Generator):
        self.model = model
        self.dt = 1.0 / float(fs_hz)
        self.rng = rng
        m = model
        self.sigma_wd = m.sigma_w / np.sqrt(self.dt)
        if np.isfinite(m.tau_b):
            self.phi = float(np.exp(-self.dt / m.tau_b))
            self.sigma_bd = m.sigma_b * np.sqrt(-m.tau_b / 2.0 * np.expm1(-2.0 * self.dt / m.tau_b))
            self.b = float(rng.normal(0.0, m.sigma_b * np.sqrt(m.tau_b / 2.0)))
        else:
            self.phi = 1.0
            self.sigma_bd = m.sigma_b * np.sqrt(self.dt)
            self.b = 0.0

    def next(self, n: int) -> np.ndarray:
        """The next ``n`` rate samples, rad/s (or m/s^2), including ``b_on``."""
        if n <= 0:
            return np.zeros(0)
        w = self.rng.normal(0.0, self.sigma_bd, n)
        from scipy.signal import lfilter  # here: scipy.signal loads scipy.stats (~1 s), simulators start without

        bias, _ = lfilter([1.0], [1.0, -self.phi], w, zi=[self.phi * self.b])
        self.b = float(bias[-1])
        v = self.rng.normal(0.0, self.sigma_wd, n)
        return bias + v + self.model.b_on


def simulate_standard(
    model: StandardModel, n: int, fs_hz: float, seed: int | np.random.Generator | None = None
) -> np.ndarray:
    """``n`` samples of the standard model at ``fs_hz`` (Algorithm 1), rad/s."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    return StandardNoiseStream(model, fs_hz, rng).next(n)
