"""Microchip MCP2210 USB-to-SPI bridge through pyusb (``mcp2210:`` URLs).

Protocol (``docs/reference/sensors.md`` §4.7, sources [MCP-B] bloguetronica/mcp2210
and [MCP-A] arachnidlabs/mcp2210): a USB HID device; each command is one 64-byte
report on the interrupt OUT endpoint, answered by one 64-byte report on
interrupt IN whose byte 0 echoes the command and byte 1 is a status. The kernel
HID driver is detached and the raw endpoints used (no report-ID byte).

An SPI transaction is ``bytes per transaction`` long (a setting): CS is asserted
at its first byte and released after its last, so a transfer of n bytes sets
that length (cached) and then sends 0x42 reports of <= 60 bytes, then empty ones
until the engine reports the transfer finished.
"""

from __future__ import annotations

import struct
from typing import ClassVar

from imustation.drivers.bus.spi import USBSPIBridge
from imustation.errors import BusError, BusTimeout, DeviceError, SettingError

REPORT_LEN = 64  # every command and reply is one 64-byte report [MCP-B] COMMAND_SIZE
ENDPOINT_TYPE_INTR = 0x03

# --- commands [MCP-B][MCP-A] --------------------------------------------------------
CMD_CANCEL_SPI = 0x11
CMD_GET_CHIP_SETTINGS = 0x20
CMD_SET_CHIP_SETTINGS = 0x21
CMD_SET_SPI_SETTINGS = 0x40
CMD_TRANSFER = 0x42
CMD_GET_INTERRUPT_COUNT = 0x12  # DS22288A §3.4.1: byte 1 0x00 reads then resets, else reads only
#: chip settings reply: byte 4.. = 9 pin designations, GPIO outputs u16, directions u16,
#: other settings u8, access control u8; the set command takes the same bytes + 8-byte password
CHIP_SETTINGS_AT = 4
CHIP_SETTINGS_LEN = 9 + 2 + 2 + 1 + 1
N_PINS = 9
PIN_CHIP_SELECT = 0x01
PIN_DEDICATED = 0x02  # GP6's dedicated function: the external interrupt (event counter) input
PIN_INTERRUPT = 6
#: chip settings byte 13 (report byte 17) "other settings": bits 3:1 interrupt counting mode
OTHER_SETTINGS_AT = 13
INT_MODE_SHIFT = 1
INT_MODE_MASK = 0x07 << INT_MODE_SHIFT
INT_MODE_NONE = 0b000
INT_MODE_FALLING_EDGES = 0b001
INT_MODE_RISING_EDGES = 0b010
INT_MODE_LOW_PULSES = 0b011
INT_MODE_HIGH_PULSES = 0b100
#: 0x12 byte 1
INT_COUNT_RESET = 0x00
INT_COUNT_KEEP = 0x01
#: 0x12 reply bytes 4-5: the count, u16 little-endian
INT_COUNT = struct.Struct("<H")
INT_COUNT_AT = 4
PASSWORD_LEN = 8

# --- statuses (reply byte 1) ----------------------------------------------------------
STATUS_OK = 0x00
STATUS_BUS_BUSY = 0xF7  # SPI bus not available (external master)
STATUS_IN_PROGRESS = 0xF8  # transfer in progress, data not accepted: send again
STATUS_TEXT = {
    0xF7: "SPI bus not available",
    0xF8: "transfer in progress",
    0xF9: "unknown command",
    0xFA: "EEPROM write failure",
    0xFB: "blocked (access control)",
    0xFC: "rejected",
    0xFD: "wrong password",
}
# --- transfer engine status (reply byte 3 of 0x42) ------------------------------------
ENGINE_FINISHED = 0x10
ENGINE_STARTED = 0x20
ENGINE_DATA = 0x30
MAX_CHUNK = 60  # data bytes per 0x42 report

#: 0x40 payload after the 4-byte header: bit rate u32, idle CS u16, active CS u16,
#: CS-to-data, last-data-to-CS, inter-byte delays u16 (100 us units), bytes per
#: transaction u16, SPI mode u8 - all little-endian (docs/reference/sensors.md §4.7)
SPI_SETTINGS = struct.Struct("<BBBBIHHHHHHB")
ALL_CS_IDLE_HIGH = (1 << N_PINS) - 1
#: 0x42 reports before a transfer is declared stuck (a 60-byte transfer needs ~3)
MAX_TRANSFER_REPORTS = 64
#: pause before re-sending data the engine did not accept (0xF8), s
BUSY_RETRY_S = 0.0005


def with_interrupt_counter(settings: bytes) -> bytes:
    """Chip settings (the 15 bytes from report byte 4) with GP6 on its dedicated function, counting rising edges."""
    out = bytearray(settings)
    out[PIN_INTERRUPT] = PIN_DEDICATED
    out[OTHER_SETTINGS_AT] = out[OTHER_SETTINGS_AT] & ~INT_MODE_MASK | INT_MODE_RISING_EDGES << INT_MODE_SHIFT
    return bytes(out)


def interrupt_count_command(reset: bool) -> bytes:
    """The 0x12 report (64 bytes) reading the interrupt event counter, resetting it after the read or not."""
    return bytes([CMD_GET_INTERRUPT_COUNT, INT_COUNT_RESET if reset else INT_COUNT_KEEP]).ljust(REPORT_LEN, b"\0")


def interrupt_count(reply: bytes) -> int:
    """The event count of a 0x12 reply."""
    return INT_COUNT.unpack_from(reply, INT_COUNT_AT)[0]


