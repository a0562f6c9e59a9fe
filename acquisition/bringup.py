"""The bring-up check before a night (``capture --check 30s``): a short capture judged GO or NO-GO.

The check records every device and thermometer for a short while exactly as a
capture does (into a temporary run file, removed afterwards), then reads the
file back and judges, per device:

* the rate reached against the configured one (within :data:`RATE_TOLERANCE`),
* the samples lost (any loss is a NO-GO: a quiet rig loses none in 30 s),
* the gravity magnitude on each accelerometer (within :data:`GRAVITY_TOLERANCE_G`
  of 1 g: the rig must stand still; a wrong range or a dead axis shows here),
* each gyro axis's mean (its bias, the rig still) against the configured range
  (at most :data:`BIAS_RANGE_FRACTION` of full scale) and that the output moves
  at all (a constant output is a stuck or disconnected sensor),
* the device's and each thermometer's temperature (within :data:`TEMPERATURE_C`).

Every reading comes with its figure, so the operator sees how close each one is.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imustation.acquisition.capture import capture
from imustation.acquisition.config import StationConfig
from imustation.runfile import open_run
from imustation.runfile.holes import check_run, check_thermometers

#: the rate reached may differ from the configured one by this fraction (crystal tolerances are < 1 %)
RATE_TOLERANCE = 0.02
#: |mean acceleration| must lie within this of 1 g (turn-on offsets of MEMS parts are < 0.1 g per axis)
GRAVITY_TOLERANCE_G = 0.1
#: a gyro axis's mean may take at most this fraction of its full scale
BIAS_RANGE_FRACTION = 0.05
#: plausible temperatures of a lab rig (the parts' operating range is -40 .. 85 degC)
TEMPERATURE_C = (-20.0, 85.0)
#: standard gravity, m/s^2
G0 = 9.80665


@dataclass
class Reading:
    """One judged figure: what, its value as text, and whether it passes."""

    what: str
    value: str
    ok: bool
    why: str = ""


@dataclass
class DeviceCheck:
    name: str
    readings: list[Reading] = field(default_factory=list)

    @property
    def go(self) -> bool:
        return all(r.ok for r in self.readings)


@dataclass
class CheckReport:
    duration_s: float
    devices: list[DeviceCheck]

    @property
    def go(self) -> bool:
        return all(d.go for d in self.devices)

    def lines(self) -> list[str]:
        out = []
        for dev in self.devices:
            out.append(f"{dev.name}: {'ok' if dev.go else 'NO-GO'}")
            for r in dev.readings:
                mark = "ok  " if r.ok else "FAIL"
                out.append(f"  {mark} {r.what:<16} {r.value}" + (f"  ({r.why})" if r.why and not r.ok else ""))
        failed = [d.name for d in self.devices if not d.go]
        out.append("GO" if not failed else f"NO-GO: {', '.join(failed)}")
        return out


def run_check(config: StationConfig, duration_s: float, *, simulate: bool, **capture_options: Any) -> CheckReport:
    """Capture ``config`` for ``duration_s`` s into a temporary file and judge it (``capture_options``: as
    :func:`~imustation.acquisition.capture.capture` takes them)."""
    with tempfile.TemporaryDirectory(prefix="imustation-check-") as tmp:
        path = os.path.join(tmp, "check.h5")
        capture(config, path, duration_s, simulate=simulate, **capture_options)
        report = judge(path)
    order = {n: k for k, n in enumerate([d.name for d in config.devices] + [t.name for t in config.thermometers])}
    report.devices.sort(key=lambda d: order.get(d.name, len(order)))
    return report


def judge(path: str) -> CheckReport:
    """The GO / NO-GO report of the run file at ``path`` (see the module docstring)."""
    with open_run(path) as run:
        holes = check_run(run)
        thermo_holes = check_thermometers(run)
        events = run.events()
        duration = 0.0
        checks = []
        for name, info in run.devices.items():
            dev = DeviceCheck(name)
            checks.append(dev)
            n = info.n
            if n < 2:
                dev.readings.append(Reading("samples", str(n), False, "the device delivered no data"))
                continue
            t = run.read(name, "t")
            span = (int(t[-1]) - int(t[0])) * 1e-9
            duration = max(duration, span)
            rate = (n - 1) / span if span > 0 else 0.0
            dev.readings.append(_rate(rate, info.rate_hz))
            lost = sum(e.lost for e in events if e.source == name and e.kind in ("gap", "overrun"))
            lost = max(lost, holes[name].holes.samples)
            faults = sum(1 for e in events if e.source == name and e.kind == "fault")
            losses = f"{lost} samples lost, {faults} faults"
            dev.readings.append(Reading("losses", losses, lost == 0 and faults == 0, "a quiet rig loses none"))
            for cname, ch in info.channels.items():
                if ch.units not in ("m/s^2", "rad/s", "degC"):
                    continue
                values = run.read(name, cname).astype(np.float64) * ch.scale + ch.offset
                if ch.units == "m/s^2":
                    dev.readings.append(_gravity(values))
                elif ch.units == "rad/s":
                    dev.readings += _gyro(values, ch.axes, info.settings.get("gyro_range_dps"))
                else:
                    dev.readings.append(_temperature("temperature", float(np.mean(values))))
        for name in run.thermometers:
            dev = DeviceCheck(name)
            checks.append(dev)
            _, celsius = run.temperatures(name)
            check = thermo_holes.get(name)
            missed = check.holes.samples if check is not None else 0
            if not len(celsius):
                dev.readings.append(Reading("readings", "0", False, "the thermometer gave no reading"))
                continue
            dev.readings.append(Reading("readings", f"{len(celsius)}, {missed} missed", missed == 0, "polls missed"))
            dev.readings.append(_temperature("temperature", float(np.mean(celsius))))
    return CheckReport(duration, checks)


def _rate(rate: float, configured: float) -> Reading:
    off = rate / configured - 1.0
    return Reading(
        "rate",
        f"{rate:.2f} Hz of {configured:g} ({off:+.2%})",
        abs(off) <= RATE_TOLERANCE,
        f"more than {RATE_TOLERANCE:.0%} off: the bus is too slow or the device runs at another rate",
    )


def _gravity(accel: np.ndarray) -> Reading:
    mean = accel.mean(axis=0) / G0
    g = float(np.linalg.norm(mean))
    axes = " ".join(f"{v:+.3f}" for v in np.atleast_1d(mean))
    return Reading(
        "gravity",
        f"{g:.3f} g (mean {axes} g)",
        abs(g - 1.0) <= GRAVITY_TOLERANCE_G,
        f"not within {GRAVITY_TOLERANCE_G} g of 1 g: the rig moves, an axis is dead, or the range/scale is wrong",
    )


def _gyro(rate: np.ndarray, axes: tuple[str, ...], range_dps: Any) -> list[Reading]:
    deg = np.degrees(rate.reshape(len(rate), -1))
    bias = deg.mean(axis=0)
    moving = deg.std(axis=0) > 0
    out = []
    for k, axis in enumerate(axes):
        if not moving[k]:
            out.append(Reading(f"gyro {axis}", f"constant at {bias[k]:+.4f} deg/s", False, "stuck or disconnected"))
            continue
        if isinstance(range_dps, (int, float)) and range_dps > 0:
            share = abs(bias[k]) / range_dps
            out.append(
                Reading(
                    f"gyro {axis} bias",
                    f"{bias[k]:+.4f} deg/s ({share:.2%} of +-{range_dps:g} deg/s)",
                    share <= BIAS_RANGE_FRACTION,
                    f"over {BIAS_RANGE_FRACTION:.0%} of full scale: the rig turns, or the part is damaged",
                )
            )
        else:
            out.append(Reading(f"gyro {axis} bias", f"{bias[k]:+.4f} deg/s (range not configurable)", True))
    return out


def _temperature(what: str, celsius: float) -> Reading:
    lo, hi = TEMPERATURE_C
    return Reading(what, f"{celsius:.1f} degC", lo <= celsius <= hi, f"outside {lo:g} .. {hi:g} degC")
