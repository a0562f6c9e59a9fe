"""Analog Devices ADIS16448 10-DoF IMU on SPI (through a USB bridge).

Register map, framing, scales and worked examples: ``docs/reference/sensors.md`` §4
(sources there: Linux ``adis16400.c``/``adis.c`` [L-ADIS][L-ADISLIB], PX4
ADIS16448 drivers [PX4-ADIS][PX4-ADIS-OLD], juchong's Arduino library [JC]).

SPI mode 3, 16-bit frames, CS high for a stall time between frames (also
between two register sequences: the driver does not count on the bridge's USB
turnaround for it); a register read returns its data on the *next* frame. Streaming uses the burst read
(``3E 00`` then 12 words, plus a CRC-16 word when MSC_CTRL bit 4 is set). The
chip has no FIFO: each burst gives the newest sample, so the station polls once
per output period; a burst identical to the previous one is the same sample
read twice and is not stored.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from imustation.channels import ChannelSpec, DriverInfo
from imustation.drivers.base import Block, Setting, Sleep, check_settings
from imustation.drivers.bus.spi import SPIDevice
from imustation.errors import BusError, ChipIdMismatch, DeviceError, SettingError
from imustation.units import DEG2RAD, G0

# --- registers (docs/reference/sensors.md §4.2); 16-bit, even addresses, low byte at the even one ---
REG_XGYRO_OUT = 0x04
REG_SMPL_PRD = 0x36  # bits12:8 D (rate 819.2/2^D), bit0 internal clock, §4.3
REG_SENS_AVG = 0x38  # bits10:8 gyro range code, bits2:0 FIR taps 2^B, §4.3
REG_MSC_CTRL = 0x34  # bit4 CRC in burst, bit2 DR enable, bit1 DR active high, §4.3
REG_DIAG_STAT = 0x3C  # §4.5
REG_GLOB_CMD = 0x3E  # bit7 software reset; reading it = burst command, §4.3/§4.6
REG_LOT_ID1 = 0x52
REG_LOT_ID2 = 0x54
REG_PROD_ID = 0x56
PROD_ID_VALUE = 0x4040  # = 16448, §4.2 [PX4-ADIS][L-ADIS]
REG_SERIAL_NUM = 0x58

READ_MASK = 0x7F  # read command = [addr & 0x7F, 0x00], §4.1 [L-ADISLIB] ADIS_READ_REG
WRITE_FLAG = 0x80  # write command = [0x80 | addr, byte], §4.1 [L-ADISLIB] ADIS_WRITE_REG
SMPL_PRD_INTERNAL_CLOCK = 0x0001  # §4.3 [L-ADIS]: set writes (D << 8) | 1
SMPL_PRD_D_SHIFT = 8
SENS_AVG_RANGE_SHIFT = 8
MSC_CTRL_CRC = 1 << 4
MSC_CTRL_DR_ENABLE = 1 << 2
MSC_CTRL_DR_ACTIVE_HIGH = 1 << 1
MSC_CTRL_DR_LINE_DIO2 = 1 << 0  # data ready on DIO2; clear: on DIO1, §4.3
GLOB_CMD_SOFTWARE_RESET = 0x80  # low byte only, as Linux writes it (§4.1)

# --- timing -------------------------------------------------------------------------
INTERNAL_RATE_HZ = 819.2  # §4.3 [L-ADIS][PX4-ADIS]
RESET_RECOVERY_S = 0.090  # §4.1 [L-ADIS] adis16448_timeouts
#: CS-high stall between 16-bit frames: 9 us [PX4-ADIS] SPI_STALL_PERIOD (Linux uses 50 us)
STALL_US_DEFAULT = 9
SPI_MODE = 3  # CPOL=1, CPHA=1, §4.1
SPI_MAX_HZ_REGISTER = 2_000_000  # §4.1 [PX4-ADIS] SPI_SPEED
SPI_MAX_HZ_BURST = 1_000_000  # §4.1 [PX4-ADIS] SPI_SPEED_BURST

# --- burst (docs/reference/sensors.md §4.6) -----------------------------------------------
BURST_CMD = bytes([REG_GLOB_CMD, 0x00])
BURST_WORDS = 12  # DIAG_STAT, X/Y/Z GYRO, X/Y/Z ACCL, X/Y/Z MAGN, BARO, TEMP
BURST = struct.Struct(">H3h3h3hHH")  # diag, gyro, accel, mag, baro (unsigned, §4.4), temp (12-bit)
CRC_WORD = struct.Struct(">H")
#: check the configuration registers every this many polls (~1 s): a chip reset is caught
CONFIG_CHECK_S = 1.0
#: bursts held and decoded together, s of samples: the chip has no FIFO, so the station
#: polls once per sample, and decoding (and handing over) one sample at a time costs more
#: than the USB transfer itself; 50 ms is far inside the run file's flush interval
BATCH_S = 0.05

#: ``data_ready`` values: the bridge pins that count edges (docs/reference/bridge-counters.md), or none
DATA_READY_PINS = ("none", "gpio4", "gp6")
CHECKSUM_NOTE = "checksum: burst CRC mismatch, sample dropped"

# --- scales (docs/reference/sensors.md §4.4) ------------------------------------------------
ACCEL_G_PER_LSB = 1.0 / 1200.0  # [L-ADIS][PX4-ADIS][JC]
MAG_GAUSS_PER_LSB = 1.0 / 7000.0  # 142.9 ugauss [PX4-ADIS][JC]
GAUSS_TO_TESLA = 1e-4
BARO_MBAR_PER_LSB = 0.02  # [JC][PX4-ADIS][L-ADIS]
MBAR_TO_PA = 100.0
TEMP_C_PER_LSB = 0.07386  # [L-ADIS][PX4-ADIS][JC]
TEMP_OFFSET_C = 31.0  # 0x000 = 31 degC
TEMP_BITS = 12


@dataclass(frozen=True)
class GyroRange:
    code: int
    range_dps: int
    dps_per_lsb: float
    #: the smallest SENS_AVG filter B (2^B taps) the range may be used with
    min_filter_b: int = 0

    @property
    def min_taps(self) -> int:
        return 2**self.min_filter_b


#: SENS_AVG bits10:8, §4.3 [PX4-ADIS-OLD]: scale = code / 100 deg/s per LSB. The reduced ranges
#: need a minimum filter: +-500 deg/s B >= 2 (4 taps), +-250 deg/s B >= 4 (16 taps) - the SENS_AVG
#: bit table of the ADIS1640x/ADIS16448 data sheets ("filter taps >= 4 / >= 16");
#: docs/reference/conformance-adis16448.md
GYRO_RANGES: tuple[GyroRange, ...] = (
    GyroRange(1, 250, 0.01, min_filter_b=4),
    GyroRange(2, 500, 0.02, min_filter_b=2),
    GyroRange(4, 1000, 0.04),
)

#: DIAG_STAT bits, ADIS16448-specific table of §4.5 [PX4-ADIS] (gyro bit order UNCONFIRMED)
DIAG_BITS: tuple[tuple[int, str], ...] = (
    (15, "Z accelerometer self-test failure"),
    (14, "Y accelerometer self-test failure"),
    (13, "X accelerometer self-test failure"),
    (12, "Z gyroscope self-test failure"),
    (11, "Y gyroscope self-test failure"),
    (10, "X gyroscope self-test failure"),
    (7, "new data in MAGN_OUT/BARO_OUT"),
    (6, "flash memory checksum failure"),
    (5, "self-test error"),
    (3, "SPI communication failure"),
    (1, "barometer functional test failure"),
    (0, "magnetometer functional test failure"),
)
DIAG_INFO_MASK = 1 << 7  # not an error
#: SENS_AVG B = 0..6 -> 2^B taps, 1 = filter off. B = 7 (128 taps) fits the 3-bit field but is no
#: valid setting: Linux adis16400.c marks it "Not a valid setting" (adis16400_3db_divisors), and
#: the data sheet's largest B is 6
MAX_FILTER_B = 6
FIR_TAPS = tuple(2**b for b in range(MAX_FILTER_B + 1))


def decode_diag(word: int) -> list[str]:
    """DIAG_STAT -> the messages of its set bits (docs/reference/sensors.md §4.5)."""
    return [text for bit, text in DIAG_BITS if word >> bit & 1]


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0x1021 if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_CRC_TABLE = _crc_table()


def _crc_word_table() -> list[int]:
    """Two steps of the byte table at once: the CRC after one whole MSB-first word ``x ^ crc``.

    After two byte steps of a 16-bit CRC nothing of the old CRC is left but what
    was XORed into the two bytes, so the pair of steps is one lookup.
    """
    x = np.arange(1 << 16, dtype=np.uint32)
    table = np.array(_CRC_TABLE, dtype=np.uint32)
    crc = table[x & 0xFF] ^ (x >> 8)  # low byte of the word first ...
    crc = (crc >> 8) ^ table[crc & 0xFF]  # ... then the high byte
    return crc.tolist()


_CRC_WORD_TABLE = _crc_word_table()
_CRC_WORDS = struct.Struct(">11H")


def burst_crc(data: bytes) -> int:
    """CRC-16 of the burst words XGYRO..TEMP (22 bytes, MSB-first as on MISO).

    docs/reference/sensors.md §4.6 [PX4-ADIS][JC]: bytes fed low byte first, reflected
    polynomial 0x1021, init 0xFFFF, result inverted and byte-swapped; compared
    with the CRC word read MSB-first. Table-driven form of that bitwise loop,
    one lookup per 16-bit word.
    """
    crc = 0xFFFF
    table = _CRC_WORD_TABLE
    for word in _CRC_WORDS.unpack(data):
        crc = table[crc ^ word]
    crc = ~crc & 0xFFFF
    return ((crc << 8) | (crc >> 8)) & 0xFFFF


def sign_extend(value: int, bits: int) -> int:
    return value - (1 << bits) if value & (1 << (bits - 1)) else value


def decode_temperature(raw: int) -> float:
    """TEMP_OUT -> degC: 12-bit two's complement, 0.07386 degC/LSB, 0 = 31 degC (§4.4)."""
    return TEMP_OFFSET_C + TEMP_C_PER_LSB * sign_extend(raw & 0x0FFF, TEMP_BITS)


