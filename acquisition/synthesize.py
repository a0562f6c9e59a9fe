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
from imustation.acquisition.station import Station
from imustation.clock import VirtualClock
from imustation.drivers.sim import device_sources, make_thermometer_simulator, station_device_seed
from imustation.drivers.sim.adis16448 import ACCEL_NOISE_G
from imustation.drivers.sim.xsens_mti import ACCEL_NOISE
from imustation.runfile import DeviceSpec, RunWriter
from imustation.units import G0

#: virtual seconds generated per block (memory: ~2 MB per 100 Hz channel axis)
BLOCK_S = 600.0
#: accelerometer white noise per sample of the simulators that make their own (m/s^2)
_OWN_ACCEL_NOISE = {"adis16448": ACCEL_NOISE_G * G0, "mti": ACCEL_NOISE}


@dataclass
class SynthSummary:
    duration_s: float
    samples: dict[str, int] = field(default_factory=dict)
    readings: dict[str, int] = field(default_factory=dict)
    path: str = ""


def _to_dtype(values: np.ndarray, spec) -> np.ndarray:
    """Chip-simulator conversion of SI values to the channel's stored type."""
    dt = np.dtype(spec.dtype)
    raw = (values - spec.offset) / spec.scale
    if dt.kind in "iu":
        info = np.iinfo(dt)
        return np.clip(np.rint(raw), info.min, info.max).astype(dt)
    return raw.astype(dt)


def _draw(source, n: int) -> np.ndarray:
    """``n`` samples asked in pieces no larger than the source's refill block, as the chip
    simulators ask them, so the stream is sample for sample the one a byte-level capture reads."""
    step = int(getattr(source, "BLOCK", n)) or n
    return np.concatenate([source.next(min(step, n - i)) for i in range(0, n, step)])


class _DeviceStream:
    """Blocks of one device's channels from its simulation sources."""

    def __init__(self, spec: DeviceSpec, dev, station_seed: int):
        self.spec = spec
        seed = station_device_seed(station_seed, dev.name)
        self.sources = device_sources(dev, seed)
        self.rng = np.random.default_rng([seed, 0xACC])
        self.n = 0
        self.modulus = int(spec.settings.get("counter_modulus", 0) or 0)
        self.driver = dev.driver
        # the constant channels: what the chip simulator reports when nothing changes
        self.constants = {"diag": 0.0, "baro": 101325.0, "mag": np.array([2.0e-5, 0.0, 4.5e-5])}

    def block(self, n: int) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray | None]:
        idx = np.arange(self.n, self.n + n, dtype=np.int64)
        self.n += n
        period_ns = 1e9 / self.spec.rate_hz
        t_ns = np.rint(idx * period_ns).astype(np.int64)
        t_s = t_ns / 1e9
        out: dict[str, np.ndarray] = {}
        main = self.sources.get("gyro") or self.sources.get("accel")
        for ch in self.spec.channels:
            width = max(1, len(ch.axes))
            if ch.name in self.sources:
                values = _draw(self.sources[ch.name], n)
            elif ch.name == "accel":
                noise = _OWN_ACCEL_NOISE.get(self.driver, 0.01)
                values = np.array([0.0, 0.0, G0]) + self.rng.normal(0.0, noise, (n, 3))
            elif ch.name == "temp":
                # the die temperature drifts over hours: evaluate once per second, interpolate
                grid = np.arange(math.floor(t_s[0]), math.ceil(t_s[-1]) + 2.0)
                temps = np.array([main.temperature(float(g)) for g in grid])
                values = np.interp(t_s, grid, temps)
            elif ch.name == "sample_time_fine":
                values = t_s
            else:
                values = np.broadcast_to(self.constants.get(ch.name, 0.0), (n, width) if ch.axes else (n,))
            if not ch.axes and values.ndim == 2:
                values = values[:, 0]
            out[ch.name] = _to_dtype(np.asarray(values, dtype=float), ch)
        counter = None
        if self.spec.has_counter:
            counter = idx % self.modulus if self.modulus else idx
        return t_ns, out, counter


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
        specs = station.open()  # the drivers' own specs of the simulated chips
        thermo_cfg = list(config.thermometers)
    finally:
        station.close()
    by_name = {d.name: d for d in config.devices}
    streams = [_DeviceStream(s, by_name[s.name], config.seed) for s in specs]
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
        devices=specs,
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
            for st in streams:
                n = int(math.floor(t_end * st.spec.rate_hz + 1e-9)) - st.n
                if n > 0:
                    t_ns, chans, counter = st.block(n)
                    writer.append(st.spec.name, t_ns, chans, counter)
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
    summary.samples = {st.spec.name: st.n for st in streams}
    return summary
