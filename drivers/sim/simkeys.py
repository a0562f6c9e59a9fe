"""The ``[device.sim]`` keys of a simulated device and what their values may be.

The config loader (``acquisition/config.py``) checks every key and value here before
anything is opened, so a bad one is one line naming the file and the key; the noise
sources read them (:mod:`.sources`).
"""

from __future__ import annotations

import math
from typing import Any

from imustation.drivers.sim.profiles import PROFILES
from imustation.drivers.sim.quirks import quirks_problem

#: keys that shape a gyroscope source / an accelerometer source
GYRO_SIM_KEYS = (
    "sigma_w",
    "sigma_b",
    "tau_b",
    "b_on_dps",
    "turn_on_bias_std_dps",
    "replay",
    "bias_instability",
    "rate_random_walk",
    "bias_tempco",
)
ACCEL_SIM_KEYS = (
    "accel_sigma_w",
    "accel_sigma_b",
    "accel_tau_b",
    "accel_b_on_mg",
    "accel_turn_on_bias_std_mg",
    "gravity_g",
    "accel_replay",
    "accel_bias_instability",
    "accel_rate_random_walk",
    "accel_bias_tempco",
)
#: keys a [device.sim] table may hold
SIM_KEYS = (
    "seed",
    "profile",
    "filter",
    *GYRO_SIM_KEYS[:5],
    "temp_c",
    "temp_drift_c",
    "temp_period_s",
    "warmup_c",
    "warmup_tau_s",
    "faults",
    # field quirks the chip simulator shows (drivers/sim/quirks.py)
    "quirks",
    *GYRO_SIM_KEYS[6:],
    # accelerometers (defaults: analysis.estimators.models.reference.ACCEL_DEFAULTS, not the paper)
    *(k for k in ACCEL_SIM_KEYS if k != "accel_replay"),
    # a recorded signal instead of the noise model (see ReplaySource)
    "replay",
    "replay_rate_hz",
    "accel_replay",
)

_ANY, _POSITIVE, _NON_NEGATIVE = "a number", "a number > 0", "a number >= 0"
_TIME = "a number > 0 (inf: no decay)"
#: key -> what a value (or each of a list's values, one per axis, where ``per_axis``) must be
_VALUES: dict[str, tuple[str, bool]] = {
    "sigma_w": (_POSITIVE, True),
    "sigma_b": (_NON_NEGATIVE, True),
    "tau_b": (_TIME, True),
    "b_on_dps": (_ANY, True),
    "turn_on_bias_std_dps": (_NON_NEGATIVE, False),
    "bias_instability": (_NON_NEGATIVE, True),
    "rate_random_walk": (_NON_NEGATIVE, True),
    "bias_tempco": (_ANY, True),
    "temp_c": (_ANY, False),
    "temp_drift_c": (_ANY, False),
    "temp_period_s": (_POSITIVE, False),
    "warmup_c": (_ANY, False),
    "warmup_tau_s": (_POSITIVE, False),
    "replay_rate_hz": (_POSITIVE, False),
}
_VALUES.update({"accel_" + k: v for k, v in _VALUES.items() if k in GYRO_SIM_KEYS})
_VALUES["accel_b_on_mg"] = _VALUES.pop("accel_b_on_dps")
_VALUES["accel_turn_on_bias_std_mg"] = _VALUES.pop("accel_turn_on_bias_std_dps")


def _number_problem(value: Any, kind: str) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return True
    if kind == _TIME:
        return not value > 0  # tau_b = inf: a random-walk bias
    if not math.isfinite(value):
        return True
    return (kind == _POSITIVE and value <= 0) or (kind == _NON_NEGATIVE and value < 0)


def sim_value_problem(key: str, value: Any, n_axes: int) -> str | None:
    """What is wrong with ``[device.sim] key = value`` on a device of ``n_axes`` axes (``None``: nothing).

    The config loader reports it as one line with the file and the key; keys it does not
    know here (``faults``, ``replay``, ``gravity_g``) are checked where they are used.
    """
    if key == "seed":
        return None if isinstance(value, int) and not isinstance(value, bool) else "an integer"
    if key == "profile":
        return None if value in PROFILES else f"one of {', '.join(repr(p) for p in PROFILES)}"
    if key == "filter":
        return None if isinstance(value, bool) else "true or false"
    if key == "quirks":
        return quirks_problem(value)
    if key not in _VALUES:
        return None
    kind, per_axis = _VALUES[key]
    if isinstance(value, (list, tuple)) and per_axis:
        if len(value) != n_axes or any(_number_problem(v, kind) for v in value):
            return f"{kind}, or a list of {n_axes} (one per axis)"
        return None
    if _number_problem(value, kind):
        return f"{kind}, or a list of {n_axes} (one per axis)" if per_axis else kind
    return None
