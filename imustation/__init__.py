"""imustation: record inertial sensors for many hours and characterise their noise.

The importable layers are ``imustation.drivers`` (chips and buses),
``imustation.acquisition`` (station, capture) and ``imustation.analysis``
(Allan, PSD, ML_i ...). The root package holds what belongs to no layer:
errors, units, clocks, channel descriptions (``imustation.channels``), the
run-file format (``imustation.runfile``) and the CLI.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("imustation")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = ["__version__"]
