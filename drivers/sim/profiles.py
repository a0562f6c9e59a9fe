"""Noise profiles of the simulated devices: ``paper`` (Table IV) and ``datasheet``.

``[device.sim] profile = "paper"`` (the default) keeps the paper's standard model: Table
IV's white noise and Gauss-Markov bias, no output filter, no further terms - the streams
the paper's experiments and the project's tests were made with. ``profile =
"datasheet"`` gives each device the typical values of its datasheet: angle random walk,
bias instability, temperature coefficient, and its output filter on; what a datasheet
does not give (rate random walk, warm-up, most bias instabilities) is chosen by a stated
rule, and every value says where it comes from (docs/simulation.md lists them). Any key
set in ``[device.sim]`` overrides its profile value.

Datasheet numbers read as IEEE-952 coefficients: a noise density is N; an "in-run bias
stability" is the Allan deviation floor, so B = floor / 0.664; a "zero-rate output change
over temperature" range spread over its temperature span is a tempco magnitude, its sign
drawn per axis from the device's seed (a datasheet gives a spread over parts, not a sign).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from imustation.analysis.estimators.models.reference import ACCEL_DEFAULTS, TABLE_IV
from imustation.drivers.sim.noise_terms import FLICKER_FLOOR
from imustation.units import DEG2RAD, G0

PROFILES = ("paper", "datasheet")

_DPH = DEG2RAD / 3600.0  # rad/s per deg/h
_MG = 1e-3 * G0  # m/s^2 per mg
_UG = 1e-6 * G0
#: Allan deviation maximum of a Gauss-Markov term over its stationary standard deviation
_GM_PEAK = 0.6174


@dataclass(frozen=True)
class Term:
    """A profile value (SI; one number, or one per axis) and its source."""

    value: float | tuple[float, ...]
    source: str


def _b_from_gm(models) -> tuple[float, ...]:
    """B whose floor 0.664 B equals each axis's Gauss-Markov Allan maximum (0.6174 x its stationary std)."""
    return tuple(_GM_PEAK * m.sigma_b * math.sqrt(m.tau_b / 2.0) / FLICKER_FLOOR for m in models)


def _k_rule(b: tuple[float, ...], tau_x: float) -> tuple[float, ...]:
    """K such that K sqrt(tau / 3) meets the floor 0.664 B at ``tau_x`` s."""
    return tuple(FLICKER_FLOOR * x * math.sqrt(3.0 / tau_x) for x in b)


def _gyro(key: str, n: float, n_src: str, b: tuple[float, ...] | None, b_src: str, tempco: float, t_src: str,
          tau_x: float, warmup: tuple[float, float]) -> dict[str, Term]:  # fmt: skip
    axes = [TABLE_IV[key][a] for a in sorted(TABLE_IV[key])]
    if b is None:
        b = _b_from_gm(axes)
        b_src = "not in the datasheet: the Allan maximum of the paper's Table IV Gauss-Markov term, read as the floor"
    return {
        "sigma_w": Term(n, n_src),
        "sigma_b": Term(0.0, "no Gauss-Markov term (the datasheet profile models the floor as bias instability)"),
        "tau_b": Term(math.inf, "no Gauss-Markov term"),
        "bias_instability": Term(b, b_src),
        "rate_random_walk": Term(_k_rule(b, tau_x), f"not in the datasheet: chosen to meet the floor at {tau_x:g} s"),
        "bias_tempco": Term(tempco, t_src),
        "warmup_c": Term(warmup[0], "not in the datasheet: chosen"),
        "warmup_tau_s": Term(warmup[1], "not in the datasheet: chosen"),
    }


def _accel(key: str, n: float, n_src: str, tempco: float | tuple[float, ...], t_src: str) -> dict[str, Term]:
    models = [ACCEL_DEFAULTS[key][a] for a in "xyz"]
    b = _b_from_gm(models)
    return {
        "accel_sigma_w": Term(n, n_src),
        "accel_sigma_b": Term(0.0, "no Gauss-Markov term"),
        "accel_tau_b": Term(math.inf, "no Gauss-Markov term"),
        "accel_bias_instability": Term(
            b, "not in the datasheet: the Allan maximum of the simulator's default accelerometer Gauss-Markov term"
        ),
        "accel_rate_random_walk": Term(_k_rule(b, 1000.0), "not in the datasheet: chosen to meet the floor at 1000 s"),
        "accel_bias_tempco": Term(tempco, t_src),
    }


