"""What a run file's stored device settings say about the device's output filter.

The model family carries a device low-pass filter as one number estimated from the
data (:mod:`imustation.analysis.estimators.models.sensor_terms`); the settings only say
*whether* a filter is configured and roughly how long its output samples stay
correlated, so the fine-scale test starts beyond that memory
(:class:`~imustation.analysis.estimators.ml.finescale.FilterHint`). The memory is
taken as ``0.5 / bandwidth`` for the chips whose datasheets give a -3 dB
bandwidth (a second-order low-pass's autocorrelation has decayed to a few per cent
there; the data test then moves on until the noise is white up to the filter's
deficit), and as the FIR length for the ADIS16448's Bartlett filter. Devices that
output the mean over each output interval (Xsens MTi, KVH DSP-3000; the ADIS16448
without its FIR) give white samples: no filter. Unknown drivers give no hint and
the data decide alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from imustation.analysis.estimators.ml.finescale import TAU_LP_MARGIN, FilterHint

#: drivers whose settings carry the -3 dB bandwidth of the chip's digital low-pass (Hz)
BANDWIDTH_DRIVERS = ("bmx055", "bmx055_accel", "mpu9150", "mpu6500")
#: drivers that output the mean over each output interval: white samples
INTERVAL_MEAN_DRIVERS = ("mti", "dsp3000")


def filter_hint(meta: Mapping[str, Any], fs_hz: float) -> FilterHint | None:
    """The :class:`FilterHint` of a run-file channel's device (``meta`` of a loaded channel:
    ``driver`` and ``settings``), or ``None`` when its driver is not known here."""
    driver = str(meta.get("driver", ""))
    settings = meta.get("settings") or {}
    if driver in BANDWIDTH_DRIVERS:
        bw = settings.get("bandwidth_hz")
        if bw is None or not (float(bw) > 0):
            return None
        bw = float(bw)
        tau_lp_max = TAU_LP_MARGIN / (2.0 * math.pi * bw)  # no filter of that bandwidth has a larger deficit
        return FilterHint(True, 0.5 / bw, f"{driver} bandwidth_hz = {bw:g}", tau_lp_max=tau_lp_max)
    if driver == "adis16448":
        taps = int(settings.get("filter_taps", 1) or 1)
        dec = int(settings.get("decimation", 0) or 0)
        if taps <= 1:
            return FilterHint(False, 0.0, f"adis16448 filter_taps = {taps}: mean over each output interval")
        # the FIR runs at the internal rate, 2**dec times the output rate (SMPL_PRD,
        # docs/reference/sensors.md §4.3): taken from the channel's own rate, not a constant
        memory = (2 * (taps - 1) + 2**dec) / (fs_hz * 2**dec)
        return FilterHint(True, memory, f"adis16448 filter_taps = {taps}, decimation = {dec}")
    if driver in INTERVAL_MEAN_DRIVERS:
        return FilterHint(False, 0.0, f"{driver}: mean over each output interval")
    return None
