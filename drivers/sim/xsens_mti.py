"""Xsens MTi-100 simulator: an Xbus byte stream on the station clock (docs/reference/sensors.md §5).

The device powers up in measurement mode with a default output configuration
(PacketCounter, SampleTimeFine, Acceleration and RateOfTurn at 100 Hz - the
real factory setting is not in docs/reference/sensors.md, this is a simulation choice), and
streams MTData2 while answering GoToConfig, ReqDID, ReqProductCode, ReqFWRev,
SetOutputConfiguration (config mode only) and GoToMeasurement with their
acknowledgements, and anything else with Error 4. Every item is sent in every
packet at the highest configured frequency (items at lower rates are not
thinned: a simplification). Packets are built with numpy a batch at a time.

Rate of turn comes from the signal source (Table IV key ``mti``); acceleration
is gravity on +z plus white noise; temperature is the source's.

Faults: ``checksum`` (one packet with a wrong checksum), ``corrupt`` (garbage
bytes between two packets), ``short_read`` (bytes of one packet lost on the
line), ``reset`` (WakeUp, back to the power-up configuration),
``disconnect`` (the port vanishes, see the pyserial handler).

Xbus states, strictly (docs/reference/conformance-mti.md): the identity requests
and SetOutputConfiguration are answered only in config state (Error 4 in
measurement state: the stricter reading of a source that does not say); after a
reset (the fault, or a Reset message, acknowledged) the device sends WakeUp and
waits ``WAKEUP_ACK_WINDOW_S`` for WakeUpAck, which keeps it in config state;
without it, it starts measuring with the power-up configuration.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

import numpy as np

from imustation.clock import Clock
from imustation.drivers import xsens_mti as xb
from imustation.drivers.sim import filters
from imustation.drivers.sim.faults import FaultPlan
from imustation.drivers.sim.serial_device import SerialDeviceSim
from imustation.drivers.sim.sources import SignalSource, fits, with_filter
from imustation.units import G0

POWER_ON_CONFIG = (
    (xb.ID_PACKET_COUNTER, xb.FREQ_EVERY_PACKET),
    (xb.ID_SAMPLE_TIME_FINE, xb.FREQ_EVERY_PACKET),
    (xb.ID_ACCELERATION, 100),
    (xb.ID_RATE_OF_TURN, 100),
)
DEVICE_ID = 0x03600123  # an MTi-100-style device ID (simulation choice)
PRODUCT_CODE = b"MTi-100-2A8G4"
FIRMWARE = bytes([1, 8, 2])
ACCEL_NOISE = 0.01  # white accel noise per sample, m/s^2 (simulation choice)
ERR_INVALID_MESSAGE = 4
ERR_INVALID_PARAMETER = 33
GARBAGE = bytes([0xFA, 0xFF, 0x36, 0x13, 0x00, 0xFA, 0x42])  # looks like a frame start, is not
#: how long a device that sent WakeUp waits for WakeUpAck before measuring (UNCONFIRMED)
WAKEUP_ACK_WINDOW_S = 0.5
#: requests the simulated device answers only in config state
CONFIG_ONLY = frozenset({xb.MID_REQ_DID, xb.MID_REQ_PRODUCT_CODE, xb.MID_REQ_FW_REV, xb.MID_SET_OUTPUT_CONFIG})


class MTiSim(SerialDeviceSim):
    """MTi-100 at the far end of a simulated serial line."""

    def __init__(self, clock: Clock, source_factory: Callable[[float], SignalSource], plan: FaultPlan | None = None,
                 seed: int = 0):  # fmt: skip
        super().__init__(clock, plan)
        self.source_factory = source_factory
        self.rng = np.random.default_rng([seed, 0x3715])
        self.source: SignalSource | None = None
        self.sim_resets = 0
        self._rx = b""
        self._out = bytearray()
        self._counter = 0
        #: station-clock time until which the device waits for WakeUpAck (None: not waiting)
        self.wakeup_until_ns: int | None = None
        self._power_on()

    def _power_on(self) -> None:
        self.config = POWER_ON_CONFIG
        self.measuring = True
        self._start()

    def _reset(self) -> None:
        """A reset: WakeUp, then wait for WakeUpAck before measuring with the power-up configuration."""
        self.sim_resets += 1
        self._power_on()
        self.measuring = False
        self.wakeup_until_ns = self.clock.now_ns() + int(WAKEUP_ACK_WINDOW_S * 1e9)
        self._send(xb.MID_WAKEUP)

    def _wakeup_window(self) -> None:
        """Without WakeUpAck in time the device starts measuring (from the end of the window)."""
        if self.wakeup_until_ns is not None and self.clock.now_ns() >= self.wakeup_until_ns:
            self.measuring = True
            self._start()
            self.t_start_ns = self.wakeup_until_ns
            self.wakeup_until_ns = None

    def _start(self) -> None:
        self.t_start_ns = self.clock.now_ns()
        self.emitted = 0
        fs = self.rate_hz
        out_filter = filters.interval_mean("Xsens MTi", fs)
        if not fits(self.source, fs, out_filter):
            self.source = with_filter(self.source_factory(fs), out_filter)

    @property
    def rate_hz(self) -> float:
        rates = [f for _, f in self.config if f != xb.FREQ_EVERY_PACKET]
        return float(max(rates) if rates else 100)

    # -- host -> device ----------------------------------------------------------------
    def _send(self, mid: int, payload: bytes = b"") -> None:
        self._out += xb.encode(mid, payload)

    def receive(self, data: bytes) -> None:
        self._emit()  # packets due so far go out before any reply
        messages, used, _g, _b = xb.parse_stream(self._rx + data)
        self._rx = (self._rx + data)[used:]
        for m in messages:
            self._handle(m)

    def _handle(self, m: xb.Message) -> None:
        ack = m.mid + 1
        if m.mid == xb.MID_WAKEUP_ACK:
            if self.wakeup_until_ns is not None:
                self.wakeup_until_ns = None  # stays in config state
            return  # an acknowledgement is never answered
        if m.mid in CONFIG_ONLY and self.measuring:
            self._send(xb.MID_ERROR, bytes([ERR_INVALID_MESSAGE]))
        elif m.mid == xb.MID_RESET:
            self._send(ack)
            self._reset()
        elif m.mid == xb.MID_GOTO_CONFIG:
            self.measuring = False
            self.wakeup_until_ns = None
            self._send(ack)
        elif m.mid == xb.MID_GOTO_MEASUREMENT:
            self.measuring = True
            self._start()
            self._send(ack)
        elif m.mid == xb.MID_REQ_DID:
            self._send(ack, struct.pack(">I", DEVICE_ID))
        elif m.mid == xb.MID_REQ_PRODUCT_CODE:
            self._send(ack, PRODUCT_CODE)
        elif m.mid == xb.MID_REQ_FW_REV:
            self._send(ack, FIRMWARE)
        elif m.mid == xb.MID_SET_OUTPUT_CONFIG and not self.measuring:
            pairs = [struct.unpack_from(">HH", m.payload, i) for i in range(0, len(m.payload) - 3, 4)]
            ok = bool(pairs) and len(m.payload) % 4 == 0
            for data_id, freq in pairs:
                known = data_id in xb.ITEMS
                ok &= known and (
                    freq == xb.FREQ_EVERY_PACKET or (0 < freq <= xb.BASE_RATE_HZ and xb.BASE_RATE_HZ % freq == 0)
                )
            if ok:
                self.config = tuple(pairs)
                self._send(ack, m.payload)
            else:
                self._send(xb.MID_ERROR, bytes([ERR_INVALID_PARAMETER]))
        else:
            self._send(xb.MID_ERROR, bytes([ERR_INVALID_MESSAGE]))

    # -- device -> host ----------------------------------------------------------------------
    def produce(self) -> bytes:
        if self.plan is not None and self.plan.fire("reset"):
            self._reset()
        self._emit()
        out = bytes(self._out)
        self._out.clear()
        return out

    def _emit(self) -> None:
        self._wakeup_window()
        if not self.measuring:
            return
        due = int((self.clock.now_ns() - self.t_start_ns) * self.rate_hz / 1e9)
        n = due - self.emitted
        if n > 0:
            self._out += self._packets(n)
            self.emitted = due

    def _packets(self, n: int) -> bytes:
        """``n`` MTData2 messages of the current configuration, as bytes."""
        assert self.source is not None
        ids = [i for i, _ in self.config]
        payload_len = sum(3 + xb.ITEMS[i].size for i in ids)
        head = 4 if payload_len <= xb.MAX_SHORT_LEN else 6
        L = head + payload_len + 1
        rows = np.zeros((n, L), dtype=np.uint8)
        header = xb.encode(xb.MID_MTDATA2, bytes(payload_len))[:head]
        rows[:, :head] = np.frombuffer(header, np.uint8)
        k = self.emitted + np.arange(n)
        t = k / self.rate_hz
        at = head
        for data_id in ids:
            item = xb.ITEMS[data_id]
            rows[:, at : at + 3] = (data_id >> 8, data_id & 0xFF, item.size)
            at += 3
            if data_id == xb.ID_PACKET_COUNTER:
                values = ((self._counter + np.arange(n)) & 0xFFFF).astype(item.fmt)
            elif data_id == xb.ID_SAMPLE_TIME_FINE:
                values = (np.rint(t / xb.SAMPLE_TIME_FINE_TICK_S).astype(np.int64) & 0xFFFFFFFF).astype(item.fmt)
            elif data_id == xb.ID_TEMPERATURE:
                values = np.full(n, self.source.temperature(float(t[n // 2])), dtype=item.fmt)
            elif data_id == xb.ID_ACCELERATION:
                values = (np.array([0.0, 0.0, G0]) + self.rng.normal(0.0, ACCEL_NOISE, (n, 3))).astype(item.fmt)
            elif data_id == xb.ID_RATE_OF_TURN:
                values = self.source.next(n).astype(item.fmt)
            else:  # StatusWord: all clear
                values = np.zeros(n, dtype=item.fmt)
            rows[:, at : at + item.size] = np.ascontiguousarray(values).view(np.uint8).reshape(n, item.size)
            at += item.size
        self._counter = (self._counter + n) & 0xFFFF
        rows[:, -1] = (-rows[:, 1:-1].sum(axis=1, dtype=np.int64)) & 0xFF
        if self.plan is not None:
            if self.plan.fire("checksum"):
                rows[n // 2, -1] ^= 0x01
            data = rows.tobytes()
            if self.plan.fire("corrupt"):
                cut = (n // 2) * L
                data = data[:cut] + GARBAGE + data[cut:]
            if self.plan.fire("short_read"):
                cut = (n // 2) * L + L // 2
                data = data[:cut] + data[cut + 5 :]
            return data
        return rows.tobytes()
