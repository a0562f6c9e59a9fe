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
