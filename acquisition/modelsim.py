"""Simulated devices at the noise-model level: polled by the station like drivers, no bus underneath.

Why: a capture at the bus level (``capture --simulate``, the default ``--sim-level bus``)
runs every sample through the driver, the bus code, pyusb or pyserial and the chip
simulator, as a bench capture does. That is the point of it, and it bounds its speed:
the ADIS16448 has no FIFO, so it costs one USB round trip per sample (409.6 per
second), and one simulated CP2130 transfer through pyusb alone takes ~10 us here
(``benchmarks/bench_capture.py`` prints it) - a 12 h lab runs at 40-70x real time.

At ``--sim-level model`` every device is a :class:`ModelDevice`: the station still
opens the driver once on its chip simulator (so identity, settings, channels and
scales are the driver's own), then polls the device's noise sources directly - the
same sources, seeds and temperatures the chip simulators read
(:func:`imustation.drivers.sim.device_sources`: the output filter the settings select,
drawn at the chip's internal rate, and any noise terms of the device's profile; the
same samples as the bus level), converted to counts as the chip simulators convert
them. Scheduler, counters, gap and fault handling, recorder, flushes, rotation, status
and workers are the ones a bus-level capture runs.
Thermometers stay on their (simulated) I2C bus: three readings per second cost
nothing.

What the model level leaves out: bus transactions and their timing jitter, FIFO
mechanics, and the bus-level fault kinds. Of the ``[device.sim]`` faults it
simulates the outcome a station sees: ``disconnect`` (the device fails for
``duration_s``, at least until the next poll, is re-opened, and what it produced since
the last read before it is lost) and ``checksum`` on devices whose protocol carries one
(one sample dropped and logged).
Other kinds are refused at open with the level that simulates them.
"""

from __future__ import annotations

import math
from dataclasses import replace
from fractions import Fraction
from typing import Any

import numpy as np

from imustation.channels import DriverInfo
from imustation.clock import Clock
from imustation.drivers.base import Block
from imustation.drivers.sim import device_sources, station_device_seed
from imustation.drivers.sim.adis16448 import ACCEL_NOISE_G
from imustation.drivers.sim.faults import FaultPlan, parse_faults
from imustation.drivers.sim.xsens_mti import ACCEL_NOISE
from imustation.errors import ConfigError, DeviceError
from imustation.units import G0

#: station poll interval of a model-level device, s: nothing overflows, so poll seldom
#: (a driver's own interval is kept when it is longer)
MODEL_POLL_S = 1.0
#: fault kinds the model level simulates (their outcome at the station)
MODEL_FAULTS = ("disconnect", "checksum")
#: drivers whose protocol carries a checksum, so a bad one drops a sample (``crc`` setting if any)
CHECKSUMMED = ("adis16448", "mti", "dsp3000")
#: accelerometer white noise per sample of the chip simulators that make their own (m/s^2)
OWN_ACCEL_NOISE = {"adis16448": ACCEL_NOISE_G * G0, "mti": ACCEL_NOISE}
#: what the chip simulators report on channels the noise model does not drive
_CONSTANTS = {"diag": 0.0, "baro": 101325.0, "mag": np.array([2.0e-5, 0.0, 4.5e-5])}
#: largest denominator of an output rate in Hz (409.6 = 2048/5): sample times are exact integers
_RATE_DENOMINATOR = 1 << 16


def exact_rate(rate_hz: float) -> Fraction:
    """An output rate (Hz) as the exact fraction it stands for (819.2 / 2**D, 1000 / (1 + div), ...)."""
    return Fraction(rate_hz).limit_denominator(_RATE_DENOMINATOR)


def to_counts(values: np.ndarray, spec: Any) -> np.ndarray:
    """Chip-simulator conversion of SI values to a channel's stored type (``rint(value / scale)``, clipped)."""
    dt = np.dtype(spec.dtype)
    raw = (values - spec.offset) / spec.scale
    if dt.kind in "iu":
        info = np.iinfo(dt)
        return np.clip(np.rint(raw), info.min, info.max).astype(dt)
    return raw.astype(dt)


