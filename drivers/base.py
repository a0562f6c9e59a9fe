"""What every device driver offers the station, whatever its chip or bus."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from imustation.channels import DriverInfo


@dataclass
class Block:
    """Samples that became available since the previous read.

    ``channels`` maps channel name to raw counts, shape ``(k, ...)``;
    ``lost`` is the number of samples the device dropped before this block
    (a count the chip gives), -1 when it knows samples were lost but not how
    many (a FIFO overrun: the station measures it from time), ``note`` says why.

    When each sample was made, for the station's timeline
    (:mod:`imustation.acquisition.timeline`), where the driver knows better than
    "the newest at the read":

    * ``read_ns``, ``previous_read_ns``: per sample, when the transfer that read it
      returned, and when the chip was read before that (the read that still found
      the sample before, or found nothing new), ns on the station's clock
      (``Driver.clock_ns``): a chip without a FIFO holds only its newest sample, so
      these date it and tell what it made while nobody read it (the ADIS16448,
      which also hands its samples over in batches).
    * ``behind_ns``: the newest sample was made this many ns before the read
      (the noise-model level knows it exactly); None: taken as made at the read.
    """

    channels: dict[str, np.ndarray]
    counter: np.ndarray | None = None
    lost: int = 0
    note: str = ""
    read_ns: np.ndarray | None = None
    previous_read_ns: np.ndarray | None = None
    behind_ns: int | None = None

    @property
    def n(self) -> int:
        return len(next(iter(self.channels.values()))) if self.channels else 0


class Driver(Protocol):
    """Protocol of a streaming device driver (one instance per configured device)."""

    #: config ``driver =`` name
    name: ClassVar[str]
    #: bus kind this driver needs: "i2c", "spi" or "serial"
    bus_kind: ClassVar[str]

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        """Validate config settings; return them completed with defaults.

        Raises :class:`imustation.errors.SettingError` naming the key and the
        allowed values.
        """
        ...

    def open(self) -> DriverInfo:
        """Identify the chip, configure it and start streaming."""
        ...

    def read_block(self) -> Block:
        """Return every sample produced since the last call (may be empty).

        A driver may hold samples it has read and hand them over later (then
        ``Block.read_ns`` dates them); such a driver also has ``drain() -> Block``,
        which the station calls once when recording ends, and at the start to
        drop what was read before it. A driver that stamps its reads has an
        attribute ``clock_ns`` (None until the station sets it to its clock's
        ``now_ns``).
        """
        ...

    def close(self) -> None: ...


Sleep = Callable[[float], None]


@dataclass(frozen=True)
class Setting:
    """One config key of a driver: allowed values (None = any) and default."""

    key: str
    default: Any
    allowed: tuple[Any, ...] | None = None
    doc: str = ""


def check_settings(driver: str, table: tuple[Setting, ...], given: Mapping[str, Any]) -> dict[str, Any]:
    """Common settings validation: unknown keys and values outside ``allowed`` fail."""
    from imustation.errors import SettingError

    known = {s.key: s for s in table}
    for key in given:
        if key not in known:
            raise SettingError(f"{key}: not a setting of driver {driver!r} (known: {', '.join(sorted(known))})")
    out: dict[str, Any] = {}
    for s in table:
        value = given.get(s.key, s.default)
        if s.allowed is not None and value not in s.allowed:
            allowed = ", ".join(str(a) for a in s.allowed)
            raise SettingError(f"{s.key} = {value!r}: driver {driver!r} allows {allowed}")
        out[s.key] = value
    return out
