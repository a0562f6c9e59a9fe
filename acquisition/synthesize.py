"""A virtual capture at the noise-model level: the run file a simulated capture would write, fast.

Why: the byte-level simulated capture runs every sample through the driver, the bus
and the chip simulator (``capture --simulate``: about 27x real time for the whole lab
of the paper in one process, 43-55x with ``--workers 2``, because the ADIS16448 has
no FIFO and costs one USB round trip per sample; docs/capture.md). A 12 h demo of the
whole lab would take 15 to 30 minutes that way. This module
draws the same signals from the same sources (:mod:`imustation.drivers.sim`: the
standard noise model with the device's Table IV parameters, the same per-device
seeds, the same die and room temperatures) and writes them in run-file format v1
with the device specs (identity, settings, scales) the real drivers report for
the simulated chips - without the bus transport, its faults or its timing jitter.

Conversion to counts is the chip simulators' (``rint(value / scale)``, clipped to
the channel's integer range); float channels are written as values. Sample times
are exact multiples of the output period. Devices whose simulator makes its own
accelerometer signal (ADIS16448, Xsens MTi) get gravity on +z plus the white noise
their simulators use; magnetometer, barometer and status channels of the ADIS16448
hold the simulator's constant values (they are not analysed).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from imustation.acquisition.config import StationConfig
from imustation.acquisition.modelsim import ModelStream
from imustation.acquisition.recorder import run_file_device
from imustation.acquisition.station import Station
from imustation.clock import VirtualClock
from imustation.drivers.sim import make_thermometer_simulator, station_device_seed
from imustation.runfile import RunWriter

#: virtual seconds generated per block (memory: ~2 MB per 100 Hz channel axis)
BLOCK_S = 600.0


@dataclass
class SynthSummary:
    duration_s: float
    samples: dict[str, int] = field(default_factory=dict)
    readings: dict[str, int] = field(default_factory=dict)
    path: str = ""


def synthesize(
    config: StationConfig,
    output: str | os.PathLike,
    duration_s: float,
    *,
    overwrite: bool = False,
    progress: Callable[[float], None] | None = None,
) -> SynthSummary:
    """Write ``duration_s`` virtual seconds of every device and thermometer of ``config``.

    ``progress(fraction)`` is called after every block. Returns sample counts per
    device and readings per thermometer.
    """
    station = Station(config, simulate=True)
    try:
        opened = station.open()  # the drivers' own reports of the simulated chips
        thermo_cfg = list(config.thermometers)
    finally:
        station.close()
    streams = {d.name: ModelStream(d.info, d.config, config.seed) for d in opened}
    ambients = []
    for th in thermo_cfg:
        sim, _ = make_thermometer_simulator(
            th.driver, VirtualClock(), th.settings, th.sim, station_device_seed(config.seed, th.name)
        )
        res = float(th.settings.get("resolution_c", 0.0625))
        ambients.append((th.name, float(th.settings.get("rate_hz", 1.0)), sim.temperature, res))
    summary = SynthSummary(float(duration_s), path=os.fspath(output))
    with RunWriter(
        output,
        station=config.name,
        config_text=config.text,
        simulated=True,
        devices=[run_file_device(d) for d in opened],
        thermometers=[a[0] for a in ambients],
        flush_interval_s=config.flush_interval_s,
        overwrite=overwrite,
    ) as writer:
        writer.event(
            0,
            "station",
            "note",
            "synthesised at the noise-model level (imustation.acquisition.synthesize): same sources and seeds "
            "as the chip simulators, no bus transport",
        )
        t = 0.0
        while t < duration_s:
            t_end = min(duration_s, t + BLOCK_S)
            for name, st in streams.items():
                n = int(math.floor(t_end * st.spec.rate_hz + 1e-9)) - st.n
                if n > 0:
                    t_ns, chans, counter = st.block(n)
                    writer.append(name, t_ns, chans, counter)
            for name, rate, ambient, res in ambients:
                k0 = summary.readings.get(name, 0)
                k1 = int(math.floor(t_end * rate + 1e-9))
                if k1 > k0:
                    tt = np.arange(k0, k1) / rate
                    celsius = np.round(np.array([ambient(float(x)) for x in tt]) / res) * res
                    writer.append_temperature(name, np.rint(tt * 1e9).astype(np.int64), celsius)
                    summary.readings[name] = k1
            writer.flush()
            t = t_end
            if progress is not None:
                progress(t / duration_s)
    summary.samples = {name: st.n for name, st in streams.items()}
    return summary