def _draw(source: Any, n: int) -> np.ndarray:
    """``n`` samples asked in pieces no larger than the source's refill block, as the chip
    simulators ask them, so the stream is sample for sample the one a bus-level capture reads."""
    step = int(getattr(source, "BLOCK", n)) or n
    if n <= step:
        return source.next(n)
    return np.concatenate([source.next(min(step, n - i)) for i in range(0, n, step)])


class ModelStream:
    """Blocks of one device's channels, in counts, from its simulation sources.

    Parameters
    ----------
    spec : what the driver reported for the simulated chip (its ``DriverInfo``):
        ``channels``, ``rate_hz`` (Hz), ``settings``, ``has_counter``.
    dev : the device's config entry (``name``, ``driver``, ``sim``).
    station_seed : the config's ``station.seed``.
    """

    def __init__(self, spec: Any, dev: Any, station_seed: int):
        self.spec = spec
        seed = station_device_seed(station_seed, dev.name)
        self.sources = device_sources(dev, seed)
        self.rng = np.random.default_rng([seed, 0xACC])
        #: samples produced so far (the index of the next one)
        self.n = 0
        self.modulus = int(spec.settings.get("counter_modulus", 0) or 0)
        self.driver = dev.driver
        self.rate = exact_rate(spec.rate_hz)
        self._main = self.sources.get("gyro") or self.sources.get("accel")

    def made_ns(self, idx: int) -> int:
        """When sample ``idx`` (0 the first) is made, ns after the stream's start: the first instant the
        output period fits ``idx + 1`` times (exact integer arithmetic from the index)."""
        num, den = self.rate.numerator, self.rate.denominator
        return -(-(int(idx) + 1) * (10**9 * den) // num)

    def due(self, elapsed_ns: int) -> int:
        """Samples made ``elapsed_ns`` (ns) after the stream's start."""
        return int(elapsed_ns) * self.rate.numerator // (10**9 * self.rate.denominator)

    def block(self, n: int) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray | None]:
        """The next ``n`` samples: (times since the stream's start, ns; channels in counts; counter or None)."""
        idx = np.arange(self.n, self.n + n, dtype=np.int64)
        self.n += n
        # from the index, not accumulated (exact in float64 for these periods up to ~100 days)
        t_ns = np.rint(idx * (1e9 / float(self.rate))).astype(np.int64)
        out: dict[str, np.ndarray] = {}
        for ch in self.spec.channels:
            if ch.name in self.sources:
                values = _draw(self.sources[ch.name], n)
            elif ch.name == "accel":
                noise = OWN_ACCEL_NOISE.get(self.driver, 0.01)
                values = np.array([0.0, 0.0, G0]) + self.rng.normal(0.0, noise, (n, 3))
            elif ch.name == "temp":
                # the die temperature drifts over hours: evaluate once per second, interpolate
                t_s = t_ns / 1e9
                grid = np.arange(math.floor(t_s[0]), math.ceil(t_s[-1]) + 2.0)
                temps = np.array([self._main.temperature(float(g)) for g in grid])
                values = np.interp(t_s, grid, temps)
            elif ch.name == "sample_time_fine":
                values = t_ns / 1e9
            else:
                width = max(1, len(ch.axes))
                values = np.broadcast_to(_CONSTANTS.get(ch.name, 0.0), (n, width) if ch.axes else (n,))
            if not ch.axes and values.ndim == 2:
                values = values[:, 0]
            out[ch.name] = to_counts(np.asarray(values, dtype=float), ch)
        counter = None
        if self.spec.has_counter:
            counter = idx % self.modulus if self.modulus else idx
        return t_ns, out, counter

    def skip(self, n: int) -> None:
        """Produce and drop ``n`` samples (a device that was away kept sampling; the noise stays in time)."""
        step = max(1, int(10 * self.spec.rate_hz))  # bounded memory over a long outage
        for i in range(0, n, step):
            self.block(min(step, n - i))


