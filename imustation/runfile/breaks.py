"""Where the logged gaps of a run file break its record (the format's event semantics, docs/runfile.md).

Readers that cut a device's record into contiguous segments (the analysis loaders, the
monitor, the reader of a rotated series joining its parts) locate the breaks here.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np


def locate_breaks(t_ns: Any, events: Iterable[Any], rate_hz: float, window: int = 4096) -> list[int]:
    """Sample indices where logged gaps/overruns break the record.

    ``t_ns``: the device's sample times (ns, sorted; an array, an HDF5 dataset or
    anything sliced like one, read only near each event); ``events``: its gap and
    overrun events (``t_ns``, ``lost``); ``rate_hz``: its configured rate (Hz).

    A loss event is dated at the first sample it says is missing, between the
    samples around its hole; files of earlier versions (and some imports) dated
    it at the read that found samples missing, whose newest sample carries that
    time (docs/runfile.md). Either way the break lies at or before the first
    sample after ``t``: among the samples up to it (``window`` samples back),
    it is the largest jump of the timestamps. An event whose block shows no jump above 1.5 sample
    periods leaves the record contiguous (the timestamps show nothing missing,
    e.g. ``lost`` estimated as 0). Returns sorted unique indices ``j``: samples ``j-1`` and ``j``
    are not neighbours.
    """
    n = len(t_ns)
    period_ns = 1e9 / rate_hz
    breaks = set()
    for ev in events:
        lo, hi = 0, n  # binary search on the (possibly on-disk) sorted timestamps
        while lo < hi:
            mid = (lo + hi) // 2
            if int(t_ns[mid]) <= ev.t_ns:
                lo = mid + 1
            else:
                hi = mid
        i = lo  # samples 0..i-1 are at or before the event
        a, b = max(0, i - max(window, 4 * max(ev.lost, 0))), min(n, i + 1)
        if b - a < 2:
            continue
        t = np.asarray(t_ns[a:b], dtype=np.int64)
        jumps = np.diff(t)
        k = int(np.argmax(jumps))
        if jumps[k] > 1.5 * period_ns:
            breaks.add(a + k + 1)
    return sorted(j for j in breaks if 0 < j < n)
