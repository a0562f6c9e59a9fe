"""One capture: station -> run file(s), with clean stops on SIGINT/SIGTERM and a full disk.

Order of work, so a bad start never leaves a half-made file: lock the output
and refuse existing files, open every device (identity, settings), then create
the run file and record. The file is finished (``ended_utc`` set) at the end of
the duration, after SIGINT/SIGTERM and when the disk fills up; after any other
error it is closed as it is, holding every sample up to the last flush.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable, Sequence
from typing import Any

from imustation.acquisition.clocksync import ClockWatch
from imustation.acquisition.config import StationConfig
from imustation.acquisition.modes import check_options
from imustation.acquisition.readers import ReaderOptions
from imustation.acquisition.realtime import READER_PRIORITY
from imustation.acquisition.recorder import Recorder, reserve_resumed
from imustation.acquisition.resume import resumed_nothing
from imustation.acquisition.station import DEFAULT_THERMOMETER_RATE_HZ, STATUS_INTERVAL_S, CaptureSummary, Station
from imustation.clock import Clock, MonotonicClock
from imustation.drivers.bus.trace import Trace, TraceWriter
from imustation.errors import DiskFullError, InputError
from imustation.runfile import DEFAULT_BALLAST_BYTES, DEFAULT_MIN_FREE_BYTES
from imustation.units import format_duration

#: opens every part file of a model-level simulated capture
MODEL_LEVEL_NOTE = (
    "simulated at the noise-model level (--sim-level model): the drivers opened their chip simulators, "
    "the samples come from the same noise sources without bus transport"
)


class _StopFlag:
    """Set by SIGINT/SIGTERM; the station checks it between polls."""

    def __init__(self) -> None:
        self.signum: int | None = None

    def __call__(self) -> bool:
        return self.signum is not None

    def handler(self, signum, frame) -> None:  # noqa: ARG002 - signal handler signature
        self.signum = signum


def shortest_capture_s(config: StationConfig) -> tuple[float, str]:
    """The shortest capture of ``config`` that records anything (s), and what sets it: one flush
    interval (nothing is on disk before the first flush) or the slowest configured sample period
    of a device or thermometer (it would get no sample)."""
    best = (
        float(config.flush_interval_s),
        f"one flush interval (station.flush_interval_s {config.flush_interval_s:g} s)",
    )
    for dev in (*config.devices, *config.thermometers):
        rate = dev.settings.get("rate_hz", DEFAULT_THERMOMETER_RATE_HZ if dev in config.thermometers else None)
        if isinstance(rate, (int, float)) and rate > 0 and 1.0 / rate > best[0]:
            best = (1.0 / float(rate), f"one sample period of {dev.name} ({float(rate):g} Hz)")
    return best


def check_capture_duration(config: StationConfig, duration_s: float) -> None:
    """Refuse (:class:`InputError`) a ``duration_s`` shorter than :func:`shortest_capture_s`: it
    would write a file without samples that every analysis then rejects."""
    least, why = shortest_capture_s(config)
    if not duration_s >= least:
        raise InputError(
            f"--duration {format_duration(duration_s)} is shorter than {why}: nothing would be recorded; "
            f"use at least {format_duration(least)}"
        )


def capture(
    config: StationConfig,
    output: str | os.PathLike,
    duration_s: float,
    *,
    simulate: bool,
    overwrite: bool = False,
    on_status: Callable[[dict[str, Any]], None] | None = None,
    status_interval_s: float = STATUS_INTERVAL_S,
    rotate_s: float | None = None,
    pace: float | None = None,
    clock: Clock | None = None,
    fsync: bool = True,
    min_free_bytes: int = DEFAULT_MIN_FREE_BYTES,
    ballast_bytes: int = DEFAULT_BALLAST_BYTES,
    trace: str | os.PathLike | None = None,
    replay: str | os.PathLike | None = None,
    workers: int = 1,
    sim_level: str = "bus",
    early_stop: Sequence[int] = (),
    resume: bool = False,
    resume_now: Callable[[], Any] | None = None,
    clock_watch: ClockWatch | None = None,
    real_time: bool = False,
    reader_priority: int = READER_PRIORITY,
    reader_cpus: Sequence[int] | None = None,
    reader_spin_us: int = 0,
    reader_phase: bool = True,
    on_note: Callable[[str], None] | None = None,
) -> CaptureSummary:
    """Record every device and thermometer of ``config`` for ``duration_s`` into ``output``.

    Parameters
    ----------
    rotate_s : start a new part file every this many seconds of station time
        (``run.001.h5``, ``run.002.h5``, ...); None writes one file.
    sim_level : simulation only: ``"bus"`` (chip simulators behind the real bus code) or
        ``"model"`` (devices at the noise-model level, :mod:`~imustation.acquisition.modelsim`).
    pace : simulation only: at most this many virtual seconds per wall second.
    clock : override the station clock (tests run simulated chips on a real clock).
    fsync, min_free_bytes, ballast_bytes : see :class:`~imustation.runfile.RunWriter`.
    trace : write every bus transaction of every device to this JSON-lines file.
    replay : answer every driver from this trace instead of a bus (virtual clock);
        the drivers must ask exactly what they asked when it was recorded.
    workers : simulation on the virtual clock only: processes to poll the bus
        groups in (see :mod:`~imustation.acquisition.workers`); 1 = this one.
    real_time : simulation only: the chip simulators on the host clock, each bus polled by
        a reader process as in a capture of real devices (a rehearsal: what this host loses).
    reader_priority : host clock: the SCHED_FIFO priority the reader processes ask for
        (:mod:`~imustation.acquisition.realtime`; 0 asks for nothing); ``reader_cpus``: the CPUs
        they run on (None: the kernel places them); ``reader_spin_us``: hybrid sleep, the last this
        many us before a poll of a device without a FIFO spent reading the clock instead of sleeping
        (:func:`~imustation.acquisition.scheduler.run_deadline`; 0: off; ``benchmarks/bench_hostclock.py
        --spin-us``); ``reader_phase``: poll a device without a FIFO just after it makes each sample once
        its reads show when (:mod:`~imustation.acquisition.pollphase`; False: blind, twice per sample - the
        benchmark's reference, ``--blind``).
    on_note : called with each line the operator should read (e.g. scheduling the OS refused).
    early_stop : SIGINT/SIGTERM received before this call (the CLI records them from its
        start, read once the capture's own handlers are in place): the capture opens its
        devices, creates its file and finishes it at once, with the stop's note.
    resume : continue the run at ``output`` as its next part, if there is one
        (:mod:`~imustation.acquisition.resume`); ``duration_s`` is then the whole run's,
        from its start. ``resume_now``: the wall clock (tests).
    clock_watch : the host clock's state and steps (:mod:`~imustation.acquisition.clocksync`;
        default: the kernel's, read with adjtimex).

    Returns the summary; ``summary.stop_reason`` says why a capture ended early.
    Raises :class:`~imustation.errors.DiskFullError` after finishing the file
    when the disk filled up, :class:`~imustation.errors.InputError` before anything is
    written for a duration shorter than one flush or sample period (:func:`check_capture_duration`).
    """
    check_options(
        simulate=simulate,
        sim_level=sim_level,
        workers=workers,
        virtual_clock=clock is None,  # an imposed clock is a test's
        trace=trace is not None,
        replay=replay is not None,
        rotate=rotate_s is not None,
        real_time=real_time,
    )
    check_capture_duration(config, duration_s)  # the planned duration, before a resume shortens it
    lock, point = (
        reserve_resumed(output, config, duration_s, simulated=simulate, now=resume_now) if resume else (None, None)
    )
    if point is not None:
        duration_s = point.remaining_s(duration_s)
        if duration_s <= 0:
            lock.release()  # type: ignore[union-attr]
            return resumed_nothing(point, duration_s)
    recorder = Recorder(
        output,
        resume=point,
        lock=lock,
        clock_watch=clock_watch or ClockWatch(),
        duration_s=duration_s,
        rotate_s=rotate_s,
        overwrite=overwrite,
        station=config.name,
        config_text=config.text,
        simulated=simulate,
        flush_interval_s=config.flush_interval_s,
        fsync=fsync,
        min_free_bytes=min_free_bytes,
        ballast_bytes=ballast_bytes,
        note=MODEL_LEVEL_NOTE if simulate and sim_level == "model" else "",
    )
    readers = None
    if real_time or (not simulate and clock is None and trace is None and replay is None):
        # the host clock: every bus in a reader process of its own (a trace is recorded in one process)
        cpus = tuple(reader_cpus) if reader_cpus is not None else None
        readers = ReaderOptions(
            simulate=simulate, priority=reader_priority, cpus=cpus, spin_us=reader_spin_us, phase=reader_phase
        )
        clock = MonotonicClock()
    replayed = Trace(replay) if replay is not None else None
    recorder.reserve()
    try:
        tracer = TraceWriter(trace) if trace is not None else None
    except BaseException:
        recorder.lock.release()
        raise
    station = Station(
        config,
        simulate=simulate,
        clock=clock,
        trace=tracer,
        replay=replayed,
        workers=workers,
        sim_level=sim_level,
        readers=readers,
    )
    stop = _StopFlag()
    previous = {}
    # the station's last document ("done"/"stopped") is handed on once the file is finished,
    # with the file's figures then: the last flush and the closing write are on disk only now
    final: list[dict[str, Any]] = []

    def relay(status: dict[str, Any]) -> None:
        if status.get("state") == "recording":
            on_status(status)  # type: ignore[misc]
        else:
            final.append(status)

    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, stop.handler)
    if early_stop:
        stop.signum = early_stop[0]
    started = False
    try:
        specs = station.open()
        recorder.start(specs, {name: th.rate_hz for name, th in station.thermometers.items()})
        started = True
        _note_scheduling(station, recorder, on_note)
        try:
            summary = station.run(
                recorder,
                duration_s,
                on_status=relay if on_status is not None else None,
                should_stop=stop,
                status_interval_s=status_interval_s,
                pace=pace,
            )
        except DiskFullError:
            _finish_after_disk_full(recorder, station)
            raise
        if stop.signum is not None:
            summary.stop_reason = f"stopped by signal {signal.Signals(stop.signum).name}"
            recorder.event(station.clock.now_ns() - station.t0, "station", "note", summary.stop_reason)
        recorder.finish()
        summary.paths = list(recorder.paths)
        return summary
    except BaseException:
        if started:
            recorder.abort()
        else:
            recorder.lock.release()
        raise
    finally:
        station.close()
        if tracer is not None:
            tracer.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if final and on_status is not None:
            on_status({**final[-1], **recorder.status()})


def _note_scheduling(station: Station, recorder: Recorder, on_note: Callable[[str], None] | None) -> None:
    """What each reader process obtained from the OS, as a note in the run file; what it was refused,
    once, to the operator too."""
    said = set()
    for bus, scheduling in station.scheduling().items():
        recorder.event(0, "station", "note", f"reader process for {bus}: {scheduling.describe()}")
        if scheduling.missing and scheduling.missing not in said:
            said.add(scheduling.missing)
            recorder.event(0, "station", "note", scheduling.missing)
            if on_note is not None:
                on_note(scheduling.missing)


def _finish_after_disk_full(recorder: Recorder, station: Station) -> None:
    """Close the file as cleanly as the disk allows: complete if the reserve held, else as it is."""
    writer = recorder.writer
    assert writer is not None
    if writer.broken:
        recorder.abort()
        return
    writer.discard_pending()
    try:
        recorder.event(station.clock.now_ns() - station.t0, "station", "note", "capture stopped: disk full")
        recorder.finish({"stopped": "disk full"})
    except (OSError, DiskFullError):
        recorder.abort()
