"""Byte-level simulator of the ADIS16448 on SPI (docs/reference/sensors.md §4).

Answers 16-bit SPI frames as the chip does: a read command returns its
register on the *next* frame, writes are one byte per frame, ``3E 00`` with CS
held low starts a burst (DIAG_STAT, gyro, accel, mag, baro, temp, and the
CRC-16 when MSC_CTRL bit 4 is set). PROD_ID reads 0x4040. A software reset
(GLOB_CMD bit 7) restores the power-on registers and the chip answers zeros
for the 90 ms recovery time. Wrong SPI mode or a clock above the chip's limit
gives unusable MISO bytes (0xFF).

Samples are produced on the station clock at 819.2 / 2^D Hz; the output
registers hold the newest one. Gyro rates come from the signal source
(Table IV key ``adis16448``); the accelerometer reads gravity on +z plus white
noise, the magnetometer a fixed field, the barometer 1013.25 mbar plus white
noise, the temperature the source's die temperature. Bursts are built a chunk
of samples at a time with numpy (CRC included), so the simulator costs little
per sample.

Strict where the data sheet is (docs/reference/conformance-adis16448.md): a chip
select asserted less than the stall time (9 us) after the previous one ended is
not understood (MISO 0xFF, nothing happens); with SMPL_PRD bit 0 clear the chip
waits for an external clock on DIO4 and produces nothing; range codes other than
001/010/100 in SENS_AVG are reserved and ignored.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imustation.clock import Clock
from imustation.drivers import adis16448 as chip
from imustation.drivers.sim import filters
from imustation.drivers.sim.faults import FaultPlan
from imustation.drivers.sim.sources import SignalSource, fits, with_filter

#: power-on register values; datasheet defaults are UNCONFIRMED (docs/reference/sensors.md §4.2)
#: except SENS_AVG range code 100 (+-1000 deg/s) [PX4-ADIS]
POR_REGS = {
    chip.REG_PROD_ID: chip.PROD_ID_VALUE,
    chip.REG_SMPL_PRD: 0x0001,  # D = 0, internal clock
    chip.REG_SENS_AVG: 0x0400,  # +-1000 deg/s, filter off
    chip.REG_MSC_CTRL: 0x0006,  # data ready on DIO1, active high; CRC off
    chip.REG_LOT_ID1: 0x1824,  # the lot PX4 knows to carry the burst CRC [PX4-ADIS]
    chip.REG_LOT_ID2: 0x0001,
    chip.REG_SERIAL_NUM: 0x0448,
}
READ_ONLY = frozenset(range(chip.REG_XGYRO_OUT, 0x1A)) | {
    chip.REG_PROD_ID,
    chip.REG_LOT_ID1,
    chip.REG_LOT_ID2,
    chip.REG_SERIAL_NUM,
    chip.REG_DIAG_STAT,
}
POWER_ON_START_S = 0.205  # §4.1 [PX4-ADIS]
ACCEL_NOISE_G = 1.5e-3  # white accel noise per sample, g (simulation choice)
BARO_NOISE_MBAR = 0.05  # simulation choice
BARO_MBAR = 1013.25
MAG_GAUSS = (0.21, 0.0, 0.43)  # a mid-latitude earth field, gauss (simulation choice)
CHUNK = 4096  # samples built per numpy step (10 s at 409.6 Hz)
DIAG_SPI_FAILURE = 1 << 3
MISO_GARBAGE = 0xFF
#: CS high time the chip needs between transfers, ns (data sheet timing table, t_STALL 9 us)
STALL_MIN_NS = 9_000
#: SENS_AVG bits 10:8 codes the chip knows (the others are reserved)
_RANGE_CODES = frozenset(r.code for r in chip.GYRO_RANGES)


def burst_crc_rows(words: np.ndarray) -> np.ndarray:
    """Vectorised :func:`chip.burst_crc` over rows of 11 words (n, 11) uint16 -> (n,) uint16.

    One lookup per word column in the driver's word table (two byte steps at once).
    """
    crc = np.full(len(words), 0xFFFF, dtype=np.uint32)
    for j in range(words.shape[1]):
        crc = _CRC_WORD_TABLE[crc ^ words[:, j]]
    crc = ~crc & 0xFFFF
    return (((crc << 8) | (crc >> 8)) & 0xFFFF).astype(np.uint16)


_CRC_WORD_TABLE = np.array(chip._CRC_WORD_TABLE, dtype=np.uint32)
#: magnetometer words of the fixed field
_MAG_WORDS = np.rint(np.array(MAG_GAUSS) / chip.MAG_GAUSS_PER_LSB).astype(np.int64)


class ADIS16448Sim:
    """ADIS16448 behind a simulated SPI bridge (implements ``spi_transfer``).

    Parameters
    ----------
    clock : the station clock.
    source_factory : ``fs_hz -> SignalSource`` of X/Y/Z rate, rad/s.
    plan : faults: ``checksum`` (one burst with a wrong CRC), ``reset`` (power-on reset).
    seed : seed of the accelerometer/barometer noise.
    """

    def __init__(
        self,
        clock: Clock,
        source_factory: Callable[[float], SignalSource],
        plan: FaultPlan | None = None,
        seed: int = 0,
    ):
        self.clock = clock
        self.plan = plan
        self.source_factory = source_factory
        self.source: SignalSource | None = None
        self.rng = np.random.default_rng([seed, 0xAD15])
        self.sim_resets = 0
        self.sim_bursts = 0
        #: transfers ignored because CS was high for less than the stall time (test back door)
        self.sim_stall_violations = 0
        self.cs_high_ns = -STALL_MIN_NS  # when the last transfer ended (chip select raised)
        #: data-ready pulses made before the current sampling run, and the run's samples before the line was on
        self._edges_before = self._edges_from = 0
        self._power_on(0.0)  # powered up long before the station opens it

    # -- state ----------------------------------------------------------------------------
    def _power_on(self, busy_s: float) -> None:
        if hasattr(self, "t_start_ns"):
            self._fold_edges()  # the pulses made so far stay made
            self.t_start_ns, self._edges_from = self.clock.now_ns(), 0
        self.regs = dict(POR_REGS)
        self.pending = 0  # the word the next frame returns
        self.busy_until_ns = self.clock.now_ns() + int(busy_s * 1e9)
        self.diag = 0
        self._restart()

    def _restart(self) -> None:
        if hasattr(self, "t_start_ns"):
            self._fold_edges()
        self.t_start_ns, self._edges_from = self.clock.now_ns(), 0
        self.produced = 0
        self._chunk_bytes = b""  # burst words of the current chunk as on MISO (big-endian), 26 bytes a sample
        self._chunk_first = 0
        fs = self._rate = self.rate_hz
        d = self.regs.get(chip.REG_SMPL_PRD, 0) >> chip.SMPL_PRD_D_SHIFT & 0x1F
        out_filter = filters.adis16448(d, 2 ** (self.regs.get(chip.REG_SENS_AVG, 0) & 0x7))
        if not fits(self.source, fs, out_filter):
            self.source = with_filter(self.source_factory(fs), out_filter)

    @property
    def rate_hz(self) -> float:
        return chip.rate_hz(self.regs.get(chip.REG_SMPL_PRD, 0) >> chip.SMPL_PRD_D_SHIFT & 0x1F)

    @property
    def internal_clock(self) -> bool:
        """SMPL_PRD bit 0: 1 = internal 819.2 SPS clock; 0 = sampling on an external clock (none here)."""
        return bool(self.regs.get(chip.REG_SMPL_PRD, 0) & chip.SMPL_PRD_INTERNAL_CLOCK)

    @property
    def gyro_scale(self) -> float:
        code = self.regs.get(chip.REG_SENS_AVG, 0) >> chip.SENS_AVG_RANGE_SHIFT & 0x7
        row = next((r for r in chip.GYRO_RANGES if r.code == code), chip.GYRO_RANGES[-1])
        return row.dps_per_lsb * chip.DEG2RAD

    def _due(self) -> int:
        """Samples made since the last restart (on the clock; an external clock never ticks here)."""
        if not self.internal_clock:
            return 0
        return max(0, int((self.clock.now_ns() - self.t_start_ns) * self._rate / 1e9))

    @property
    def data_ready_on(self) -> bool:
        """MSC_CTRL: data ready enabled on DIO1 (bit 2 set, bit 0 clear)."""
        msc = self.regs.get(chip.REG_MSC_CTRL, 0)
        return bool(msc & chip.MSC_CTRL_DR_ENABLE) and not msc & chip.MSC_CTRL_DR_LINE_DIO2

    def data_ready_edges(self) -> int:
        """Pulses on DIO1 so far: one per sample made while data ready is enabled on it (what a counter
        wired to DIO1 counts)."""
        return self._edges_before + (self._due() - self._edges_from if self.data_ready_on else 0)

    def _fold_edges(self) -> None:
        """Keep the pulses made so far before a setting or the sampling run changes."""
        self._edges_before, self._edges_from = self.data_ready_edges(), self._due()

    def _build(self, n: int) -> None:
        """Draw the next ``n`` samples and build their burst words (n, 13): diag, 11 data, CRC."""
        assert self.source is not None
        rates = self.source.next(n)
        t_mid = (self.produced + n / 2) / self._rate
        w = np.empty((n, 13), dtype=np.int64)
        w[:, 0] = self.diag
        gyro = rates / self.gyro_scale  # a new array: the source's may be a recording's
        w[:, 1:4] = np.rint(np.clip(gyro, -32768, 32767, out=gyro), out=gyro)
        accel = self.rng.normal(0.0, ACCEL_NOISE_G / chip.ACCEL_G_PER_LSB, (n, 3))
        accel[:, 2] += 1.0 / chip.ACCEL_G_PER_LSB  # gravity on +z
        w[:, 4:7] = np.rint(np.clip(accel, -32768, 32767, out=accel), out=accel)
        w[:, 7:10] = _MAG_WORDS
        baro = self.rng.normal(BARO_MBAR / chip.BARO_MBAR_PER_LSB, BARO_NOISE_MBAR / chip.BARO_MBAR_PER_LSB, n)
        w[:, 10] = np.rint(np.clip(baro, 0, 65535, out=baro), out=baro)
        temp = self.source.temperature(t_mid)
        w[:, 11] = int(np.clip(round((temp - chip.TEMP_OFFSET_C) / chip.TEMP_C_PER_LSB), -2048, 2047)) & 0x0FFF
        words = (w & 0xFFFF).astype(np.uint16)
        words[:, 12] = burst_crc_rows(words[:, 1:12])
        self._chunk_bytes = words.astype(">u2").tobytes()
        self._chunk_first = self.produced
        self.produced += n

    def _newest(self) -> int:
        """Row in the current chunk of the newest sample due by now (-1 before the first)."""
        due = self._due()
        if due <= 0:
            return -1  # nothing sampled since the last restart
        while self.produced < due:
            self._build(max(CHUNK, due - self.produced))
        return due - 1 - self._chunk_first

    # -- wire protocol -------------------------------------------------------------------------
    def spi_transfer(self, tx: bytes, mode: int, hz: float) -> bytes:
        if self.plan is not None and self.plan.fire("reset"):
            self.sim_resets += 1
            self._power_on(POWER_ON_START_S)
        now = self.clock.now_ns()
        stalled = now - self.cs_high_ns >= STALL_MIN_NS
        self.cs_high_ns = now  # the transfer takes no time on the virtual clock
        if now < self.busy_until_ns:
            return bytes(len(tx))
        if not stalled:
            self.sim_stall_violations += 1
            return bytes([MISO_GARBAGE]) * len(tx)
        burst = len(tx) > 2 and tx[:2] == chip.BURST_CMD
        if mode != chip.SPI_MODE or hz > (chip.SPI_MAX_HZ_BURST if burst else chip.SPI_MAX_HZ_REGISTER):
            return bytes([MISO_GARBAGE]) * len(tx)
        if len(tx) % 2:
            self.diag |= DIAG_SPI_FAILURE
        if burst:
            return self._burst(len(tx))
        out = bytearray()
        for i in range(0, len(tx) - 1, 2):
            out += self.pending.to_bytes(2, "big")
            self._frame(tx[i], tx[i + 1])
        return bytes(out)

    def _frame(self, b0: int, b1: int) -> None:
        addr = b0 & chip.READ_MASK
        if b0 & chip.WRITE_FLAG:
            self.pending = 0
            self._write_byte(addr, b1)
            return
        self.pending = self._read(addr & ~1)

    def _read(self, reg: int) -> int:
        if reg == chip.REG_DIAG_STAT:
            value, self.diag = self.diag, 0  # DIAG_STAT clears on read
            return value
        if chip.REG_XGYRO_OUT <= reg <= 0x18:
            row = self._newest()
            at = 26 * row + 2 * (1 + (reg - chip.REG_XGYRO_OUT) // 2)
            return 0 if row < 0 else int.from_bytes(self._chunk_bytes[at : at + 2], "big")
        return self.regs.get(reg, 0)

    def _write_byte(self, addr: int, value: int) -> None:
        reg = addr & ~1
        if reg == chip.REG_GLOB_CMD:
            if addr == reg and value & chip.GLOB_CMD_SOFTWARE_RESET:
                self.sim_resets += 1
                self._power_on(chip.RESET_RECOVERY_S)
            return
        if reg in READ_ONLY:
            return
        old = self.regs.get(reg, 0)
        new = (old & 0xFF00) | value if addr == reg else (old & 0x00FF) | value << 8
        if reg == chip.REG_MSC_CTRL:
            self._fold_edges()  # from now on the line follows the new setting
        if reg == chip.REG_SENS_AVG and new >> chip.SENS_AVG_RANGE_SHIFT & 0x7 not in _RANGE_CODES and addr != reg:
            return  # a reserved range code: the high byte is not taken
        self.regs[reg] = new
        if reg in (chip.REG_SMPL_PRD, chip.REG_SENS_AVG):
            self._newest()  # samples due so far belong to the old setting
            self._restart()

    def _burst(self, n: int) -> bytes:
        self.sim_bursts += 1
        row = self._newest()
        body = bytes(26) if row < 0 else self._chunk_bytes[26 * row : 26 * row + 26]
        if self.regs.get(chip.REG_MSC_CTRL, 0) & chip.MSC_CTRL_CRC:
            if self.plan is not None and self.plan.fire("checksum"):
                body = body[:-2] + bytes([body[-2] ^ 0x5A, body[-1] ^ 0x5A])
        else:
            body = body[:-2] + b"\0\0"  # MISO idle after the 12 words
        out = self.pending.to_bytes(2, "big") + body
        self.pending = 0
        return out if n == len(out) else (out + bytes(max(0, n - len(out))))[:n]
