"""Library of inertial noise terms as linear state-space models (SI units).

Each term of a composite rate noise ``z(t) = sum_j z_j(t) + b_on`` is one of

==============  =================  ================================  ==========================
term            parameters         continuous model                   states
==============  =================  ================================  ==========================
``WhiteRate``   ``sigma_w``        white rate noise v, PSD sigma_w^2  none (enters the angle)
``GaussMarkov`` ``sigma_b, tau_b`` db/dt = -b/tau_b + w, PSD(w) =    1 (b)
                                   sigma_b^2 (Nikolic et al. eq. 1b)
``RandomWalk``  ``sigma_k``        db/dt = w, PSD(w) = sigma_k^2      1 (b), starts at 0
                                   (IEEE-952 rate random walk K)
``WhiteAngle``  ``sigma_a``        iid angle error of variance        none (observation noise
                                   sigma_a^2 on every angle sample    of the angle)
==============  =================  ================================  ==========================

plus the turn-on bias ``b_on`` (a constant, diffuse in the fits) held by
:class:`NoiseModel`. ``Quantization`` and ``RateRamp`` have closed-form Allan
variance / PSD for plot overlays but are not used in fits (quantisation noise
has the second-order statistics of ``WhiteAngle``: fit that instead).

Units (gyro; replace rad by m for accelerometers): ``sigma_w`` rad s^-1/sqrt(Hz),
``sigma_b``, ``sigma_k`` rad s^-2/sqrt(Hz), ``tau_b`` s, ``sigma_a`` rad,
``b_on`` rad/s, Allan variance (rad/s)^2, PSD (rad/s)^2/Hz.

The integrated model (the paper's eq. 11/23) stacks the term states and the
angle ``Omega`` (d Omega/dt = rate). :meth:`NoiseModel.discretize` gives its
transition and process noise over intervals ``dt`` in closed form;
:func:`van_loan` gives the same for any ``(F, G Q G^T)`` by eq. 21 with
balancing, and is what the tests check the closed forms against.

Allan variance: every term has the continuous-time form (IEEE 952 Annex C,
docs/reference/noise-formulas.md §5) and, with ``fs_hz``, the exact form for the sampled
process where the two differ (Gauss-Markov as AR(1), rate random walk).
PSD: **two-sided** ``S(f)`` of the rate, ``avar = 4 int_0^inf S sin^4(pi f tau)/(pi f tau)^2 df``;
pass ``onesided=True`` for ``2 S(f)`` (the convention of ``scipy.signal.welch``).

One idea in ~610 lines, kept together on purpose: each term carries its PSD, Allan
variance, state-space block, closed-form discretisation and exact simulation side by
side, so a new term is written in one place; splitting by operation would spread every
term over several modules.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm, matrix_balance
from scipy.signal import lfilter

from imustation.errors import InputError

# ---------------------------------------------------------------------------
# helpers


def f3(a: np.ndarray) -> np.ndarray:
    """``a - c - c^2/2`` with ``c = 1 - e^{-a}`` (= int_0^a (1 - e^{-u})^2 du), a >= 0.

    The direct form cancels for small ``a``; there the series
    ``sum_{k>=2} (-1)^k (2^k - 2) a^{k+1} / ((k+1) k!)`` is used (terms beyond
    k = 12 are below 1e-16 relative for a < 0.1).
    """
    a = np.asarray(a, dtype=float)
    out = np.empty_like(a)
    small = a < 0.1
    big = ~small
    c = -np.expm1(-a[big])
    out[big] = a[big] - c - 0.5 * c * c
    s = a[small]
    acc = np.full_like(s, F3_COEF[-1])
    for coef in F3_COEF[-2::-1]:
        acc = acc * s + coef
    out[small] = acc * s**3
    return out


#: series coefficients of :func:`f3` (a^3, a^4, ...), shared with the compiled filter
F3_COEF = tuple((-1) ** k * (2**k - 2) / ((k + 1) * math.factorial(k)) for k in range(2, 13))


def expm1_tail(x: np.ndarray) -> np.ndarray:
    """``E(x) = x + expm1(-x) = x^2/2 - x^3/6 + ...`` for x >= 0, series below 0.1 (no cancellation)."""
    x = np.asarray(x, dtype=float)
    small = x < 0.1
    out = np.where(small, 0.0, x + np.expm1(-np.where(small, 0.0, x)))
    s = np.where(small, x, 0.0)
    acc = np.zeros_like(s)
    for k in range(14, 1, -1):  # terms beyond x^14/14! are below 1e-16 relative for x < 0.1
        acc = acc * s + (-1) ** k / math.factorial(k)
    return np.where(small, acc * s * s, out)


def _gm_avar_bracket(a: np.ndarray) -> np.ndarray:
    """``1 - (3 - 4e^-a + e^-2a)/(2a)`` (IEEE 952 Table B.1), series for small ``a``."""
    a = np.asarray(a, dtype=float)
    safe = np.where(a > 1e-3, a, 1.0)
    direct = 1.0 - (3.0 - 4.0 * np.exp(-safe) + np.exp(-2.0 * safe)) / (2.0 * safe)
    series = a**2 / 3.0 - a**3 / 4.0 + 7.0 * a**4 / 60.0
    return np.where(a > 1e-3, direct, series)


def gm_unit_avar(tau_b: np.ndarray, tau: float, fs_hz: float) -> np.ndarray:
    """AVAR at ``tau`` (s) of the sampled Gauss-Markov bias with sigma_b = 1, for an array of tau_b (s).

    The exact sampled-AR(1) form of :meth:`GaussMarkov.avar` (Algorithm 1), vectorised over tau_b.
    """
    tau_b = np.asarray(tau_b, dtype=float)
    dt = 1.0 / fs_hz
    n = tau / dt
    d = dt / tau_b
    phi = np.exp(-d)
    om = -np.expm1(-d)
    g = -np.expm1(-n * d) / om
    n_minus_g = (expm1_tail(n * d) - n * expm1_tail(d)) / om  # n - g without cancellation
    s2 = tau_b / 2.0
    return s2 / n**2 * (n + 2.0 * phi * n_minus_g / om - phi * g * g)


def _dt_of(fs_hz: float | None, what: str) -> float:
    if fs_hz is None:
        raise InputError(f"{what} depends on the sampling interval: pass fs_hz")
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise InputError(f"fs_hz = {fs_hz}: must be a positive sampling rate")
    return 1.0 / float(fs_hz)


def _pos(name: str, v: float, allow_inf: bool = False) -> float:
    v = float(v)
    ok = v > 0 and (math.isfinite(v) or (allow_inf and v == math.inf))
    if not ok:
        raise InputError(f"{name} = {v}: must be positive{' (inf allowed)' if allow_inf else ''}")
    return v


# ---------------------------------------------------------------------------
# terms


class Term:
    """One noise term; subclasses hold their parameters (SI) as dataclass fields."""

    #: short code used in model names ("wn", "gm", "rw", "wa")
    code: str = ""
    #: number of Kalman states the term adds (besides the angle)
    n_states: int = 0
    #: usable in state-space fits
    state_space: bool = True

    def avar(self, tau: np.ndarray, fs_hz: float | None = None) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def psd(self, f: np.ndarray, fs_hz: float | None = None, onesided: bool = False) -> np.ndarray:
        s = self._psd2(np.asarray(f, dtype=float), fs_hz)
        return 2.0 * s if onesided else s

    def _psd2(self, f: np.ndarray, fs_hz: float | None) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def adev(self, tau: np.ndarray, fs_hz: float | None = None) -> np.ndarray:
        return np.sqrt(self.avar(tau, fs_hz))

    def params(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.__dict__.items()}

    def components(self) -> tuple[Term, ...]:
        """The state-space terms this term stands for (itself; a bias instability: its Gauss-Markov sum)."""
        return (self,)

    def angle_variance(self) -> float:
        """Variance this term adds to every angle sample (rad^2): white angle noise; negative for the
        angle deficit of a device low-pass filter (:mod:`.sensor_terms`)."""
        return 0.0


@dataclass(frozen=True)
class WhiteRate(Term):
    """White rate noise ``v``: PSD ``sigma_w^2`` (rad s^-1/sqrt(Hz)); ARW, IEEE-952 N."""

    sigma_w: float
    code = "wn"

    def avar(self, tau, fs_hz=None):
        # eq. 4; the sampled process (variance sigma_w^2/dt per sample, eq. 9) has the same AVAR
        return self.sigma_w**2 / np.asarray(tau, dtype=float)

    def _psd2(self, f, fs_hz):
        return np.full_like(f, self.sigma_w**2)

    def simulate(self, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        return rng.normal(0.0, self.sigma_w / math.sqrt(dt), n)


@dataclass(frozen=True)
class GaussMarkov(Term):
    """First-order Gauss-Markov bias ``db/dt = -b/tau_b + w``, PSD(w) = ``sigma_b^2``.

    Stationary variance ``sigma_b^2 tau_b / 2`` (rad/s)^2; ``sigma_b`` in
    rad s^-2/sqrt(Hz) (the paper's bias diffusion), ``tau_b`` in s.
    """

    sigma_b: float
    tau_b: float
    code = "gm"
    n_states = 1

    def avar(self, tau, fs_hz=None):
        tau = np.asarray(tau, dtype=float)
        q, T = self.sigma_b**2, self.tau_b
        if fs_hz is None:  # continuous (eq. 6 with sigma_b; IEEE 952 Table B.1)
            return q * T * T / tau * _gm_avar_bracket(tau / T)
        # exact for the sampled AR(1) (Algorithm 1): with phi = e^{-d}, d = dt/T,
        # g = sum_{k<n} phi^k, AVAR(n) = s^2/n^2 [n + 2 phi (n - g)/(1 - phi) - phi g^2]
        dt = _dt_of(fs_hz, "discrete GM AVAR")
        n = tau / dt
        d = dt / T
        phi = math.exp(-d)
        om = -math.expm1(-d)  # 1 - phi, accurately
        g = -np.expm1(-n * d) / om
        # n - g = (E(nd) - n E(d)) / om without the cancellation of n - g for n d << 1
        n_minus_g = (expm1_tail(n * d) - n * expm1_tail(np.array(d))) / om
        s2 = q * T / 2.0
        return s2 / n**2 * (n + 2.0 * phi * n_minus_g / om - phi * g * g)

    def _psd2(self, f, fs_hz):
        q, T = self.sigma_b**2, self.tau_b
        if fs_hz is None:  # eq. 5
            return q * T * T / (1.0 + (2.0 * np.pi * f * T) ** 2)
        dt = _dt_of(fs_hz, "discrete GM PSD")
        phi = math.exp(-dt / T)
        var_e = q * T / 2.0 * -math.expm1(-2.0 * dt / T)
        return dt * var_e / (1.0 - 2.0 * phi * np.cos(2.0 * np.pi * f * dt) + phi * phi)

    def simulate(self, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        # exact discretisation (eq. 8) with a stationary start (Algorithm 1)
        T = self.tau_b
        phi = math.exp(-dt / T)
        sd = self.sigma_b * math.sqrt(-T / 2.0 * math.expm1(-2.0 * dt / T))
        b0 = rng.normal(0.0, self.sigma_b * math.sqrt(T / 2.0))
        out, _ = lfilter([1.0], [1.0, -phi], rng.normal(0.0, sd, n), zi=[phi * b0])
        return out


@dataclass(frozen=True)
class RandomWalk(Term):
    """Rate random walk ``db/dt = w``, PSD(w) = ``sigma_k^2`` (rad s^-2/sqrt(Hz)); IEEE-952 K.

    Starts at 0: its initial value is not separable from the turn-on bias.
    """

    sigma_k: float
    code = "rw"
    n_states = 1

    def avar(self, tau, fs_hz=None):
        tau = np.asarray(tau, dtype=float)
        q = self.sigma_k**2
        if fs_hz is None:
            return q * tau / 3.0
        dt = _dt_of(fs_hz, "discrete RW AVAR")
        return q * tau / 3.0 + q * dt * dt / (6.0 * tau)

    def _psd2(self, f, fs_hz):
        q = self.sigma_k**2
        if fs_hz is None:
            return q / (2.0 * np.pi * f) ** 2
        dt = _dt_of(fs_hz, "discrete RW PSD")
        return q * dt * dt / (4.0 * np.sin(np.pi * f * dt) ** 2)

    def simulate(self, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        return np.cumsum(rng.normal(0.0, self.sigma_k * math.sqrt(dt), n))


@dataclass(frozen=True)
class WhiteAngle(Term):
    """White angle noise: iid error of standard deviation ``sigma_a`` (rad) on every angle sample.

    The rate samples see its first difference divided by dt (dominant in dithered
    ring laser gyros, which the standard model cannot capture). Allan variance
    ``3 sigma_a^2/tau^2`` (exact); the PSD needs the sampling rate.
    """

    sigma_a: float
    code = "wa"

    def avar(self, tau, fs_hz=None):
        return 3.0 * self.sigma_a**2 / np.asarray(tau, dtype=float) ** 2

    def _psd2(self, f, fs_hz):
        dt = _dt_of(fs_hz, f"{type(self).__name__} PSD")
        return 4.0 * self.sigma_a**2 / dt * np.sin(np.pi * f * dt) ** 2

    def simulate(self, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        return np.diff(rng.normal(0.0, self.sigma_a, n + 1)) / dt

    def angle_variance(self) -> float:
        return self.sigma_a**2


@dataclass(frozen=True)
class Quantization(WhiteAngle):
    """Angle quantisation noise Q (rad), IEEE-952: AVAR ``3 Q^2/tau^2``; overlays only.

    Same second-order statistics as :class:`WhiteAngle` with ``sigma_a = Q``
    (for a quantiser of step delta, Q = delta/sqrt(12)).
    """

    code = "qn"
    state_space = False

    @property
    def Q(self) -> float:
        return self.sigma_a


@dataclass(frozen=True)
class RateRamp(Term):
    """Deterministic rate ramp R (rad/s^2): AVAR ``R^2 tau^2/2``, PSD ``R^2/(2 pi f)^3``; overlays only."""

    R: float
    code = "rr"
    state_space = False

    def avar(self, tau, fs_hz=None):
        # the sampled ramp has the same AVAR (n^2 delta^2/2 with delta = R dt)
        return 0.5 * self.R**2 * np.asarray(tau, dtype=float) ** 2

    def _psd2(self, f, fs_hz):
        return self.R**2 / (2.0 * np.pi * np.abs(f)) ** 3

    def simulate(self, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        return self.R * dt * np.arange(n)


# ---------------------------------------------------------------------------
# composite model


TERM_ORDER = {"wa": 0, "wn": 1, "gm": 2, "fl": 3, "rw": 4, "lp": 5}
#: what each code of a model name stands for (``analyze --help``, docs/mli.md)
TERM_CODES = {
    "wn": "white rate noise (angle random walk, IEEE-952 N)",
    "wa": "white angle noise / angle quantisation (IEEE-952 Q)",
    "gm": "first-order Gauss-Markov bias (sigma_b, tau_b; '2gm', '3gm' for several)",
    "fl": "bias instability (flicker, IEEE-952 B) as a fixed Gauss-Markov sum",
    "rw": "rate random walk (IEEE-952 K)",
    "lp": "device low-pass filter (its equivalent time constant tau_lp)",
}


def parse_model(name: str) -> tuple[str, ...]:
    """Term codes of a model name such as ``"wn+gm"``, ``"wn+2gm"``, ``"wa+wn+gm+rw"``, ``"wn+fl+rw+lp"``.

    Codes (:data:`TERM_CODES`): ``wn`` white rate (required), ``gm`` Gauss-Markov
    (repeatable, ``2gm``), ``fl`` bias instability, ``rw`` rate random walk, ``wa``
    white angle, ``lp`` device low-pass filter. Returned in canonical order.
    """
    codes: list[str] = []
    for part in name.replace(" ", "").lower().split("+"):
        m = re.fullmatch(r"(\d*)(wn|gm|rw|wa|fl|lp)", part)
        if not m:
            raise InputError(
                f"model {name!r}: unknown term {part!r}; use {', '.join(TERM_CODES)} (2gm, 3gm) joined by '+'"
            )
        codes += [m.group(2)] * int(m.group(1) or 1)
    if codes.count("wn") != 1:
        raise InputError(f"model {name!r}: needs exactly one 'wn' (white rate noise) term")
    for c in ("rw", "wa", "fl", "lp"):
        if codes.count(c) > 1:
            raise InputError(f"model {name!r}: '{c}' may appear once")
    if "wa" in codes and "lp" in codes:
        # both add to the variance of every angle sample: beyond the filter's memory only their sum is seen
        raise InputError(f"model {name!r}: 'wa' and 'lp' cannot be told apart; use one of them")
    if codes.count("gm") > 3:
        raise InputError(f"model {name!r}: at most 3 Gauss-Markov terms")
    return tuple(sorted(codes, key=TERM_ORDER.__getitem__))


def model_name(codes: tuple[str, ...]) -> str:
    k = codes.count("gm")
    parts = [c for c in codes if c != "gm"]
    if k:
        parts.insert(parts.index("wn") + 1, "gm" if k == 1 else f"{k}gm")
    return "+".join(parts)


@dataclass(frozen=True)
class NoiseModel:
    """A sum of independent noise terms plus a turn-on bias ``b_on`` (rad/s).

    ``terms`` may include overlay-only terms (``Quantization``, ``RateRamp``)
    for :meth:`avar` / :meth:`psd`; the state-space methods need state-space terms.
    """

    terms: tuple[Term, ...]
    b_on: float = 0.0
    name: str = field(default="", compare=False)

    # -- statistics ---------------------------------------------------------
    def avar(self, tau: np.ndarray, fs_hz: float | None = None) -> np.ndarray:
        """Allan variance at cluster times ``tau`` (s): continuous, or exact sampled with ``fs_hz``."""
        tau = np.asarray(tau, dtype=float)
        return sum((t.avar(tau, fs_hz) for t in self.terms), np.zeros_like(tau))

    def adev(self, tau: np.ndarray, fs_hz: float | None = None) -> np.ndarray:
        return np.sqrt(self.avar(tau, fs_hz))

    def psd(self, f: np.ndarray, fs_hz: float | None = None, onesided: bool = False) -> np.ndarray:
        """Rate PSD at frequencies ``f`` (Hz), two-sided unless ``onesided`` ((unit)^2/Hz)."""
        f = np.asarray(f, dtype=float)
        return sum((t.psd(f, fs_hz, onesided) for t in self.terms), np.zeros_like(f))

    # -- state space --------------------------------------------------------
    def _ss_terms(self) -> tuple[Term, ...]:
        bad = [type(t).__name__ for t in self.terms if not t.state_space]
        if bad:
            raise InputError(f"{', '.join(bad)}: overlay-only terms have no state-space form")
        return tuple(c for t in self.terms for c in t.components())

    @property
    def n_states(self) -> int:
        """Kalman states of the integrated model: term states + the angle (b_on is diffuse, separate)."""
        return sum(t.n_states for t in self._ss_terms()) + 1

    def state_space(self) -> dict[str, np.ndarray]:
        """Continuous integrated model (eq. 11, 23): ``dx/dt = F x + G w``, ``E[w w^T] = Q delta``.

        State ``x = [term states..., b_on, Omega]`` (b_on constant), driving noise
        ``w = [v (white rate), w_1, ...]``; ``H`` picks the angle ``Omega``;
        ``R`` is the variance of the white angle noise on each angle sample (rad^2).
        """
        terms = self._ss_terms()
        ns = sum(t.n_states for t in terms)
        p = ns + 2
        drivers = [t for t in terms if isinstance(t, (GaussMarkov, RandomWalk))]
        F = np.zeros((p, p))
        G = np.zeros((p, 1 + len(drivers)))
        Q = np.zeros((1 + len(drivers),) * 2)
        G[p - 1, 0] = 1.0  # white rate noise enters the angle
        Q[0, 0] = sum(t.sigma_w**2 for t in terms if isinstance(t, WhiteRate))
        for j, t in enumerate(drivers):
            if isinstance(t, GaussMarkov):
                F[j, j] = -1.0 / t.tau_b
                Q[j + 1, j + 1] = t.sigma_b**2
            else:
                Q[j + 1, j + 1] = t.sigma_k**2
            G[j, j + 1] = 1.0
            F[p - 1, j] = 1.0  # the bias integrates into the angle
        F[p - 1, ns] = 1.0  # so does b_on
        H = np.zeros((1, p))
        H[0, p - 1] = 1.0
        R = np.array([[sum(t.angle_variance() for t in terms)]])
        return {"F": F, "G": G, "Q": Q, "H": H, "R": R}

    def discretize(self, dt: np.ndarray, method: str = "analytic") -> tuple[np.ndarray, np.ndarray]:
        """Transition ``Phi`` and process noise ``Qd`` of ``[term states..., Omega]`` over ``dt`` (s).

        Returns arrays of shape ``dt.shape + (p, p)``. ``analytic``: closed forms
        (eqs. 14, 18); ``vanloan``: eq. 21 with balancing, for checking.
        """
        dt = np.asarray(dt, dtype=float)
        ss = self.state_space()
        keep = [i for i in range(ss["F"].shape[0]) if i != ss["F"].shape[0] - 2]  # drop b_on
        F = ss["F"][np.ix_(keep, keep)]
        GQG = (ss["G"] @ ss["Q"] @ ss["G"].T)[np.ix_(keep, keep)]
        if method == "vanloan":
            out = [van_loan(F, GQG, float(d)) for d in dt.ravel()]
            Phi = np.array([o[0] for o in out]).reshape(dt.shape + F.shape)
            Qd = np.array([o[1] for o in out]).reshape(dt.shape + F.shape)
            return Phi, Qd
        if method != "analytic":
            raise InputError(f"discretisation {method!r}: use 'analytic' or 'vanloan'")
        return discretize_blocks([TermBlock.of(t) for t in self._ss_terms()], dt)

    # -- simulation (Algorithm 1, generalised) -------------------------------
    def simulate(self, n: int, fs_hz: float, seed: int | np.random.Generator | None = None) -> np.ndarray:
        """``n`` rate samples at ``fs_hz`` (Hz): sum of the terms' exact discrete simulations + b_on."""
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        dt = _dt_of(fs_hz, "simulation")
        out = np.full(n, float(self.b_on))
        shaping = [t for t in self.terms if hasattr(t, "filter_white")]
        for t in self.terms:
            x = t.simulate(n, dt, rng)
            if isinstance(t, WhiteRate):
                for f in shaping:  # a device filter acts on the white noise (sensor_terms.LowPass)
                    x = f.filter_white(x, dt)
            out += x
        return out

    def params(self) -> dict[str, float]:
        """Flat parameter dict; Gauss-Markov terms beyond the first are suffixed 2, 3."""
        out: dict[str, float] = {}
        k = 0
        for t in sorted(self.terms, key=lambda t: getattr(t, "tau_b", 0.0)):
            p = t.params()
            if isinstance(t, GaussMarkov):
                k += 1
                if self.n_gm > 1:
                    p = {f"{key}{k}": v for key, v in p.items()}
            out.update(p)
        out["b_on"] = float(self.b_on)
        return out

    @property
    def n_gm(self) -> int:
        return sum(isinstance(t, GaussMarkov) for t in self.terms)


def van_loan(F: np.ndarray, GQG: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``Phi = exp(F dt)`` and ``Qd = int_0^dt Phi(s) GQG Phi(s)^T ds`` by eq. 21 (Van Loan 1978).

    The block matrix is balanced (diagonal similarity, scipy ``matrix_balance``)
    before exponentiation, and long intervals are split: eq. 21 is applied over
    ``h = dt/2^k`` with ``||F|| h <= 1/2`` and the result doubled k times
    (``Phi(2h) = Phi(h)^2``, ``Qd(2h) = Phi(h) Qd(h) Phi(h)^T + Qd(h)``). Without the
    split, ``exp(-F dt)`` overflows the block for ``dt >> tau`` and Qd is lost to
    cancellation.
    """
    p = F.shape[0]
    norm = float(np.abs(F).sum(axis=1).max()) * dt
    k = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    h = dt / 2**k
    M = np.zeros((2 * p, 2 * p))
    M[:p, :p] = -F
    M[:p, p:] = GQG
    M[p:, p:] = F.T
    Mb, (scale, _perm) = matrix_balance(M * h, permute=False, separate=True)
    E = expm(Mb) * (scale[:, None] / scale[None, :])  # D exp(D^-1 M D) D^-1
    Phi = E[p:, p:].T
    Qd = Phi @ E[:p, p:]
    for _ in range(k):
        Qd = Phi @ Qd @ Phi.T + Qd
        Phi = Phi @ Phi
    return Phi, 0.5 * (Qd + Qd.T)


# ---------------------------------------------------------------------------
# closed-form discretisation, batched over parameter points


@dataclass(frozen=True)
class TermBlock:
    """A term's variance ``q`` and correlation time (``inf`` for RW, 0 for no state)."""

    code: str
    q: float | np.ndarray
    tau: float | np.ndarray = math.inf

    @staticmethod
    def of(t: Term) -> TermBlock:
        if isinstance(t, WhiteRate):
            return TermBlock("wn", t.sigma_w**2)
        if isinstance(t, GaussMarkov):
            return TermBlock("gm", t.sigma_b**2, t.tau_b)
        if isinstance(t, RandomWalk):
            return TermBlock("rw", t.sigma_k**2)
        if isinstance(t, WhiteAngle) or (t.n_states == 0 and t.state_space and t.angle_variance()):
            return TermBlock("wa", t.angle_variance())  # no state: angle noise only (sensor_terms.LowPass)
        raise InputError(f"{type(t).__name__}: no state-space form")


def discretize_blocks(blocks: list[TermBlock], dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form ``Phi``, ``Qd`` of ``[term states..., Omega]``; ``dt`` and the
    blocks' ``q``/``tau`` broadcast together (e.g. dt (M, 1), q (K,)) -> shape ``(..., p, p)``.

    Gauss-Markov (a = dt/tau, c = 1 - e^-a): Phi_bb = e^-a, Phi_Ob = tau c,
    Q_bb = q tau/2 (1 - e^-2a), Q_bO = q tau^2 c^2/2, Q_OO += q tau^3 f3(a);
    random walk: Phi_bb = 1, Phi_Ob = dt, Q_bb = q dt, Q_bO = q dt^2/2, Q_OO += q dt^3/3;
    white rate: Q_OO += q dt.
    """
    dt = np.asarray(dt, dtype=float)
    shape = np.broadcast_shapes(dt.shape, *(np.shape(b.q) for b in blocks), *(np.shape(b.tau) for b in blocks))
    ns = sum(b.code in ("gm", "rw") for b in blocks)
    p = ns + 1
    Phi = np.zeros(shape + (p, p))
    Qd = np.zeros(shape + (p, p))
    Phi[..., ns, ns] = 1.0
    dtb = np.broadcast_to(dt, shape)
    j = 0
    for b in blocks:
        q = np.broadcast_to(np.asarray(b.q, dtype=float), shape)
        if b.code == "wn":
            Qd[..., ns, ns] += q * dtb
        elif b.code == "gm":
            T = np.broadcast_to(np.asarray(b.tau, dtype=float), shape)
            a = dtb / T
            c = -np.expm1(-a)
            Phi[..., j, j] = np.exp(-a)
            Phi[..., ns, j] = T * c
            Qd[..., j, j] = q * T * 0.5 * -np.expm1(-2.0 * a)
            Qd[..., j, ns] = Qd[..., ns, j] = q * T * T * 0.5 * c * c
            Qd[..., ns, ns] += q * T**3 * f3(a)
            j += 1
        elif b.code == "rw":
            Phi[..., j, j] = 1.0
            Phi[..., ns, j] = dtb
            Qd[..., j, j] = q * dtb
            Qd[..., j, ns] = Qd[..., ns, j] = q * dtb**2 / 2.0
            Qd[..., ns, ns] += q * dtb**3 / 3.0
            j += 1
    return Phi, Qd


def standard(sigma_w: float, sigma_b: float, tau_b: float, b_on: float = 0.0) -> NoiseModel:
    """The paper's standard model (eq. 22): white rate + Gauss-Markov (RW for tau_b = inf) + b_on."""
    _pos("sigma_w", sigma_w)
    _pos("tau_b", tau_b, allow_inf=True)
    bias = RandomWalk(sigma_b) if math.isinf(tau_b) else GaussMarkov(sigma_b, tau_b)
    return NoiseModel((WhiteRate(sigma_w), bias), b_on, name="wn+gm" if math.isfinite(tau_b) else "wn+rw")
