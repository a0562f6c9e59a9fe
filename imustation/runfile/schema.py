"""Names of the run-file layout (format v1) and the description of a recorded device.

What the writer creates and the reader looks for: the root attributes'
format tag, the group and dataset names, the event table's record type.
``docs/runfile.md`` describes the layout in full.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from imustation.channels import ChannelSpec

FORMAT = "imustation-run"
FORMAT_VERSION = 1

DEVICES = "devices"
THERMOMETERS = "thermometers"
EVENTS = "events"
TIME = "t"  # int64 ns since started_utc, host monotonic clock
COUNTER = "counter"  # int64 device sample counter, where the device has one
CELSIUS = "celsius"

#: the ``driver`` of an imported device (its stamps are the source's, kept in file order)
IMPORT_DRIVER = "import"
#: kinds of event a run file may hold (docs/runfile.md)
EVENT_KINDS = ("gap", "resync", "reconnect", "overrun", "checksum", "config", "note", "fault")
#: event kinds that count as gaps of a device's record, their ``lost`` as samples lost
LOSS_KINDS = ("gap", "overrun")
EVENT_DTYPE = np.dtype(
    [
        ("t", "<i8"),  # ns since started_utc
        ("source", "S64"),  # device or thermometer name, or "station"
        ("kind", "S16"),  # one of EVENT_KINDS
        ("lost", "<i8"),  # samples lost (gaps, overruns); 0 when not applicable
        ("detail", "S256"),  # free text, truncated to 256 bytes
    ]
)


@dataclass(frozen=True)
class DeviceSpec:
    """What the recorder knows about a device before the first sample."""

    name: str
    driver: str
    model: str
    bus: str
    identity: str
    rate_hz: float
    settings: Mapping[str, Any]
    channels: tuple[ChannelSpec, ...]
    has_counter: bool = False


def utc_now_iso() -> str:
    """The current UTC time as the run file's ``*_utc`` attributes hold it (ISO 8601, ms)."""
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


@dataclass(frozen=True)
class Event:
    """One row of the event table (``lost``: samples lost, 0 where not applicable)."""

    t_ns: int
    source: str
    kind: str
    lost: int
    detail: str