def rate_hz(decimation: int) -> float:
    return INTERNAL_RATE_HZ / 2**decimation


class ADIS16448:
    """ADIS16448 streaming gyro, accel, mag, baro and temperature by burst reads.

    Parameters
    ----------
    spi : the chip's SPI device (mode 3).
    settings : see ``SETTINGS`` / :meth:`check_settings`.
    sleep : delay function (the station's clock, virtual in simulation).
    """

    name: ClassVar[str] = "adis16448"
    bus_kind: ClassVar[str] = "spi"
    spi_mode: ClassVar[int] = SPI_MODE
    SETTINGS: ClassVar[tuple[Setting, ...]] = (
        Setting("decimation", 1, tuple(range(0, 7)), "SMPL_PRD D: output rate = 819.2 / 2**D Hz"),
        Setting("gyro_range_dps", 1000, tuple(r.range_dps for r in GYRO_RANGES), "gyro full scale, deg/s"),
        Setting("filter_taps", 1, FIR_TAPS, "SENS_AVG Bartlett FIR taps (1 = off)"),
        Setting("crc", True, (True, False), "MSC_CTRL bit4: burst carries a CRC-16 (newer lots only)"),
        Setting("stall_us", STALL_US_DEFAULT, None, "CS-high time between 16-bit frames, us (>= 9)"),
        Setting(
            "data_ready",
            "none",
            DATA_READY_PINS,
            "bridge input wired to DIO1 (data ready): gpio4 (CP2130 event counter), gp6 (MCP2210 interrupt "
            "counter), none (losses inferred from read times)",
        ),
    )

    def __init__(self, spi: SPIDevice, settings: Mapping[str, Any], *, sleep: Sleep = time.sleep):
        self.spi = spi
        self.settings = self.check_settings(settings)
        self._sleep = sleep
        self._range = next(r for r in GYRO_RANGES if r.range_dps == self.settings["gyro_range_dps"])
        self._crc = bool(self.settings["crc"])
        self._stall_s = self.settings["stall_us"] * 1e-6
        self._rate = rate_hz(self.settings["decimation"])
        self._burst_tx = BURST_CMD + bytes(2 * BURST_WORDS + (CRC_WORD.size if self._crc else 0))
        self._last: bytes | None = None
        self._polls = 0
        #: bursts read and not yet handed over, when each was read (clock ns) and the burst before it; the
        #: poll (count) the first was read at
        self._held: list[bytes] = []
        self._held_read: list[int] = []
        self._held_before: list[int] = []
        self._first_held = 0
        #: the station's clock (ns), set by the station: each burst is stamped when its transfer returns
        self.clock_ns: Callable[[], int] | None = None
        self._last_read = self._burst_ns = 0
        self._batch = max(1, round(BATCH_S * self._rate))
        #: bursts dropped since the last hand-over; an error to raise at the next call
        self._lost = 0
        self._error: BaseException | None = None
        self._check_every = max(1, round(CONFIG_CHECK_S * self._rate))
        #: bursts dropped for a CRC mismatch (a health figure)
        self.crc_errors = 0
        #: whether the last read_block found a sample the read before had not (None: a failed or dropped
        #: transfer); the station times its next poll by it (acquisition/pollphase.py)
        self.new_sample: bool | None = None
        #: DIO1 wired to the bridge's edge counter: each sample's number is the count of data-ready pulses
        #: before the burst read it; a poll whose count has not moved reads no burst
        self._counting = self.settings["data_ready"] != "none"
        self._count = 0
        self._held_count: list[int] = []
        #: a burst dropped for its CRC while counting: the count shows the loss, the note goes with the next block
        self._dropped = False

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        out = check_settings(cls.name, cls.SETTINGS, settings)
        stall = out["stall_us"]
        if isinstance(stall, bool) or not isinstance(stall, (int, float)) or not 9 <= stall <= 1000:
            raise SettingError(f"stall_us = {stall!r}: a number of microseconds, 9 .. 1000 (datasheet minimum 9)")
        rng = next(r for r in GYRO_RANGES if r.range_dps == out["gyro_range_dps"])
        if out["filter_taps"] < rng.min_taps:
            allowed = ", ".join(str(t) for t in FIR_TAPS if t >= rng.min_taps)
            raise SettingError(
                f"filter_taps = {out['filter_taps']!r} with gyro_range_dps = {rng.range_dps}: the ADIS16448 data "
                f"sheet (SENS_AVG) needs at least {rng.min_taps} filter taps at +-{rng.range_dps} deg/s "
                f"(allowed: {allowed}; or gyro_range_dps = 1000 with any)"
            )
        return out

    # -- register access (docs/reference/sensors.md §4.1) ----------------------------------
    def read_regs(self, regs: Sequence[int]) -> list[int]:
        """Read 16-bit registers, pipelined: frame k returns the register asked in frame k-1."""
        frames = [bytes([r & READ_MASK, 0]) for r in regs] + [bytes(2)]
        rx = self.spi.transfer_frames(frames, self._stall_s)
        self._sleep(self._stall_s)  # the stall before whatever transfer comes next
        return [int.from_bytes(f, "big") for f in rx[1:]]

    def write_reg(self, reg: int, value: int) -> None:
        """Write a 16-bit register as two byte writes, low byte first."""
        frames = [bytes([WRITE_FLAG | reg, value & 0xFF]), bytes([WRITE_FLAG | (reg + 1), value >> 8 & 0xFF])]
        self.spi.transfer_frames(frames, self._stall_s)
        self._sleep(self._stall_s)

    def _burst(self) -> bytes:
        """One burst transfer (stamped when it returns: ``_burst_ns``), then the stall: the next chip select may
        follow at once (catching up)."""
        rx = self.spi.transfer(self._burst_tx)
        clock = self.clock_ns
        self._burst_ns = clock() if clock is not None else 0
        self._sleep(self._stall_s)
        return rx

    def _config_words(self) -> dict[int, int]:
        b = FIR_TAPS.index(self.settings["filter_taps"])
        msc = MSC_CTRL_DR_ENABLE | MSC_CTRL_DR_ACTIVE_HIGH | (MSC_CTRL_CRC if self._crc else 0)
        return {
            REG_SMPL_PRD: self.settings["decimation"] << SMPL_PRD_D_SHIFT | SMPL_PRD_INTERNAL_CLOCK,
            REG_SENS_AVG: self._range.code << SENS_AVG_RANGE_SHIFT | b,
            REG_MSC_CTRL: msc,
        }

    def identify(self) -> int:
        (prod,) = self.read_regs([REG_PROD_ID])
        if prod != PROD_ID_VALUE:
            raise ChipIdMismatch("ADIS16448", PROD_ID_VALUE, prod, self.spi.where)
        return prod

    def _check_config(self) -> None:
        want = self._config_words()
        got = dict(zip(want, self.read_regs(list(want)), strict=True))
        if got != want:
            shown = ", ".join(f"0x{r:02X}=0x{got[r]:04X}/0x{want[r]:04X}" for r in want)
            raise DeviceError(f"{self.spi.where}: ADIS16448 configuration lost (read/set {shown}); chip reset?")

    def open(self) -> DriverInfo:
        self.spi.ensure_open()
        if self.spi.hz > SPI_MAX_HZ_BURST:
            raise SettingError(f"{self.spi.where}: SPI clock {self.spi.hz:g} Hz above the ADIS16448 burst limit 1 MHz")
        self.identify()
        self.write_reg(REG_GLOB_CMD, GLOB_CMD_SOFTWARE_RESET)
        self._sleep(RESET_RECOVERY_S)
        prod = self.identify()
        for reg, value in self._config_words().items():
            self.write_reg(reg, value)
        self._check_config()
        lot1, lot2, serial, diag = self.read_regs([REG_LOT_ID1, REG_LOT_ID2, REG_SERIAL_NUM, REG_DIAG_STAT])
        modulus = self.spi.start_event_counter(self.settings["data_ready"]) if self._counting else 0
        self._sleep(2.0 / self._rate)  # the first output period after configuration
        self._last = None
        self._clear_held()
        self._lost, self._error, self._dropped = 0, None, False
        self._last_read = self._now()
        if self._crc:
            rx = self._burst()
            self._last_read = self._burst_ns
            if burst_crc(rx[4:26]) != CRC_WORD.unpack_from(rx, 26)[0]:
                raise DeviceError(
                    f"{self.spi.where}: burst CRC does not match on the first read"
                    " (lots without burst CRC need crc = false)"
                )
        if self._counting:
            self._count = self.spi.read_event_counter()  # the samples made so far are not this capture's
            counting = {"counter_modulus": modulus}
        else:
            counting = {}
        g = self._range.dps_per_lsb * DEG2RAD
        return DriverInfo(
            model="ADIS16448",
            identity=f"prod_id=0x{prod:04X} lot=0x{lot1:04X}{lot2:04X} serial=0x{serial:04X}",
            rate_hz=self._rate,
            settings={
                "rate_hz": self._rate,
                "decimation": int(self.settings["decimation"]),
                "gyro_range_dps": self._range.range_dps,
                "filter_taps": int(self.settings["filter_taps"]),
                "crc": self._crc,
                "stall_us": float(self.settings["stall_us"]),
                "spi_hz": float(self.spi.hz),
                "smpl_prd": self._config_words()[REG_SMPL_PRD],
                "sens_avg": self._config_words()[REG_SENS_AVG],
                "msc_ctrl": self._config_words()[REG_MSC_CTRL],
                "diag_at_open": "; ".join(decode_diag(diag & ~DIAG_INFO_MASK)) or "ok",
                "data_ready": str(self.settings["data_ready"]),
                **counting,
            },
            channels=(
                ChannelSpec("gyro", "int16", "rad/s", g, 0.0, ("x", "y", "z")),
                ChannelSpec("accel", "int16", "m/s^2", ACCEL_G_PER_LSB * G0, 0.0, ("x", "y", "z")),
                ChannelSpec("mag", "int16", "T", MAG_GAUSS_PER_LSB * GAUSS_TO_TESLA, 0.0, ("x", "y", "z")),
                ChannelSpec("baro", "uint16", "Pa", BARO_MBAR_PER_LSB * MBAR_TO_PA),
                ChannelSpec("temp", "int16", "degC", TEMP_C_PER_LSB, TEMP_OFFSET_C),
                ChannelSpec("diag", "uint16", "", 1.0),
            ),
            # the data-ready pulses the bridge counted number the samples
            has_counter=self._counting,
            # no FIFO: one burst per output period; what it makes while nobody reads is gone
            poll_interval_s=1.0 / self._rate,
            overflow="newest",
            buffer_s=1.0 / self._rate,
        )

    # -- streaming ------------------------------------------------------------------------
    def read_block(self) -> Block:
        """One burst (the newest sample); every ``BATCH_S`` the samples read so far.

        A sample read is kept, decoded with the others of its batch, and handed
        over when the batch is full or ``BATCH_S`` worth of polls after the
        oldest was read, before a dropped burst or a failed transfer, and by
        :meth:`drain` when the capture ends. Each burst is stamped when its
        transfer returns (``Block.read_ns``, with the burst before it): the chip
        has no FIFO, so what it made while the station was busy elsewhere is lost
        and only these times tell the station how much. A bus or device error is
        raised at the call after the one that hands over the samples before it.
        A dropped burst is reported (``lost``) with the next block, or at once
        when nothing is held.

        With DIO1 wired to the bridge's counter (``data_ready``) each poll first
        reads the count of data-ready pulses: unchanged, no burst is read; moved,
        the burst is read and its sample numbered with the count (``Block.counter``,
        modulo 2**16), so a count that moved by more than one is a loss the
        station sees (a counter jump), not one it infers from the read times.
        """
        self._raise_held()
        self._polls += 1
        self.new_sample = None
        fresh = True
        try:
            if self._polls % self._check_every == 0:
                self._check_config()
            if self._counting:
                count = self.spi.read_event_counter()
                fresh, self._count = count != self._count, count
                if not fresh:
                    self._last_read = self._now()  # found nothing new: the read before the next sample
            if fresh:
                rx = self._burst()
                read, before = self._burst_ns, self._last_read
                self._last_read = read
        except (BusError, DeviceError) as exc:
            if not self._held:
                raise
            self._error = exc
            return self._release()
        held = self._held
        self.new_sample = False
        if fresh:
            data = rx[2 : 2 + 2 * BURST_WORDS]
            if self._crc and burst_crc(data[2:]) != CRC_WORD.unpack_from(rx, 2 + 2 * BURST_WORDS)[0]:
                self.new_sample = None
                return self._crc_mismatch()
            # the same sample read twice is no new data (without the wire: no new sample yet; with it: the
            # sample after the count came during the read before, which took it under the count before)
            if data != self._last:
                self.new_sample = True
                self._last = data
                if not held:
                    self._first_held = self._polls
                held.append(data)
                self._held_read.append(read)
                self._held_before.append(before)
                self._held_count.append(self._count)
        if held and (len(held) >= self._batch or self._polls - self._first_held + 1 >= self._batch or self._lost):
            return self._release()
        return _NOTHING

    def _crc_mismatch(self) -> Block:
        """A burst whose CRC does not match: dropped and counted lost (with the wire, the count shows it)."""
        self.crc_errors += 1
        self._last = None
        before = self._release() if self._held else None
        if self._counting:
            self._dropped = True
        else:
            self._lost += 1  # handed over with the next block: it comes after ``before``
        try:
            self._check_config()  # a reset chip fails every CRC: catch it now, not at the next check
        except (BusError, DeviceError) as exc:
            if before is None:
                raise
            self._error = exc
        return before if before is not None else self._release()

    def drain(self) -> Block:
        """The samples read but not yet handed over (the capture is ending).

        An error held back from the last poll is raised now, so it is logged.
        """
        self._raise_held()
        return self._release()

    def _raise_held(self) -> None:
        """Raise the error of a transfer that failed after samples were held (they went first)."""
        if self._error is not None:
            exc, self._error = self._error, None
            raise exc

    def _release(self) -> Block:
        """Decode the held bursts into one block, with the polls since each was read; a dropped burst counts
        as lost before it."""
        lost, self._lost = self._lost, 0
        if not self._held:
            return Block(_EMPTY, lost=lost, note=CHECKSUM_NOTE if lost else "")
        note = CHECKSUM_NOTE if lost or self._dropped else ""
        self._dropped = False
        words = np.frombuffer(b"".join(self._held), dtype=">u2").reshape(-1, BURST_WORDS)
        stamps = {}
        if self.clock_ns is not None:
            stamps = {"read_ns": np.array(self._held_read), "previous_read_ns": np.array(self._held_before)}
        counter = np.array(self._held_count, dtype=np.int64) if self._counting else None
        self._clear_held()
        return Block(_decode(words), counter=counter, lost=lost, note=note, **stamps)

    def _clear_held(self) -> None:
        for held in (self._held, self._held_read, self._held_before, self._held_count):
            held.clear()

    def _now(self) -> int:
        return self.clock_ns() if self.clock_ns is not None else 0

    def close(self) -> None:
        self.spi.close()


def _decode(words: np.ndarray) -> dict[str, np.ndarray]:
    """Burst words (k, 12) as read, big-endian u16 -> channels in the station's dtypes (§4.4, §4.6).

    The layout of :data:`BURST`, vectorised.
    """
    temp = (words[:, 11] & 0x0FFF).astype(np.int16)
    temp -= (temp & 0x0800) << 1  # 12-bit two's complement
    return {
        "gyro": words[:, 1:4].astype(np.int16),
        "accel": words[:, 4:7].astype(np.int16),
        "mag": words[:, 7:10].astype(np.int16),
        "baro": words[:, 10].astype(np.uint16),
        "temp": temp,
        "diag": words[:, 0].astype(np.uint16),
    }


def _frozen_empty() -> dict[str, np.ndarray]:
    out = _decode(np.zeros((0, BURST_WORDS), dtype=">u2"))
    for a in out.values():
        a.flags.writeable = False
    return out


#: the channels of a poll that hands nothing over (shared: nobody writes into them), and such a poll
_EMPTY = _frozen_empty()
_NOTHING = Block(_EMPTY)