def model_fault_plan(dev: Any, info: DriverInfo, clock: Clock, seed: int, path: str = "<config>") -> FaultPlan | None:
    """The device's ``sim.faults`` for the model level; kinds it cannot simulate are refused
    (:class:`ConfigError` naming the config file ``path`` and the key)."""
    entries = dev.sim.get("faults") or []
    specs = parse_faults(entries, f"device {dev.name}.sim.faults")
    for i, spec in enumerate(specs):
        where = f"device {dev.name}.sim.faults[{i}].kind"
        if spec.kind not in MODEL_FAULTS:
            raise ConfigError(
                path,
                where,
                f"{spec.kind!r} is simulated at --sim-level bus only (the model level simulates "
                f"{', '.join(MODEL_FAULTS)})",
            )
        checksummed = dev.driver in CHECKSUMMED and info.settings.get("crc", True)
        if spec.kind == "checksum" and not checksummed:
            raise ConfigError(path, where, f"'checksum': driver {dev.driver!r} reads no checksum in this setting")
    return FaultPlan(specs, clock, seed) if specs else None  # the seed a bus-level plan gets


class ModelDevice:
    """A simulated device at the noise-model level, with the :class:`~imustation.drivers.base.Driver` calls.

    Parameters
    ----------
    dev : the device's config entry.
    info : what the device's driver reported when it opened the chip simulator.
    clock : the station's (virtual) clock.
    station_seed : the config's ``station.seed``.
    config_path : the config file, for error messages.

    Samples are made at exact output periods from the first :meth:`open`; a read
    returns those due by the clock and says when the newest was made (``Block.behind_ns``),
    so the station dates them on the device's sample grid.
    """

    name = "model"

    def __init__(self, dev: Any, info: DriverInfo, clock: Clock, station_seed: int, config_path: str = "<config>"):
        self.dev = dev
        # nothing overflows at this level: every loss is one the device reports
        self.info = replace(
            info,
            poll_interval_s=max(info.poll_interval_s, MODEL_POLL_S),
            overflow="reported",
            buffer_s=float("inf"),
        )
        self.clock = clock
        self.stream = ModelStream(info, dev, station_seed)
        self.plan = model_fault_plan(dev, info, clock, station_device_seed(station_seed, dev.name), config_path)
        self._origin_ns: int | None = None
        #: samples produced while the device was away, reported with the next block
        self._away = 0

    @property
    def produced(self) -> int:
        """Samples the device has produced so far (read, dropped or lost while away)."""
        return self.stream.n

    def _due(self) -> int:
        assert self._origin_ns is not None
        return self.stream.due(self.clock.now_ns() - self._origin_ns)

    def _check_present(self) -> None:
        # fire: a disconnect shorter than a poll interval still happened (its samples are gone)
        if self.plan is not None and (self.plan.active("disconnect") or self.plan.fire("disconnect")):
            raise DeviceError(f"{self.dev.name}: no answer (simulated disconnect, model level)")

    def open(self) -> DriverInfo:
        self._check_present()
        if self._origin_ns is None:
            self._origin_ns = self.clock.now_ns()
        else:
            away = max(0, self._due() - self.stream.n)  # produced while it was away
            self.stream.skip(away)
            self._away += away
        return self.info

    def read_block(self) -> Block:
        self._check_present()
        n = self._due() - self.stream.n
        if n <= 0:
            # losses go with samples: the station checks a counter against the previous block's
            return Block({})
        away, self._away = self._away, 0
        _, channels, counter = self.stream.block(n)
        assert self._origin_ns is not None
        behind = self.clock.now_ns() - self._origin_ns - self.stream.made_ns(self.stream.n - 1)
        bad = 0
        while n > 1 and self.plan is not None and self.plan.fire("checksum"):
            bad += 1
        if not bad and not away:
            return Block(channels, counter, behind_ns=behind)
        notes = ["samples lost while the device was away"] if away else []
        if bad:
            # the oldest samples of the block go: the rest keep their times (newest at the read)
            bad = min(bad, n - 1)
            channels = {name: values[bad:] for name, values in channels.items()}
            counter = counter[bad:] if counter is not None else None
            notes.append(f"bad checksum: {bad} sample(s) dropped")
        return Block(channels, counter, lost=away + bad, note="; ".join(notes), behind_ns=behind)

    def close(self) -> None:
        pass
