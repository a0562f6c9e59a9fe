"""One capture: station -> run file, with clean stops on SIGINT/SIGTERM."""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable
from typing import Any

from imustation.acquisition.config import StationConfig
from imustation.acquisition.station import CaptureSummary, Station
from imustation.runfile import RunWriter


class _StopFlag:
    """Set by SIGINT/SIGTERM; the station loop checks it between polls."""

    def __init__(self) -> None:
        self.signum: int | None = None

    def __call__(self) -> bool:
        return self.signum is not None

    def handler(self, signum, frame) -> None:  # noqa: ARG002 - signal handler signature
        self.signum = signum


def capture(
    config: StationConfig,
    output: str | os.PathLike,
    duration_s: float,
    *,
    simulate: bool,
    overwrite: bool = False,
    on_status: Callable[[dict[str, Any]], None] | None = None,
) -> CaptureSummary:
    """Record every device of ``config`` for ``duration_s`` into ``output``.

    The run file is complete (``ended_utc`` set) when this returns, also after
    SIGINT/SIGTERM, which end the capture early at the next poll. Any other
    error leaves a readable file holding every sample up to the last flush.
    """
    station = Station(config, simulate=simulate)
    stop = _StopFlag()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, stop.handler)
    try:
        specs = station.open()
        writer = RunWriter(
            output,
            station=config.name,
            config_text=config.text,
            simulated=simulate,
            devices=specs,
            flush_interval_s=config.flush_interval_s,
            overwrite=overwrite,
        )
        try:
            summary = station.run(writer, duration_s, on_status=on_status, should_stop=stop)
            if stop.signum is not None:
                writer.event(
                    station.clock.now_ns() - station.t0,
                    "station",
                    "note",
                    f"stopped by signal {signal.Signals(stop.signum).name}",
                )
        except BaseException:
            writer.abort()
            raise
        writer.close()
        return summary
    finally:
        station.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
