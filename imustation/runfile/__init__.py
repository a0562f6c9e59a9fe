"""Run-file format, version 1: one HDF5 file per capture (``docs/runfile.md``).

Raw integer counts are stored, never only converted floats: the conversion is
kept as attributes (``value = raw * scale + offset``, SI units), so nothing is
lost and files stay small.

- :mod:`~imustation.runfile.schema`: the layout's names and :class:`DeviceSpec`;
- :mod:`~imustation.runfile.writer`: :class:`RunWriter`, through which the
  recorder (``imustation.acquisition``) writes;
- :mod:`~imustation.runfile.reader`: :func:`open_run`, through which the
  analysis, ``imustation inspect`` and the monitor read;
- :mod:`~imustation.runfile.checks`: validation on read (attributes against the schema and
  each other, damaged chunks, event rows) - a damaged file is one clear error;
- :mod:`~imustation.runfile.swmr`: the SWMR open with a bounded retry on damaged blocks;
- :mod:`~imustation.runfile.recover`: ``imustation recover`` (a crashed file made plain);
- :mod:`~imustation.runfile.series`: :func:`open_series`, the parts of a rotated capture
  read as one run (:class:`RunSeries`), and :func:`join_parts` for a command's inputs;
- :mod:`~imustation.runfile.breaks`: where logged gaps break a device's record;
- :mod:`~imustation.runfile.holes`: holes in a device's record found from its times (or counter)
  and matched with its logged losses;
- :mod:`~imustation.runfile.disk`: durable renames and the full-disk ballast.

Nothing else touches the HDF5 layout. Every name is importable from
``imustation.runfile`` itself; :class:`ChannelSpec` is defined in
:mod:`imustation.channels` (drivers use it without the file format).
"""

from imustation.channels import ChannelSpec
from imustation.runfile.reader import ChannelInfo, DeviceInfo, RunFile, open_run
from imustation.runfile.schema import (
    CELSIUS,
    COUNTER,
    DEVICES,
    EVENT_DTYPE,
    EVENT_KINDS,
    EVENTS,
    FORMAT,
    FORMAT_VERSION,
    LOSS_KINDS,
    THERMOMETERS,
    TIME,
    DeviceSpec,
    Event,
    utc_now_iso,
)
from imustation.runfile.series import RunSeries, join_parts, latest_part, open_series, part_path, parts_of
from imustation.runfile.writer import (
    BALLAST_SUFFIX,
    CHUNK_ROWS,
    CREATING_SUFFIX,
    DEFAULT_BALLAST_BYTES,
    DEFAULT_MIN_FREE_BYTES,
    H5_OPTS,
    RunWriter,
)

__all__ = [
    "BALLAST_SUFFIX",
    "CELSIUS",
    "CHUNK_ROWS",
    "COUNTER",
    "CREATING_SUFFIX",
    "DEFAULT_BALLAST_BYTES",
    "DEFAULT_MIN_FREE_BYTES",
    "DEVICES",
    "EVENTS",
    "EVENT_DTYPE",
    "EVENT_KINDS",
    "FORMAT",
    "FORMAT_VERSION",
    "H5_OPTS",
    "LOSS_KINDS",
    "THERMOMETERS",
    "TIME",
    "ChannelInfo",
    "ChannelSpec",
    "DeviceInfo",
    "DeviceSpec",
    "Event",
    "RunFile",
    "RunSeries",
    "RunWriter",
    "join_parts",
    "latest_part",
    "open_run",
    "open_series",
    "part_path",
    "parts_of",
    "utc_now_iso",
]