_MEMS_WARMUP = (1.5, 300.0)
_BMX = "Bosch BMX055 datasheet (BST-BMX055-DS000)"
_MPU9150 = "InvenSense PS-MPU-9150A-00 (MPU-6050 die: PS-MPU-6000A-00 rev 3.4 §6.1/§6.2 give the same)"
_MPU6500 = "InvenSense PS-MPU-6500A-01 §3.1/§3.2 (UNCONFIRMED: not re-checked against the document here)"

#: Table IV key -> sim key -> the datasheet profile's value (SI) and its source
DATASHEET: dict[str, dict[str, Term]] = {
    "bmx055": {
        **_gyro("bmx055", 0.014 * DEG2RAD, f"{_BMX}, gyroscope rate noise density 0.014 deg/s/sqrt(Hz) typ.",
                None, "", 0.015 * DEG2RAD, f"{_BMX}, gyroscope zero-rate offset drift TCO +-0.015 deg/s/K typ.",
                1000.0, _MEMS_WARMUP),
        **_accel("bmx055", 150 * _UG, f"{_BMX}, accelerometer output noise density 150 ug/sqrt(Hz) typ.",
                 1.0 * _MG, f"{_BMX}, accelerometer zero-g offset drift TCO +-1 mg/K typ."),
    },
    "mpu9150": {
        **_gyro("mpu9150", 0.005 * DEG2RAD, f"{_MPU9150}: rate noise spectral density 0.005 deg/s/sqrt(Hz)",
                None, "", 20.0 / 125.0 * DEG2RAD,
                f"{_MPU9150}: ZRO variation over temperature +-20 deg/s over -40..+85 degC (0.16 deg/s/K)",
                1000.0, _MEMS_WARMUP),
        **_accel("mpu9150", 400 * _UG, f"{_MPU9150}: accel noise power spectral density 400 ug/sqrt(Hz)",
                 (35.0 / 70 * _MG, 35.0 / 70 * _MG, 60.0 / 70 * _MG),
                 f"{_MPU9150}: zero-G level change +-35 mg (x, y), +-60 mg (z) over 0..70 degC"),
    },
    "mpu6500": {
        **_gyro("mpu6500", 0.01 * DEG2RAD, f"{_MPU6500}: rate noise spectral density 0.01 deg/s/sqrt(Hz)",
                None, "", 0.24 * DEG2RAD, f"{_MPU6500}: ZRO variation over temperature +-0.24 deg/s/K",
                1000.0, _MEMS_WARMUP),
        **_accel("mpu6500", 300 * _UG, f"{_MPU6500}: accel noise power spectral density 300 ug/sqrt(Hz)",
                 0.64 * _MG, f"{_MPU6500}: zero-G level change vs temperature +-0.64 mg/K"),
    },
    "adis16448": _gyro(
        "adis16448", 0.66 / 60.0 * DEG2RAD, "ADIS16448 datasheet Rev. D Table 1: angle random walk 0.66 deg/sqrt(h)",
        (14.5 / FLICKER_FLOOR * _DPH,) * 3, "ADIS16448 Rev. D Table 1: in-run bias stability 14.5 deg/h (the floor)",
        0.005 * DEG2RAD, "ADIS16448 Rev. D Table 1: bias temperature coefficient +-0.005 deg/s/K (UNCONFIRMED)",
        2000.0, (2.0, 600.0),
    ),
    "mti": _gyro(
        "mti", 0.01 * DEG2RAD, "Xsens MTi 100-series datasheet: gyroscope noise density 0.01 deg/s/sqrt(Hz)",
        (10.0 / FLICKER_FLOOR * _DPH,) * 3, "Xsens MTi 100-series datasheet: in-run bias stability 10 deg/h",
        0.001 * DEG2RAD, "not in the datasheet (calibrated over temperature): residual chosen 0.001 deg/s/K",
        2000.0, (3.0, 600.0),
    ),
    "dsp3000": _gyro(
        "dsp3000", 0.0667 / 60.0 * DEG2RAD, "KVH DSP-3000 datasheet: angle random walk 0.0667 deg/sqrt(h)",
        (1.0 / FLICKER_FLOOR * _DPH,), "KVH DSP-3000 datasheet: bias stability 1 deg/h, 1 sigma (the floor)",
        0.05 * _DPH, "not in the datasheet: chosen 0.05 deg/h/K",
        10000.0, (2.0, 1200.0),
    ),
}  # fmt: skip


def defaults(table_key: str, profile: str) -> dict[str, float | tuple[float, ...]]:
    """Sim-key defaults of ``profile`` for a device's Table IV key (empty for ``paper``)."""
    if profile == "paper":
        return {}
    return {key: term.value for key, term in DATASHEET.get(table_key, {}).items()}
