"""Exception hierarchy shared by every layer.

Every error a user can cause (bad config, bad file, bad option value) derives
from :class:`ImustationError`; the CLI prints its message as one line and exits
with status 2. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations


class ImustationError(Exception):
    """Base of all expected, user-facing errors. ``str(err)`` is one line."""


class ConfigError(ImustationError):
    """A station config file is missing, malformed or holds a forbidden value."""

    def __init__(self, path: str, key: str | None, problem: str):
        self.path, self.key, self.problem = str(path), key, problem
        where = f"{self.path}: {key}: " if key else f"{self.path}: "
        super().__init__(where + problem)


class RunFileError(ImustationError):
    """A file is unreadable or is not an imustation run file of a known version."""


class RateCorrected(UserWarning):
    """A run file's ``rate_hz`` contradicts its timestamps beyond their jitter; readers use the stamps' rate
    (imustation.runfile.checks). The CLI prints it as one ``imustation: warning:`` line."""


class InputError(ImustationError):
    """Analysis input (array file, channel selection, option value) is unusable."""


class RecordTooShort(InputError):
    """The record, or each contiguous piece of it between logged holes, is too short for an estimator.
    The analysis reports a channel split into such pieces as skipped, not failed (docs/analysis-json.md)."""


# --- bus layer -------------------------------------------------------------


class BusError(ImustationError):
    """A transaction on a bus failed (after any retries the bus makes)."""


class NackError(BusError):
    """The addressed device did not acknowledge (I2C NACK, ENXIO/EREMOTEIO)."""


class BusTimeout(BusError):
    """The bus or bridge did not answer in time."""


class BusClosed(BusError):
    """The bus was closed, or its device disappeared (cable pulled)."""


# --- device layer ----------------------------------------------------------


class DeviceError(ImustationError):
    """A device answered, but not as the driver expects."""


class ChipIdMismatch(DeviceError):
    """The identity register holds another value than the driver's chip."""

    def __init__(self, chip: str, expected: int, found: int, where: str):
        self.chip, self.expected, self.found, self.where = chip, expected, found, where
        super().__init__(
            f"{where}: expected {chip} (id 0x{expected:02X}), found id 0x{found:02X}"
            " - check the wiring, the address and the driver name"
        )


class SettingError(DeviceError):
    """A requested device setting is not one the chip supports."""


class DiskFullError(RunFileError):
    """The run file's filesystem is full: the capture stops, the file stays readable."""
