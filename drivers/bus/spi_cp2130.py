"""Silicon Labs CP2130 USB-to-SPI bridge through pyusb (``cp2130:`` URLs).

Protocol (``docs/reference/sensors.md`` §4.7, sources [CP-B] bloguetronica/cp2130
and [CP-R] rust-driver-cp2130): configuration by vendor control transfers on
endpoint 0, SPI data by commands on the bulk endpoints - an 8-byte header
``00 00 cmd 00 len(u32 LE)`` followed by the data; for WriteRead the device
returns exactly ``len`` bytes on bulk IN. The bulk endpoint addresses depend on
the OTP transfer priority, so they are read from the interface descriptor.
"""

from __future__ import annotations

import struct
from typing import ClassVar

from imustation.drivers.bus.spi import USBSPIBridge
from imustation.errors import BusError, DeviceError

# --- control requests, docs/reference/sensors.md §4.7 [CP-B][CP-R] --------------------
REQTYPE_OUT = 0x40  # host-to-device | vendor | device
REQTYPE_IN = 0xC0  # device-to-host | vendor | device
REQ_GET_GPIO_CHIP_SELECT = 0x24
REQ_SET_GPIO_CHIP_SELECT = 0x25  # data [channel, ctl]
CS_CTL_ENABLE_ONLY = 0x02  # "enabled + others disabled"
REQ_GET_SPI_WORD = 0x30  # returns one SPI word per channel
REQ_SET_SPI_WORD = 0x31  # data [channel, word]
SPI_WORD_LEN = 11  # Get_SPI_Word returns 11 bytes, one per channel
SPI_WORD_CPHA = 0x20  # bit5
SPI_WORD_CPOL = 0x10  # bit4
SPI_WORD_PUSH_PULL = 0x08  # bit3: CS push-pull
#: SPI clock codes bits2:0 -> Hz
CLOCKS_HZ = (12e6, 6e6, 3e6, 1.5e6, 750e3, 375e3, 187.5e3, 93.75e3)

# --- GPIO.4 event counter, docs/reference/bridge-counters.md (AN792 Get/Set_Event_Counter) ----
REQ_GET_EVENT_COUNTER = 0x44  # IN, 3 bytes
REQ_SET_EVENT_COUNTER = 0x45  # OUT, 3 bytes
#: byte 0 mode/flags, bytes 1-2 count (u16 big-endian)
EVENT_COUNTER = struct.Struct(">BH")
EVTCNTR_OVERFLOW = 0x80  # byte 0 bit 7: the count passed 0xFFFF
EVTCNTR_MODE_MASK = 0x07  # byte 0 bits 2:0: GPIO.4 pin mode
EVTCNTR_RISING_EDGE = 0x04
EVTCNTR_FALLING_EDGE = 0x05
EVTCNTR_NEGATIVE_PULSE = 0x06
EVTCNTR_POSITIVE_PULSE = 0x07
#: the pin modes in which GPIO.4 counts
EVTCNTR_COUNTING = frozenset(range(EVTCNTR_RISING_EDGE, EVTCNTR_POSITIVE_PULSE + 1))

# --- bulk commands ----------------------------------------------------------------
CMD_WRITE_READ = 0x02  # full duplex
HEADER = struct.Struct("<HBBI")  # 00 00 | cmd | 00 | length (u32 LE)
#: data bytes per WriteRead so header + data fit one 64-byte full-speed packet [CP-B]
MAX_WRITEREAD_BYTES = 56
ENDPOINT_TYPE_BULK = 0x02


def spi_word(mode: int, clock_code: int) -> int:
    """SPI word of Set_SPI_Word: CPOL/CPHA from the mode, push-pull CS, clock code."""
    cpol, cpha = mode >> 1 & 1, mode & 1
    return (SPI_WORD_CPHA if cpha else 0) | (SPI_WORD_CPOL if cpol else 0) | SPI_WORD_PUSH_PULL | clock_code


def pack_event_counter(mode: int, count: int) -> bytes:
    """Data stage of Set_Event_Counter: GPIO.4 mode and the count to start from."""
    return EVENT_COUNTER.pack(mode & EVTCNTR_MODE_MASK, count & 0xFFFF)


