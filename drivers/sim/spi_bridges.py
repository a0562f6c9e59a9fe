"""Simulated USB-to-SPI bridge chips (CP2130, MCP2210) for :class:`SimUSBBackend`.

Each decodes its bridge's framing exactly as the real bridge code produces it
(``drivers/bus/spi_cp2130.py``, ``drivers/bus/spi_mcp2210.py``) and routes the
SPI bytes of one chip-select transaction to an :class:`SPITarget` - a chip
simulator that answers full-duplex bytes as the chip does on the wire.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from imustation.drivers.bus import spi_cp2130 as cp
from imustation.drivers.bus import spi_mcp2210 as mcp
from imustation.drivers.sim.faults import FaultPlan
from imustation.drivers.sim.usb_backend import SimUSBFunction, usb_stall, usb_timeout

#: what MISO reads when no chip drives it (pulled up)
MISO_IDLE = 0xFF


class SPITarget(Protocol):
    def spi_transfer(self, tx: bytes, mode: int, hz: float) -> bytes:
        """One chip-select-asserted transaction: return the bytes clocked out on MISO."""
        ...


class EdgeCounter:
    """A bridge's 16-bit counter of the edges on its counter input pin.

    ``edges()`` is the wired chip's data-ready line: the edges it has made so far
    (each new sample one pulse, on the chip's clock); nothing wired counts nothing.
    The count is kept as an offset from that total, so counting costs nothing per edge.
    """

    def __init__(self) -> None:
        self.edges: Callable[[], int] = lambda: 0
        self.counting = False
        self._value = 0  # the count when not counting; the offset from edges() while counting

    def wire(self, edges: Callable[[], int]) -> None:
        count = self.count()
        self.edges = edges
        self.set(count)

    def count(self) -> int:
        """Edges counted, not wrapped."""
        return self._value + self.edges() if self.counting else self._value

    def set(self, count: int) -> None:
        self._value = count - self.edges() if self.counting else count

    def enable(self, counting: bool) -> None:
        count = self.count()
        self.counting = counting
        self.set(count)


def _corrupt(rx: bytes, plan: FaultPlan | None) -> bytes:
    """``corrupt`` fault: flip one bit of one byte read back (middle of the transfer)."""
    if plan is not None and len(rx) > 2 and plan.fire("corrupt"):
        b = bytearray(rx)
        b[len(b) // 2] ^= 0x10
        return bytes(b)
    return rx


class CP2130Sim(SimUSBFunction):
    """CP2130 with high-priority-write endpoints (bulk OUT 0x01 / IN 0x82) [CP-B]."""

    ENDPOINTS = ((0x01, 0x02), (0x82, 0x02))
    COUNTER_PIN = cp.CP2130.COUNTER_PIN

    def __init__(self, serial: str = "0001", plan: FaultPlan | None = None):
        super().__init__(cp.CP2130.DEFAULT_VID, cp.CP2130.DEFAULT_PID, serial, plan)
        self.targets: dict[int, SPITarget] = {}
        #: power-on SPI words (datasheet default not in docs/reference/sensors.md; 0 = mode 0, 12 MHz, open drain)
        self.spi_words = bytearray(cp.SPI_WORD_LEN)
        self.cs_enabled: set[int] = set()
        self._in = bytearray()
        #: the OTP ROM makes GPIO.4 the event counter input (a board prepared for the data-ready wire);
        #: False: GPIO.4 is a plain GPIO and Set_Event_Counter's mode does not take
        self.gpio4_counter_input = True
        self.evt_mode = 0
        self.evt = EdgeCounter()

    def attach(self, cs: int, target: SPITarget) -> None:
        self.targets[cs] = target

    def wire_counter(self, pin: str, edges: Callable[[], int]) -> None:
        """Connect a chip's data-ready line (``edges()``: the pulses it made so far) to ``pin``."""
        if pin != self.COUNTER_PIN:
            raise ValueError(f"the CP2130 counts edges on {self.COUNTER_PIN} only, not {pin!r}")
        self.evt.wire(edges)

    def control(self, request_type, request, value, index, data):
        if request_type == cp.REQTYPE_OUT and request == cp.REQ_SET_EVENT_COUNTER and len(data) == 3:
            _overflow, mode, count = cp.unpack_event_counter(data)
            if self.gpio4_counter_input:
                self.evt_mode = mode
            self.evt.enable(self.evt_mode in cp.EVTCNTR_COUNTING)
            self.evt.set(count)
            return 3
        if request_type == cp.REQTYPE_IN and request == cp.REQ_GET_EVENT_COUNTER:
            n = self.evt.count()
            flags = self.evt_mode | (cp.EVTCNTR_OVERFLOW if n > 0xFFFF else 0)
            return cp.EVENT_COUNTER.pack(flags, n & 0xFFFF)
        if request_type == cp.REQTYPE_OUT and request == cp.REQ_SET_SPI_WORD and len(data) == 2:
            self.spi_words[data[0]] = data[1]
            return 2
        if request_type == cp.REQTYPE_OUT and request == cp.REQ_SET_GPIO_CHIP_SELECT and len(data) == 2:
            ch, ctl = data
            if ctl == cp.CS_CTL_ENABLE_ONLY:
                self.cs_enabled = {ch}
            elif ctl == 1:
                self.cs_enabled.add(ch)
            else:
                self.cs_enabled.discard(ch)
            return 2
        if request_type == cp.REQTYPE_IN and request == cp.REQ_GET_SPI_WORD:
            return bytes(self.spi_words)
        raise usb_stall()

    def out(self, ep: int, data: bytes) -> int:
        if ep != self.ENDPOINTS[0][0] or len(data) < cp.HEADER.size:
            raise usb_stall()
        _zero, cmd, _res, n = cp.HEADER.unpack_from(data)
        payload = data[cp.HEADER.size :]
        if cmd != cp.CMD_WRITE_READ or len(payload) != n:
            raise usb_stall()  # only WriteRead in one packet is modelled
        self._in += _corrupt(self._spi(payload), self.plan)
        return len(data)

    def _spi(self, tx: bytes) -> bytes:
        if len(self.cs_enabled) != 1:
            return bytes([MISO_IDLE]) * len(tx)
        (cs,) = self.cs_enabled
        word = self.spi_words[cs]
        mode = (2 if word & cp.SPI_WORD_CPOL else 0) | (1 if word & cp.SPI_WORD_CPHA else 0)
        target = self.targets.get(cs)
        if target is None:
            return bytes([MISO_IDLE]) * len(tx)
        return target.spi_transfer(tx, mode, cp.CLOCKS_HZ[word & 0x07])

    def in_(self, ep: int, size: int) -> bytes:
        if not self._in:
            raise usb_timeout()
        out = bytes(self._in[:size])
        del self._in[:size]
        return out


class MCP2210Sim(SimUSBFunction):
    """MCP2210: HID, interrupt OUT 0x01 / IN 0x81, 64-byte reports [MCP-B].

    Power-on pin designations are all GPIO (the driver must designate its chip
    select); the kernel HID driver starts attached (the driver must detach it).
    """

    INTERFACE_CLASS = 0x03
    ENDPOINTS = ((0x01, 0x03), (0x81, 0x03))
    COUNTER_PIN = mcp.MCP2210.COUNTER_PIN

    def __init__(self, serial: str = "0001", plan: FaultPlan | None = None):
        super().__init__(mcp.MCP2210.DEFAULT_VID, mcp.MCP2210.DEFAULT_PID, serial, plan, kernel_driver=True)
        self.targets: dict[int, SPITarget] = {}
        self.chip_settings = bytearray(mcp.CHIP_SETTINGS_LEN)  # pins all GPIO
        self.bitrate, self.idle_cs, self.active_cs, self.tx_size, self.mode = 1_000_000, 0x1FF, 0x1FE, 4, 0
        self._acc = bytearray()  # bytes of the transaction in progress
        self._rx = bytearray()  # received bytes not yet handed to the host
        self._replies: list[bytes] = []
        self.interrupts = EdgeCounter()  # GP6's external interrupt event counter

    def attach(self, cs: int, target: SPITarget) -> None:
        self.targets[cs] = target

    def wire_counter(self, pin: str, edges: Callable[[], int]) -> None:
        """Connect a chip's data-ready line (``edges()``: the pulses it made so far) to ``pin``."""
        if pin != self.COUNTER_PIN:
            raise ValueError(f"the MCP2210 counts edges on {self.COUNTER_PIN} only, not {pin!r}")
        self.interrupts.wire(edges)

    def _interrupt_counting(self) -> bool:
        mode = self.chip_settings[mcp.OTHER_SETTINGS_AT] >> mcp.INT_MODE_SHIFT & 0x07
        return self.chip_settings[mcp.PIN_INTERRUPT] == mcp.PIN_DEDICATED and mode != mcp.INT_MODE_NONE

    def _reply(self, *head: int, data: bytes = b"") -> None:
        self._replies.append((bytes(head) + data).ljust(mcp.REPORT_LEN, b"\0"))

    def out(self, ep: int, data: bytes) -> int:
        if ep != self.ENDPOINTS[0][0] or len(data) != mcp.REPORT_LEN:
            raise usb_stall()
        cmd = data[0]
        if cmd == mcp.CMD_GET_CHIP_SETTINGS:
            self._reply(cmd, mcp.STATUS_OK, 0, 0, data=bytes(self.chip_settings))
        elif cmd == mcp.CMD_SET_CHIP_SETTINGS:
            at = mcp.CHIP_SETTINGS_AT
            self.chip_settings[:] = data[at : at + mcp.CHIP_SETTINGS_LEN]
            self.interrupts.enable(self._interrupt_counting())
            self._reply(cmd, mcp.STATUS_OK, 0, 0)
        elif cmd == mcp.CMD_GET_INTERRUPT_COUNT:
            n = self.interrupts.count() & 0xFFFF
            if data[1] == mcp.INT_COUNT_RESET:
                self.interrupts.set(0)
            self._reply(cmd, mcp.STATUS_OK, 0, 0, data=mcp.INT_COUNT.pack(n))
        elif cmd == mcp.CMD_SET_SPI_SETTINGS:
            if self._acc:
                self._reply(cmd, mcp.STATUS_IN_PROGRESS, 0, 0)
            else:
                fields = mcp.SPI_SETTINGS.unpack_from(data)
                self.bitrate, self.idle_cs, self.active_cs = fields[4], fields[5], fields[6]
                self.tx_size, self.mode = fields[10], fields[11]
                self._reply(cmd, mcp.STATUS_OK, 0, 0)
        elif cmd == mcp.CMD_CANCEL_SPI:
            self._acc.clear()
            self._rx.clear()
            self._reply(cmd, mcp.STATUS_OK, 0, 0)
        elif cmd == mcp.CMD_TRANSFER:
            self._transfer(data[4 : 4 + min(data[1], mcp.MAX_CHUNK)])
        else:
            self._reply(cmd, 0xF9, 0, 0)  # unknown command
        return len(data)

    def _transfer(self, chunk: bytes) -> None:
        if chunk:
            # data reports are acknowledged; what the chip sent back comes with the next reports
            for byte in chunk:
                self._acc.append(byte)
                if len(self._acc) == self.tx_size:
                    self._rx += _corrupt(self._spi(bytes(self._acc)), self.plan)
                    self._acc.clear()
            self._reply(mcp.CMD_TRANSFER, mcp.STATUS_OK, 0, mcp.ENGINE_STARTED)
            return
        out = bytes(self._rx[: mcp.MAX_CHUNK])
        del self._rx[: len(out)]
        done = not self._rx and not self._acc
        self._reply(
            mcp.CMD_TRANSFER, mcp.STATUS_OK, len(out), mcp.ENGINE_FINISHED if done else mcp.ENGINE_DATA, data=out
        )

    def _spi(self, tx: bytes) -> bytes:
        pins = self.chip_settings[: mcp.N_PINS]
        selected = [cs for cs in range(mcp.N_PINS) if pins[cs] == mcp.PIN_CHIP_SELECT and not self.active_cs >> cs & 1]
        if len(selected) != 1 or selected[0] not in self.targets:
            return bytes([MISO_IDLE]) * len(tx)
        return self.targets[selected[0]].spi_transfer(tx, self.mode, float(self.bitrate))

    def in_(self, ep: int, size: int) -> bytes:
        if not self._replies:
            raise usb_timeout()
        return self._replies.pop(0)[:size]