class MCP2210(USBSPIBridge):
    """MCP2210 bridge: chip select on GP0..GP8 (``cs=0..8``)."""

    NAME: ClassVar[str] = "MCP2210"
    SCHEME: ClassVar[str] = "mcp2210"
    DEFAULT_VID: ClassVar[int] = 0x04D8  # docs/reference/sensors.md §4.7 [MCP-B]
    DEFAULT_PID: ClassVar[int] = 0x00DE
    N_CS: ClassVar[int] = N_PINS
    COUNTER_PIN: ClassVar[str] = "gp6"

    def _command(self, payload: bytes, what: str) -> bytes:
        self._data_out(payload.ljust(REPORT_LEN, b"\0"))
        reply = self._data_in(REPORT_LEN)
        if len(reply) < 4 or reply[0] != payload[0]:
            raise DeviceError(
                f"{self.where}: {what}: reply {reply[:4].hex(' ')} does not echo command {payload[0]:02X}"
            )
        return reply

    def _check(self, reply: bytes, what: str) -> None:
        if reply[1] != STATUS_OK:
            text = STATUS_TEXT.get(reply[1], "unknown status")
            raise BusError(f"{self.where}: {what}: status 0x{reply[1]:02X} ({text})")

    def _setup(self) -> None:
        self.ep_out, self.ep_in = self._endpoints(ENDPOINT_TYPE_INTR)
        reply = self._command(bytes([CMD_GET_CHIP_SETTINGS, 0, 0, 0]), "get chip settings")
        self._check(reply, "get chip settings")
        settings = bytearray(reply[CHIP_SETTINGS_AT : CHIP_SETTINGS_AT + CHIP_SETTINGS_LEN])
        if settings[self.cs] != PIN_CHIP_SELECT:
            settings[self.cs] = PIN_CHIP_SELECT  # volatile: the NVRAM power-up settings stay
            cmd = bytes([CMD_SET_CHIP_SETTINGS, 0, 0, 0]) + bytes(settings) + bytes(PASSWORD_LEN)
            self._check(self._command(cmd, "set chip settings"), f"designate GP{self.cs} as chip select")
        self.hz = self.requested_hz  # the MCP2210 divides its clock; the rate it picks is not read back
        self._tx_size = -1

    def _start_counter(self) -> None:
        if self.cs == PIN_INTERRUPT:
            raise SettingError(f"{self.where}: GP6 is this chip's select: it cannot also count data-ready edges")
        reply = self._command(bytes([CMD_GET_CHIP_SETTINGS, 0, 0, 0]), "get chip settings")
        self._check(reply, "get chip settings")
        settings = reply[CHIP_SETTINGS_AT : CHIP_SETTINGS_AT + CHIP_SETTINGS_LEN]
        wanted = with_interrupt_counter(settings)
        if wanted != settings:
            cmd = bytes([CMD_SET_CHIP_SETTINGS, 0, 0, 0]) + wanted + bytes(PASSWORD_LEN)
            self._check(self._command(cmd, "set chip settings"), "make GP6 the interrupt counter input")
        reply = self._command(interrupt_count_command(reset=True), "get interrupt event count")
        self._check(reply, "get interrupt event count")

    def _read_counter(self) -> int:
        reply = self._command(interrupt_count_command(reset=False), "get interrupt event count")
        self._check(reply, "get interrupt event count")
        return interrupt_count(reply)

    def _spi_settings(self, n: int) -> None:
        active = ALL_CS_IDLE_HIGH & ~(1 << self.cs)
        cmd = SPI_SETTINGS.pack(
            CMD_SET_SPI_SETTINGS, 0, 0, 0, int(self.hz), ALL_CS_IDLE_HIGH, active, 0, 0, 0, n, self.mode
        )
        self._check(self._command(cmd, "set SPI settings"), "set SPI settings")
        self._tx_size = n

    def _transfer(self, tx: bytes) -> bytes:
        if not 1 <= len(tx) <= 0xFFFF:
            raise ValueError(f"MCP2210 transfer of {len(tx)} bytes: 1..65535 allowed")
        if self._tx_size != len(tx):
            self._spi_settings(len(tx))
        sent, rx = 0, bytearray()
        for _ in range(MAX_TRANSFER_REPORTS):
            chunk = tx[sent : sent + MAX_CHUNK]
            reply = self._command(bytes([CMD_TRANSFER, len(chunk), 0, 0]) + chunk, "SPI transfer")
            if reply[1] == STATUS_IN_PROGRESS:
                self._sleep(BUSY_RETRY_S)
                continue
            self._check(reply, "SPI transfer")
            sent += len(chunk)
            rx += reply[4 : 4 + reply[2]]
            if reply[3] == ENGINE_FINISHED and sent == len(tx):
                break
        else:
            raise BusTimeout(
                f"{self.where}: SPI transfer of {len(tx)} bytes not finished after {MAX_TRANSFER_REPORTS} reports"
            )
        if len(rx) != len(tx):
            raise BusError(f"{self.where}: SPI transfer of {len(tx)} bytes returned {len(rx)}")
        return bytes(rx)

    def _recover(self) -> None:
        # a transfer may be half done after a failed report: cancel it (best effort)
        try:
            self._command(bytes([CMD_CANCEL_SPI, 0, 0, 0]), "cancel")
        except Exception:  # noqa: BLE001 - the retry reports the real error
            pass
