"""KVH DSP-3000 simulator: ASCII lines at 100 Hz, 38 400 baud (docs/reference/sensors.md §6).

Lines ``" <value with 6 decimals>   <flag>\\r\\n"`` in rate mode (deg/s, the
power-up default) or incremental-angle mode (deg per output), switched by the
single-character commands ``R``/``A``/``P`` (``P``, integrated angle, is
emitted modulo 360 deg; ``Z`` zeroes it) [KVH-R]. The z rate comes from the
signal source (Table IV key ``dsp3000``). The line rate is fixed at 38 400 baud:
a port opened at another rate reads garbage.

Faults: ``corrupt``/``checksum`` (one character of one line damaged - the
ASCII protocol has no checksum, so only non-numeric damage is detectable),
``short_read`` (5 bytes lost across a line end), ``reset`` (flag 0 for the
start-up time, then rate mode), ``disconnect`` (the port vanishes).

Quirk ``trailing_blanks`` (:mod:`.quirks`): every line carries blanks after the
status word, before CR LF.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imustation.clock import Clock
from imustation.drivers import kvh_dsp3000 as chip
from imustation.drivers.sim import filters
from imustation.drivers.sim.faults import FaultPlan
from imustation.drivers.sim.serial_device import SerialDeviceSim
from imustation.drivers.sim.sources import SignalSource, with_filter
from imustation.units import RAD2DEG

START_UP_S = 1.0  # flag-0 lines after power-on (duration UNCONFIRMED; simulation choice)
#: quirk ``trailing_blanks``: what follows the status word before CR LF
TRAILING_BLANKS = "  \t "
BAUD = 38400  # [KVH-M]


class DSP3000Sim(SerialDeviceSim):
    baud = BAUD

    def __init__(self, clock: Clock, source_factory: Callable[[float], SignalSource], plan: FaultPlan | None = None,
                 rate_hz: float = chip.NOMINAL_RATE_HZ, quirks: frozenset[str] = frozenset()):  # fmt: skip
        super().__init__(clock, plan)
        self.tail = TRAILING_BLANKS if "trailing_blanks" in quirks else ""
        self.rate_hz = float(rate_hz)
        self.source = with_filter(source_factory(self.rate_hz), filters.interval_mean("KVH DSP-3000", self.rate_hz))
        self.mode = "rate"
        self.integrated_deg = 0.0
        self.sim_resets = 0
        self.t_start_ns = clock.now_ns()
        self.emitted = 0
        # powered long before the station opens it: no start-up window
        self.fault_from_ns = self.fault_until_ns = self.t_start_ns

    def receive(self, data: bytes) -> None:
        self._lines()  # lines due so far keep the old mode
        for byte in data:
            c = chr(byte)
            if c == "R":
                self.mode = "rate"
            elif c == "A":
                self.mode = "incremental_angle"
            elif c == "P":
                self.mode = "integrated_angle"
            elif c == "Z":
                self.integrated_deg = 0.0

    def produce(self) -> bytes:
        if self.plan is not None and self.plan.fire("reset"):
            self.sim_resets += 1
            self.mode = "rate"
            # the reset happened when the plan scheduled it, maybe before this read
            self.fault_from_ns = max(t for t, kind in self.plan.sim_log if kind == "reset")
            self.fault_until_ns = self.fault_from_ns + int(START_UP_S * 1e9)
        return self._lines()

    def _lines(self) -> bytes:
        due = int((self.clock.now_ns() - self.t_start_ns) * self.rate_hz / 1e9)
        n = due - self.emitted
        if n <= 0:
            return b""
        t_ns = self.t_start_ns + (self.emitted + 1 + np.arange(n)) * 1e9 / self.rate_hz
        self.emitted = due
        rate_dps = self.source.next(n)[:, 0] * RAD2DEG
        if self.mode == "rate":
            values = rate_dps
        else:
            step = rate_dps / self.rate_hz
            if self.mode == "incremental_angle":
                values = step
            else:
                values = np.mod(self.integrated_deg + np.cumsum(step), 360.0)
                self.integrated_deg = float(values[-1])
        flags = np.where((t_ns >= self.fault_from_ns) & (t_ns < self.fault_until_ns), 0, 1)
        text = "".join(f" {v:13.6f}   {f}{self.tail}\r\n" for v, f in zip(values.tolist(), flags.tolist(), strict=True))
        data = text.encode("ascii")
        if self.plan is not None:
            if self.plan.fire("corrupt") or self.plan.fire("checksum"):
                at = data.find(b".", len(data) // 2) - 1  # the digit before a decimal point
                if at > 0:
                    data = data[:at] + b"q" + data[at + 1 :]
            if self.plan.fire("short_read"):
                cut = data.find(b"\r\n", len(data) // 2) - 2
                if cut > 0:
                    data = data[:cut] + data[cut + 5 :]
        return data
