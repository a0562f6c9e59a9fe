"""Samples no inertial sensor produces: NaN, infinities, and rates far beyond any sensor's range.

Integer counts are bounded by the chip's range (int16 counts x scale), so only
float samples - imported logs and bags, plain arrays - need this: one flipped
bit in a float's exponent makes a gyro read 4e19 rad/s, and an analysis of it
reports sigma_w of 1e16 as if it were a result. Such samples are refused with
their count and the first one, never analysed.

The limits lie far above the largest range of any supported sensor (ADIS16448
+-1000 deg/s, MTi +-2000 deg/s = 35 rad/s; accelerometers +-18 g = 177 m/s^2;
docs/drivers.md, docs/drivers-serial-spi.md), so no real signal reaches them.
"""

from __future__ import annotations

import numpy as np

from imustation.errors import InputError

#: largest magnitude a sample may have, per SI unit (57,000 deg/s; about 1,000 g)
LIMITS = {"rad/s": 1e3, "m/s^2": 1e4}


def impossible(values: np.ndarray, units: str) -> np.ndarray:
    """Boolean mask over the rows of ``values`` ((n,) or (n, k), in ``units``): rows holding
    a NaN, an infinity or a magnitude beyond ``LIMITS[units]`` (no limit for other units)."""
    v = np.asarray(values, dtype=np.float64)
    bad = ~np.isfinite(v)
    limit = LIMITS.get(units)
    if limit is not None:
        with np.errstate(invalid="ignore"):
            bad |= np.abs(v) > limit
    return bad.reshape(len(v), -1).any(axis=1)


def refuse_impossible(where: str, values: np.ndarray, units: str, first_row: int = 0) -> None:
    """Raise :class:`InputError` naming ``where`` when a row of ``values`` is impossible (see :func:`impossible`).

    ``first_row``: index of ``values[0]`` in the whole record, for the message.
    """
    bad = impossible(values, units)
    if not bad.any():
        return
    i = int(np.argmax(bad))
    row = np.asarray(values[i], dtype=np.float64).ravel()
    limit = LIMITS.get(units)
    beyond = f" or beyond +-{limit:g} {units}" if limit is not None else ""
    raise InputError(
        f"{where}: {int(bad.sum())} samples are NaN/infinite{beyond}, which no sensor produces "
        f"(first: sample {first_row + i}, {', '.join(f'{x:.6g}' for x in row)}); refused, not analysed"
    )
