"""The one write loop every source feeds: blocks in file order -> a run file, stamps checked on the way.

Samples are written in file order, never dropped or reordered;
:class:`~.timestamps.StampChecker` measures the stamps, and every gap (and a
summary of backward / duplicated stamps) becomes an ``/events`` row, so the
analysis splits the record at the gaps (docs/import.md, "Timestamp hygiene").
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from imustation.acquisition.importers.messages import BLOCK_ROWS, Rows
from imustation.acquisition.importers.sources import Recording, open_recording
from imustation.acquisition.importers.timestamps import StampChecker, StampReport
from imustation.acquisition.importers.units import implausible_means
from imustation.runfile import DeviceSpec, RunWriter, utc_now_iso
from imustation.sample_checks import refuse_impossible

#: rows queued (all devices) before the run writer flushes: 2^16 rows = 3.7 MB (its default, 2^20, is 59 MB)
WRITE_ROWS = 1 << 16

Progress = Callable[[int, int], None]


class Target(Protocol):
    """Where the loop writes: the methods of :class:`~imustation.runfile.RunWriter` it uses."""

    def append(self, device: str, t_ns: np.ndarray, channels: dict[str, np.ndarray]) -> None: ...

    def append_temperature(self, name: str, t_ns: np.ndarray, celsius: np.ndarray) -> None: ...

    def event(self, t_ns: int, source: str, kind: str, detail: str = "", lost: int = 0) -> None: ...


@dataclass
class ImportResult:
    """What was imported: the output run file and one stamp report per device."""

    path: str
    source: str
    source_format: str
    devices: dict[str, str]  # device name -> topic / column description
    reports: dict[str, StampReport]
    mapping: str = ""
    thermometers: dict[str, tuple[str, int]] = field(default_factory=dict)  # name -> (topic, readings)
    notes: list[str] = field(default_factory=list)  # reader notes (also /events notes)


class _Sink:
    """Writes blocks of one device and logs the stamp problems as events."""

    def __init__(self, target: Target, name: str, t0: int, with_accel: bool, period_ns: float, source: str = ""):
        self.w, self.name, self.t0, self.with_accel = target, name, t0, with_accel
        self.where = f"{source}: {name}" if source else name
        self.check = StampChecker(period_ns=period_ns)
        self._logged = 0
        self._prev_last = 0
        self._sums: dict[str, np.ndarray] = {}
        #: what the record's stamps and means say against it (printed and stored as notes)
        self.warnings: list[str] = []

    def write(self, blk: Rows) -> None:
        t, gyro, accel = blk
        start = self.check.r.n
        # a flipped bit in a float's exponent must not become a "measured" 4e19 rad/s
        refuse_impossible(f"{self.where} gyro", gyro, "rad/s", start)
        if accel is not None:
            refuse_impossible(f"{self.where} accel", accel, "m/s^2", start)
        rel = t - self.t0
        self.check.update(t)
        for key, x in (("gyro", gyro), ("accel", accel)):
            if x is not None and len(x):
                self._sums[key] = self._sums.get(key, 0.0) + x.sum(axis=0, dtype=np.float64)
        chans = {"gyro": gyro}
        if self.with_accel:
            chans["accel"] = accel if accel is not None else np.zeros_like(gyro)
        self.w.append(self.name, rel, chans)
        self._log_gaps(lambda i: int(rel[i - start]) if i >= start else self._prev_last)
        self._prev_last = int(rel[-1])

    def _log_gaps(self, stamp_of) -> None:
        for idx, dt, miss in self.check.r.gap_list[self._logged :]:
            self.w.event(stamp_of(idx), self.name, "gap", f"stamp gap {dt / 1e6:.3f} ms", lost=miss)
        self._logged = len(self.check.r.gap_list)

    def finish(self) -> StampReport:
        r = self.check.report()
        self._log_gaps(lambda i: self._prev_last)
        t_end = r.last_ns - self.t0
        if r.gaps > len(r.gap_list):
            self.w.event(t_end, self.name, "note", f"{r.gaps - len(r.gap_list)} further gaps not listed", r.missing)
        if r.backwards or r.duplicates:
            first = f"; first at sample {r.backward_list[0][0]}" if r.backward_list else ""
            self.w.event(
                t_end,
                self.name,
                "note",
                f"stamps kept in file order: {r.backwards} non-monotonic, {r.duplicates} duplicated{first}",
            )
        self.w.event(t_end, self.name, "note", "import: " + r.summary())
        means = {k: tuple((v / r.n).tolist()) for k, v in self._sums.items()} if r.n else {}
        for why in r.warnings() + implausible_means(means.get("gyro"), means.get("accel")):
            self.warnings.append(f"{self.name}: {why}")
            self.w.event(t_end, self.name, "note", why[:256])
        return r


def feed(rec: Recording, target: Target, progress: Progress | None = None) -> ImportResult:
    """Write every block of ``rec`` to ``target``: the one loop of every source and target.

    ``progress(done, total)`` after each Imu block. Returns the result without ``path``.
    """
    sinks = {
        key: _Sink(
            target, spec.name, rec.t0, any(c.name == "accel" for c in spec.channels), 1e9 / spec.rate_hz, rec.source
        )
        for key, spec in rec.devices.items()
    }
    readings = dict.fromkeys(rec.thermometers, 0)
    target.event(0, "station", "note", f"imported from {os.path.abspath(rec.source)} ({rec.fmt})"[:256])
    for key, pos, blk in rec.blocks:
        if key in rec.thermometers:
            target.append_temperature(rec.thermometers[key], blk[0] - rec.t0, blk[1])
            readings[key] += len(blk[0])
            continue
        sinks[key].write(blk)
        if progress:
            progress(pos, rec.total)
    reports = {sink.name: sink.finish() for sink in sinks.values()}
    warnings = [w for sink in sinks.values() for w in sink.warnings]
    for note in rec.notes:
        target.event(max(r.last_ns for r in reports.values()) - rec.t0, "station", "note", note[:256])
    return ImportResult(
        "",
        rec.source,
        rec.fmt,
        {spec.name: spec.identity for spec in rec.devices.values()},
        reports,
        rec.mapping,
        {name: (topic, readings[topic]) for topic, name in rec.thermometers.items()},
        rec.notes + warnings,
    )


def fitted_rates(res: ImportResult, devices: dict[str, DeviceSpec]) -> dict[str, float]:
    """Device name -> the rate its whole record's stamps give (:class:`.timestamps.StampReport`'s fit),
    the device's ``rate_hz`` in the file; the probe's rate where the record has too few regular stamps."""
    out = {}
    for spec in devices.values():
        rep = res.reports.get(spec.name)
        fit = rep.true_rate_hz if rep is not None else math.nan
        out[spec.name] = fit if math.isfinite(fit) and fit > 0 else spec.rate_hz
    return out


def import_recording(
    source: str,
    out: str,
    *,
    topic: str | None = None,
    text: dict | None = None,
    time_unit: str | None = None,
    overwrite: bool = False,
    progress: Progress | None = None,
    block: int = BLOCK_ROWS,
    bag_reader: str = "new",
) -> ImportResult:
    """Convert ``source`` into the run file ``out``; returns the stamp reports.

    ``topic``: the Imu topic of a bag (default: all). ``text``: keyword options of
    :func:`.logs.text_mapping` for text logs. ``progress(done, total)`` is called as
    the import advances (messages for bags, bytes for text, rows for arrays).
    ``bag_reader``: ``"new"`` (streaming, the default) or ``"old"`` (rosbags message by message, for
    comparison; see :func:`.bags.iter_bag`). sensor_msgs/Temperature topics of a bag become thermometers.
    """
    rec = open_recording(source, topic=topic, text=text, time_unit=time_unit, block=block, bag_reader=bag_reader)
    writer = RunWriter(
        out, station="import", config_text="", simulated=False, devices=list(rec.devices.values()),
        thermometers=list(rec.thermometers.values()), overwrite=overwrite, started_utc=_iso(rec.t0),
        fsync=False,  # an import is re-run from its source; no power-cut guarantee needed
        ballast_bytes=0, max_buffer_rows=WRITE_ROWS,
    )  # fmt: skip
    try:
        res = feed(rec, writer, progress)
    except BaseException:
        writer.abort()
        raise
    attrs = {"source": os.path.abspath(source), "source_format": rec.fmt, "import_report": _rep(res.reports)}
    # ended_utc is the end of the data, as for a capture; when the conversion ran is imported_utc
    attrs["imported_utc"] = utc_now_iso()
    last = max((r.last_ns for r in res.reports.values() if r.n), default=rec.t0)
    rates = fitted_rates(res, rec.devices)
    writer.close(
        ended_utc=_iso(rec.t0, last - rec.t0), attrs=attrs, device_attrs={n: {"rate_hz": hz} for n, hz in rates.items()}
    )
    res.path = out
    return res


def _iso(ns: int, after_ns: int = 0) -> str:
    """UTC time of the stamp ``ns`` plus ``after_ns`` (ns), to the stamp's own resolution: ms, us or ns
    digits as the time needs (``t`` counts from ``started_utc``, so a started_utc cut to ms would date
    every sample up to 1 ms early). Stamps that do not look like Unix time start at 1970-01-01
    (``started_utc`` of such an import), so the end is that plus the span."""
    base = ns if ns > 10**17 else 0  # a Unix epoch in ns, or a clock of its own
    return iso_ns(base + after_ns)


def iso_ns(ns: int) -> str:
    """ISO 8601 UTC of ``ns`` since the Unix epoch with 3, 6 or 9 fraction digits, the fewest that are exact."""
    sec, frac = divmod(int(ns), 1_000_000_000)
    stamp = _dt.datetime.fromtimestamp(sec, _dt.UTC).strftime("%Y-%m-%dT%H:%M:%S")
    digits = 3 if frac % 1_000_000 == 0 else 6 if frac % 1000 == 0 else 9
    return f"{stamp}.{frac // 10 ** (9 - digits):0{digits}d}+00:00"


def _rep(reports: dict[str, StampReport]) -> str:
    return json.dumps({k: r.as_dict() for k, r in reports.items()})
