"""What a device records, as its driver describes it: channels and driver info.

Plain dataclasses with no file-format dependency (no h5py): drivers produce
them, the station passes them on, and the run-file writer
(:mod:`imustation.runfile`) stores them. Chip drivers import this module,
never the run-file format.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ChannelSpec:
    """One recorded quantity of a device: ``gyro``, ``accel`` or ``temp``.

    ``value [units] = raw * scale + offset``; ``axes`` is ``("x", "y", "z")``
    for vector channels and ``()`` for scalars.
    """

    name: str
    dtype: str
    units: str
    scale: float
    offset: float = 0.0
    axes: tuple[str, ...] = ()


@dataclass(frozen=True)
class DriverInfo:
    """Static description a driver gives before streaming starts."""

    model: str
    identity: str
    rate_hz: float
    settings: Mapping[str, Any]
    channels: tuple[ChannelSpec, ...]
    has_counter: bool = False
    #: how often the station should poll, s (FIFO depth / rate with margin)
    poll_interval_s: float = 0.1
    #: how the device loses samples the station does not read in time, so the station knows where
    #: to count them (docs/capture.md, "Samples lost"): one of :data:`OVERFLOW_KINDS`
    overflow: str = "reported"
    #: how long the device and its transport hold samples between two reads without losing any, s
    #: (``overflow`` "newest" or "oldest"; one output period for a chip without a FIFO)
    buffer_s: float = float("inf")

    def __post_init__(self) -> None:
        if self.overflow not in OVERFLOW_KINDS:
            raise ValueError(f"overflow = {self.overflow!r}: one of {', '.join(OVERFLOW_KINDS)}")


#: ``DriverInfo.overflow``: where the station finds the samples a device lost
OVERFLOW_KINDS = {
    "reported": "the device says so (a FIFO overrun flag, a sample counter) with the block after the loss",
    "newest": "a read returns the newest sample only (no FIFO): samples made while the station did not read "
    "for longer than buffer_s are lost without a word; counted from the read times, before the next sample",
    "oldest": "a buffer keeps the oldest samples and drops what arrives when it is full (a tty without flow "
    "control): counted from the read times when the station did not read for longer than buffer_s, after "
    "the samples that read returns",
}
