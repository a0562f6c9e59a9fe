"""Live monitor of a run file being written: ``imustation monitor RUN.h5``.

A small read-only web server beside an overnight capture (docs/monitor.md):

* :mod:`.watcher` reads the run file while it is written (HDF5 SWMR, read-only,
  re-opened at every poll) and keeps the status, temperature series and the
  gyro counts the Allan curves need, reading only the rows added since the
  last poll;
* :mod:`.live_allan` computes each gyro axis's overlapping Allan deviation
  (the analysis package's ``oadev`` on raw counts) and, once enough data
  exist, the ML_i fit of the paper's standard model and its Allan curve, in a
  background thread, at most every few seconds;
* :mod:`.server` serves one page, its vendored scripts (uPlot, no CDN) and
  three JSON endpoints with tornado; GET only, localhost by default, a token
  for any other address;
* :mod:`.launcher` starts the monitor as its own process beside a capture
  (``imustation capture ... --monitor``).

The monitor never writes: the capture cannot be slowed by more than the CPU
and disk reads of another process, and a crash of the monitor leaves it
untouched.
"""

from __future__ import annotations

from imustation.monitor.watcher import Monitor

__all__ = ["Monitor"]