def unpack_event_counter(data: bytes) -> tuple[bool, int, int]:
    """Data stage of Get_Event_Counter -> (overflowed, GPIO.4 mode, count)."""
    flags, count = EVENT_COUNTER.unpack(bytes(data))
    return bool(flags & EVTCNTR_OVERFLOW), flags & EVTCNTR_MODE_MASK, count


def clock_code(hz: float) -> int:
    """Fastest CP2130 clock not above ``hz``."""
    for code, f in enumerate(CLOCKS_HZ):
        if f <= hz:
            return code
    raise ValueError(f"SPI clock {hz:g} Hz below the CP2130 minimum {CLOCKS_HZ[-1]:g} Hz")


class CP2130(USBSPIBridge):
    """CP2130 bridge: one chip select of 11 (``cs=0..10``)."""

    NAME: ClassVar[str] = "CP2130"
    SCHEME: ClassVar[str] = "cp2130"
    DEFAULT_VID: ClassVar[int] = 0x10C4  # docs/reference/sensors.md §4.7 [CP-B][CP-R]
    DEFAULT_PID: ClassVar[int] = 0x87A0
    N_CS: ClassVar[int] = 11
    COUNTER_PIN: ClassVar[str] = "gpio4"

    def _setup(self) -> None:
        try:
            code = clock_code(self.requested_hz)
        except ValueError as exc:
            raise BusError(f"{self.where}: {exc}") from None
        self.hz = CLOCKS_HZ[code]
        self.ep_out, self.ep_in = self._endpoints(ENDPOINT_TYPE_BULK)
        word = spi_word(self.mode, code)
        t = self.timeout_ms
        self.dev.ctrl_transfer(REQTYPE_OUT, REQ_SET_SPI_WORD, 0, 0, bytes([self.cs, word]), t)
        self.dev.ctrl_transfer(REQTYPE_OUT, REQ_SET_GPIO_CHIP_SELECT, 0, 0, bytes([self.cs, CS_CTL_ENABLE_ONLY]), t)
        back = bytes(self.dev.ctrl_transfer(REQTYPE_IN, REQ_GET_SPI_WORD, 0, 0, SPI_WORD_LEN, t))
        if len(back) != SPI_WORD_LEN or back[self.cs] != word:
            raise DeviceError(
                f"{self.where}: SPI word of channel {self.cs} reads back {back.hex(' ')}, wrote {word:02X}"
            )

    def _transfer(self, tx: bytes) -> bytes:
        if len(tx) > MAX_WRITEREAD_BYTES:
            raise ValueError(f"CP2130 WriteRead of {len(tx)} bytes: at most {MAX_WRITEREAD_BYTES} per transfer")
        self._data_out(HEADER.pack(0, CMD_WRITE_READ, 0, len(tx)) + tx)
        rx = self._data_in(len(tx))
        if len(rx) != len(tx):
            raise BusError(f"{self.where}: WriteRead of {len(tx)} bytes returned {len(rx)}")
        return rx

    def _start_counter(self) -> None:
        t = self.timeout_ms
        self.dev.ctrl_transfer(REQTYPE_OUT, REQ_SET_EVENT_COUNTER, 0, 0, pack_event_counter(EVTCNTR_RISING_EDGE, 0), t)
        back = bytes(self.dev.ctrl_transfer(REQTYPE_IN, REQ_GET_EVENT_COUNTER, 0, 0, EVENT_COUNTER.size, t))
        if len(back) != EVENT_COUNTER.size:
            raise BusError(f"{self.where}: Get_Event_Counter returned {len(back)} bytes, not {EVENT_COUNTER.size}")
        _overflow, mode, _count = unpack_event_counter(back)
        if mode != EVTCNTR_RISING_EDGE:
            raise DeviceError(
                f"{self.where}: GPIO.4 reads back event counter mode {mode} after setting {EVTCNTR_RISING_EDGE} "
                "(rising edges): its OTP pin configuration does not make it the event counter input"
            )

    def _read_counter(self) -> int:
        t = self.timeout_ms
        back = bytes(self.dev.ctrl_transfer(REQTYPE_IN, REQ_GET_EVENT_COUNTER, 0, 0, EVENT_COUNTER.size, t))
        if len(back) != EVENT_COUNTER.size:
            raise BusError(f"{self.where}: Get_Event_Counter returned {len(back)} bytes, not {EVENT_COUNTER.size}")
        return unpack_event_counter(back)[2]
