"""One warm-up decision per device, shared by every command (``--warmup auto|0|DURATION``).

``analyze``, ``report``, ``export``, ``fleet`` and ``demo`` cut the same start of a device's
record for the same option, so they give the same numbers for the same channel:

* ``auto`` (the default everywhere): the device's own temperature decides
  (:func:`~imustation.analysis.estimators.classical.temperature.fit_warmup`: a real temperature
  change of many reading steps and a fitted transient); a warm-up that settles inside the
  record is cut up to its end; nothing is cut for no warm-up, for a record still warming up
  at its end (nothing settled would be left) or too short to tell, nor for a device without
  a temperature channel;
* ``0`` / ``none``: nothing is cut;
* a duration (``20m``, ``1h``): that much is cut from every device.

:func:`warmup_cut` gives the decision (:class:`WarmupCut`, which says what was cut and why),
:func:`apply_warmup` cuts a loaded channel's segments and records the cut in its ``meta``
(``warmup``), where the verdict and the reports read it.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass

from imustation.analysis.pipeline.choices import DEFAULT_WARMUP, WARMUP_HELP
from imustation.errors import InputError
from imustation.units import format_duration, parse_duration

__all__ = ["DEFAULT_WARMUP", "WARMUP_HELP", "NO_WARMUP", "WarmupCut", "apply_warmup", "check_warmup", "cut_channels",
           "warmup_cut", "auto_warmup"]  # fmt: skip

#: option values that cut nothing
NO_WARMUP = ("0", "none")
#: the channel ``meta`` key :func:`apply_warmup` records its cut under
META_KEY = "warmup"


def check_warmup(option: str) -> float | None:
    """Seconds to cut from the start of every device, or None for ``"auto"`` (each device's own
    temperature decides); ``"0"``/``"none"`` cut nothing. Raises :class:`InputError` otherwise."""
    if option == "auto":
        return None
    if option in NO_WARMUP:
        return 0.0
    try:
        return parse_duration(option, "--warmup")
    except InputError as exc:
        raise InputError(f"{exc} (or auto, or 0 for nothing)") from None


@dataclass(frozen=True)
class WarmupCut:
    """What ``--warmup`` cuts from one device: ``cut_s`` seconds from the start of its record;
    ``option`` the option's value, ``state`` what ``auto`` found (the warm-up fit's state,
    :data:`~imustation.analysis.estimators.classical.temperature.WARMUP_STATES`; "" without a
    temperature channel), ``found`` the warm-up fit in words and ``end_s`` the warm-up's end it found
    (NaN when none)."""

    device: str
    option: str
    cut_s: float
    state: str = ""
    found: str = ""
    end_s: float = math.nan

    def describe(self) -> str:
        """One phrase: ``"bmx055: 45m49s cut (auto: warm-up 3.9 K until 2749 s)"``."""
        cut = f"{format_duration(self.cut_s)} cut" if self.cut_s > 0 else "nothing cut"
        why = f"{self.option}: {self.found}" if self.found else self.option
        return f"{self.device}: {cut} ({why})"

    def as_dict(self) -> dict:
        """The ``warmup`` block of a channel in the analysis JSON (docs/analysis-json.md)."""
        return {
            "option": self.option,
            "cut_s": float(self.cut_s),
            "state": self.state or None,
            "found": self.found or None,
            "end_s": float(self.end_s) if math.isfinite(self.end_s) else None,
        }


def warmup_cut(path: str, device: str, option: str = DEFAULT_WARMUP) -> WarmupCut:
    """The cut of ``device`` in run file ``path`` for ``--warmup option`` (module docstring)."""
    fixed = check_warmup(option)
    try:
        mtime = os.stat(path).st_mtime_ns
    except OSError:
        mtime = 0
    state, found, end = auto_warmup(path, device, mtime)
    if fixed is not None:
        return WarmupCut(device, option, fixed, state, found, end)
    cut = end if state == "transient" else 0.0
    return WarmupCut(device, option, cut, state, found, end)


@functools.lru_cache(maxsize=32)
def auto_warmup(path: str, device: str, mtime_ns: int) -> tuple[str, str, float]:
    """(state, description, end s) of the warm-up fit of a device's temperature (``mtime_ns``: the
    file's version, the cache key); ("", "no temperature channel", NaN) without one. Cached: every
    channel of a device asks."""
    from imustation.analysis.estimators.classical.temperature import fit_warmup
    from imustation.analysis.pipeline.loaders import device_temperature_record

    try:
        rec = device_temperature_record(path, device)
    except InputError:
        return "", "no temperature channel", math.nan
    fit = fit_warmup(rec.t_s, rec.temp_c, step_c=rec.step_c)
    end = fit.end_s if fit.state == "transient" else math.nan
    return fit.state, fit.describe(), end


def apply_warmup(ch, cut: WarmupCut) -> None:
    """Drop the first ``cut.cut_s`` seconds of a loaded channel's segments (in place) and record
    ``cut`` in ``ch.meta[META_KEY]``. Raises :class:`InputError` when nothing would be left."""
    n0 = int(round(cut.cut_s * ch.fs_hz))
    if n0 > 0:
        segs = [(max(a, n0), b) for a, b in ch.segments if b > n0]
        if not segs:
            raise InputError(
                f"{ch.id}: the warm-up cut ({format_duration(cut.cut_s)}, --warmup {cut.option}) leaves no data"
            )
        ch.segments = segs
    ch.meta[META_KEY] = cut


def cut_channels(channels, option: str = DEFAULT_WARMUP) -> dict[str, WarmupCut]:
    """:func:`apply_warmup` to every channel of ``channels`` with a device (run files, field recordings);
    returns the cut per device, in first-appearance order. Channels without a device (plain arrays)
    are left alone."""
    fixed = check_warmup(option)  # a bad value fails before any file is read
    cuts: dict[str, WarmupCut] = {}
    for ch in channels:
        device = ch.meta.get("device")
        if not device:
            continue
        if device not in cuts:
            if ch.ref is not None:
                cuts[device] = warmup_cut(ch.source, device, option)
            else:  # a streamed field recording: no device temperature to read, as in its imported run file
                cuts[device] = WarmupCut(device, option, fixed or 0.0, "", "no temperature channel")
        apply_warmup(ch, cuts[device])
    return cuts
