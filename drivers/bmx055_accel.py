"""Bosch BMX055 accelerometer die (BMA2x2 family, chip id 0xFA), I2C.

Register map, tables and worked examples: ``docs/reference/sensors.md`` §1.1,
§1.5-§1.7 (sources there: Linux ``bmc150-accel-core.c`` [L-BMC], Bosch BMA2x2
driver [B-BMA], kriswiner BMX-055 [KW]). The accelerometer is a die of its own
with its own address and output data rate, so it is a device of its own in
the run file (one time base per device); the gyro die is :mod:`.bmx055`.

Two read modes:

* ``fifo`` (default): the 32-frame FIFO in stream mode, read in one burst per
  poll (polled at 40 % fill), overrun flag -> a lost-sample block;
* ``data_ready``: the data registers are polled twice per output period and a
  sample is taken when its ``new_data`` bits are set (no FIFO; a late poll
  loses samples without the chip noticing, so prefer ``fifo``).

Every poll reads registers 0x02..0x17 in one burst: data with ``new_data``
bits, temperature, FIFO status, and the range/bandwidth/interrupt-enable
settings, so a chip that lost its configuration (power-on reset) is caught on
the next poll and raised as :class:`DeviceError`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from imustation.channels import ChannelSpec, DriverInfo
from imustation.drivers.base import Block, Setting, Sleep, check_settings
from imustation.drivers.bmx055 import TEMP_OFFSET_C, TEMP_SCALE_C
from imustation.drivers.bus.base import RegisterDevice
from imustation.drivers.regs import Field
from imustation.errors import ChipIdMismatch, DeviceError, SettingError
from imustation.units import G0

# --- registers (docs/reference/sensors.md §1.6) ------------------------------
REG_CHIP_ID = 0x00
CHIP_ID_VALUE = 0xFA  # §1.6 [L-BMC][KW][SM]
REG_ACCD_X_LSB = 0x02  # 0x02..0x07 X/Y/Z: LSB bits7:4 = data3:0, bit0 new_data; MSB = data11:4, §1.6 [B-BMA]
NEW_DATA = Field(REG_ACCD_X_LSB, 0, 1)  # bit0 of each LSB register, §1.6 [B-BMA] NEW_DATA_X mask 0x01
REG_TEMP = 0x08  # s8, T = 23 + 0.5 * raw, §1.5 [KW]
REG_FIFO_STATUS = 0x0E  # bit7 overrun, bits6:0 frame count, §1.6 [B-BMA][L-BMC]
FIFO_STATUS_OVERRUN = Field(REG_FIFO_STATUS, 7, 1)
FIFO_STATUS_COUNT = Field(REG_FIFO_STATUS, 0, 7)
REG_PMU_RANGE = 0x0F  # range codes 0x03/0x05/0x08/0x0C, §1.6 [L-BMC][KW]
PMU_BW = Field(0x10, 0, 5)  # bandwidth codes 0x08..0x0F, §1.7 [B-BMA]
REG_PMU_LPW = 0x11  # bits7:5 mode, 000 = normal, §1.6 [L-BMC][B-BMA]
LPW_NORMAL = 0x00
REG_SOFTRESET = 0x14  # write SOFTRESET_CMD, §1.6 [L-BMC]
SOFTRESET_CMD = 0xB6
REG_INT_EN_1 = 0x17  # bit4 data_en, §1.6 [L-BMC]
INT_EN_1_DATA_EN = Field(REG_INT_EN_1, 4, 1)
FIFO_MODE = Field(0x3E, 6, 2)  # FIFO_CONFIG_1 bits7:6: 0 bypass, 1 FIFO, 2 stream, §1.6 [L-BMC]
FIFO_DATA_SELECT = Field(0x3E, 0, 2)  # 0 = X, Y, Z frames
FIFO_MODE_BYPASS = 0
FIFO_MODE_STREAM = 2
REG_FIFO_DATA = 0x3F  # 6-byte XYZ frames, §1.6 [L-BMC]
FIFO_FRAME_BYTES = 6
FIFO_DEPTH_FRAMES = 32  # §1.6 [L-BMC] BMC150_ACCEL_FIFO_LENGTH, [B-BMA] MAX_FIFO_F_LEVEL

#: one burst per poll: data .. INT_EN_1 (0x02..0x17)
STATUS_FIRST, STATUS_LAST = REG_ACCD_X_LSB, REG_INT_EN_1
#: the data-enable interrupt bit doubles as a configuration marker: its power-on
#: value is 0 (Bosch BMA2x2 reset values; not in docs/reference/sensors.md), and RANGE/BW alone
#: cannot reveal a reset when the configured values equal the power-on ones
CONFIG_MARKER = INT_EN_1_DATA_EN

# --- delays --------------------------------------------------------------------
SOFTRESET_WAIT_S = 0.0018  # "wait >= 1.8 ms" after soft reset, §1.6 [L-BMC]
#: settling after configuration; the driver waits this plus two output periods so
#: that samples at the new rate exist before the first read (value UNCONFIRMED)
STARTUP_WAIT_S = 0.010


# --- tables ----------------------------------------------------------------------
@dataclass(frozen=True)
class BwRow:
    code: int
    bandwidth_hz: float
    update_ms: float

    @property
    def odr_hz(self) -> float:
        """Data rate: one new sample per update time (= 2 x bandwidth)."""
        return 1000.0 / self.update_ms


#: PMU_BW register 0x10, docs/reference/sensors.md §1.7: bandwidths [B-BMA], update times [KW][SM]
BW_TABLE: tuple[BwRow, ...] = (
    BwRow(0x08, 7.81, 64.0),
    BwRow(0x09, 15.63, 32.0),
    BwRow(0x0A, 31.25, 16.0),
    BwRow(0x0B, 62.5, 8.0),
    BwRow(0x0C, 125.0, 4.0),
    BwRow(0x0D, 250.0, 2.0),
    BwRow(0x0E, 500.0, 1.0),
    BwRow(0x0F, 1000.0, 0.5),
)


@dataclass(frozen=True)
class RangeRow:
    code: int
    range_g: int
    lsb_per_g: float

    @property
    def scale(self) -> float:
        """m/s^2 per LSB (12-bit value)."""
        return G0 / self.lsb_per_g


#: PMU_RANGE register 0x0F, docs/reference/sensors.md §1.6/§1.7 (12-bit: 1024/512/256/128 LSB/g [ICG][KW])
RANGE_TABLE: tuple[RangeRow, ...] = (
    RangeRow(0x03, 2, 1024.0),
    RangeRow(0x05, 4, 512.0),
    RangeRow(0x08, 8, 256.0),
    RangeRow(0x0C, 16, 128.0),
)

READ_MODES = ("fifo", "data_ready")


def bw_row(rate_hz: float) -> BwRow:
    for row in BW_TABLE:
        if row.odr_hz == rate_hz:
            return row
    raise ValueError(f"no PMU_BW code for {rate_hz} Hz")


def range_row(range_g: int) -> RangeRow:
    for row in RANGE_TABLE:
        if row.range_g == range_g:
            return row
    raise ValueError(f"no PMU_RANGE code for +-{range_g} g")


def decode_accel(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """ACCD_X_LSB..ACCD_Z_MSB (or FIFO frames) -> (counts, new_data), shapes ``(k, 3)``.

    Counts are the 12-bit values: ``s16(LSB | MSB << 8) >> 4`` (docs/reference/sensors.md §1.6),
    int16; ``new_data`` is bit 0 of each LSB byte, bool.
    """
    raw = np.frombuffer(data, dtype="<i2").reshape(-1, 3)
    return (raw >> 4).astype(np.int16), (raw & 1).astype(bool)


def decode_temperature(raw: int) -> float:
    """ACCD_TEMP byte -> degC (docs/reference/sensors.md §1.5: 23 + 0.5 * s8)."""
    s8 = raw - 256 if raw >= 128 else raw
    return TEMP_OFFSET_C + TEMP_SCALE_C * s8


_RATES = tuple(sorted(r.odr_hz for r in BW_TABLE))


class BMX055Accel:
    """BMX055 accelerometer die streaming X/Y/Z acceleration.

    Parameters
    ----------
    regs : register device at the accelerometer's I2C address (0x18 or 0x19).
    settings : validated by :meth:`check_settings`: ``rate_hz`` (one row of the
        PMU_BW table; ``bandwidth_hz`` is rate/2 and may be given to check it),
        ``accel_range_g``, ``read_mode``.
    sleep : delay function (the station's clock, virtual in simulation).
    """

    name: ClassVar[str] = "bmx055_accel"
    bus_kind: ClassVar[str] = "i2c"
    default_address: ClassVar[int] = 0x18
    SETTINGS: ClassVar[tuple[Setting, ...]] = (
        # 125 Hz: the Linux default (PMU_BW 0x0B), §1.6 [L-BMC]
        Setting("rate_hz", 125.0, _RATES, "output data rate, Hz (= 1 / data update time)"),
        Setting("bandwidth_hz", None, (None, *(r.bandwidth_hz for r in BW_TABLE)), "filter bandwidth, Hz (rate/2)"),
        Setting("accel_range_g", 2, tuple(r.range_g for r in RANGE_TABLE), "full scale, g"),
        Setting("read_mode", "fifo", READ_MODES, "fifo (32-frame FIFO) or data_ready (poll new_data)"),
    )

    def __init__(self, regs: RegisterDevice, settings: Mapping[str, Any], *, sleep: Sleep = time.sleep):
        self.regs = regs
        self.settings = self.check_settings(settings)
        self._sleep = sleep
        self._bw = bw_row(self.settings["rate_hz"])
        self._range = range_row(self.settings["accel_range_g"])
        self._fifo = self.settings["read_mode"] == "fifo"
        self._stuck = False
        #: data-ready mode: whether the last read_block found a new sample (None: not known)
        self.new_sample: bool | None = None

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        out = check_settings(cls.name, cls.SETTINGS, settings)
        row = bw_row(out["rate_hz"])
        if out["bandwidth_hz"] is None:
            out["bandwidth_hz"] = row.bandwidth_hz
        elif out["bandwidth_hz"] != row.bandwidth_hz:
            pairs = ", ".join(f"{r.odr_hz:g} Hz/{r.bandwidth_hz:g} Hz" for r in BW_TABLE)
            raise SettingError(
                f"rate_hz = {out['rate_hz']} with bandwidth_hz = {out['bandwidth_hz']}: "
                f"the BMX055 accelerometer allows rate/bandwidth pairs {pairs}"
            )
        return out

    # -- identity and configuration ------------------------------------------
    def identify(self) -> int:
        chip_id = self.regs.read(REG_CHIP_ID, 1)[0]
        if chip_id != CHIP_ID_VALUE:
            raise ChipIdMismatch("BMX055 accelerometer", CHIP_ID_VALUE, chip_id, self.regs.where)
        return chip_id

    def _fifo_config(self) -> bytes:
        mode = FIFO_MODE_STREAM if self._fifo else FIFO_MODE_BYPASS
        return bytes([FIFO_MODE.encode(mode) | FIFO_DATA_SELECT.encode(0)])

    def configure(self) -> None:
        """Soft reset, normal mode, range, bandwidth, data-enable marker, FIFO mode; read back."""
        self.regs.write(REG_SOFTRESET, bytes([SOFTRESET_CMD]))
        self._sleep(SOFTRESET_WAIT_S)
        self.identify()
        self.regs.write(REG_PMU_LPW, bytes([LPW_NORMAL]))
        self.regs.write(REG_PMU_RANGE, bytes([self._range.code]))
        self.regs.write(PMU_BW.reg, bytes([PMU_BW.encode(self._bw.code)]))
        self.regs.write(REG_INT_EN_1, bytes([CONFIG_MARKER.encode(1)]))
        self._check_config(self.regs.read(STATUS_FIRST, STATUS_LAST - STATUS_FIRST + 1), "read back")
        self.regs.write(FIFO_MODE.reg, self._fifo_config())
        fifo_back = self.regs.read(FIFO_MODE.reg, 1)
        if fifo_back != self._fifo_config():
            raise DeviceError(
                f"{self.regs.where}: FIFO_CONFIG_1 read back 0x{fifo_back[0]:02X}, wrote 0x{self._fifo_config()[0]:02X}"
            )
        self._sleep(STARTUP_WAIT_S + 2.0 / self._bw.odr_hz)
        # the start-up samples are not valid: empty the FIFO / clear new_data once
        self._stuck = False
        self.read_block()

    def _check_config(self, status: bytes, what: str) -> None:
        range_code = status[REG_PMU_RANGE - STATUS_FIRST]
        bw_code = PMU_BW.decode(status[PMU_BW.reg - STATUS_FIRST])
        marker = CONFIG_MARKER.decode(status[CONFIG_MARKER.reg - STATUS_FIRST])
        if (range_code, bw_code, marker) != (self._range.code, self._bw.code, 1):
            raise DeviceError(
                f"{self.regs.where}: configuration {what}: PMU_RANGE/PMU_BW/data_en 0x{range_code:02X}/"
                f"0x{bw_code:02X}/{marker}, set 0x{self._range.code:02X}/0x{self._bw.code:02X}/1"
                + ("; chip reset?" if what == "lost" else "")
            )

    def open(self) -> DriverInfo:
        chip_id = self.identify()
        self.configure()
        return DriverInfo(
            model="BMX055 accelerometer (BMA2x2)",
            identity=f"chip_id=0x{chip_id:02X}",
            rate_hz=self._bw.odr_hz,
            settings={
                "rate_hz": self._bw.odr_hz,
                "bandwidth_hz": self._bw.bandwidth_hz,
                "accel_range_g": int(self._range.range_g),
                "accel_sensitivity_lsb_per_g": self._range.lsb_per_g,
                "bw_code": self._bw.code,
                "range_code": self._range.code,
                "read_mode": self.settings["read_mode"],
                "fifo_mode": "stream" if self._fifo else "bypass",
            },
            channels=(
                ChannelSpec("accel", "int16", "m/s^2", self._range.scale, 0.0, ("x", "y", "z")),
                ChannelSpec("temp", "int8", "degC", TEMP_SCALE_C, TEMP_OFFSET_C),
            ),
            has_counter=False,
            # FIFO: at most 40 % full, a whole number of output periods (so every poll
            # finds the same number of frames); data_ready: twice per output period
            poll_interval_s=(math.floor(0.4 * FIFO_DEPTH_FRAMES) if self._fifo else 0.5) / self._bw.odr_hz,
            # the FIFO reports its overruns; the data registers hold one sample, lost unread without a word
            overflow="reported" if self._fifo else "newest",
            buffer_s=float("inf") if self._fifo else 1.0 / self._bw.odr_hz,
        )

    # -- streaming --------------------------------------------------------------
    def read_block(self) -> Block:
        self.new_sample = None
        status = self.regs.read(STATUS_FIRST, STATUS_LAST - STATUS_FIRST + 1)
        self._check_config(status, "lost")
        latest, new = decode_accel(status[: REG_TEMP - STATUS_FIRST])
        temp_byte = status[REG_TEMP - STATUS_FIRST]
        temp_raw = temp_byte - 256 if temp_byte >= 128 else temp_byte
        lost, note = 0, ""
        if not self._fifo:
            # the station times its next poll by this (acquisition/pollphase.py)
            self.new_sample = bool(new.any())
            accel = latest if self.new_sample else np.zeros((0, 3), dtype=np.int16)
        else:
            fifo = status[REG_FIFO_STATUS - STATUS_FIRST]
            count = FIFO_STATUS_COUNT.decode(fifo)
            if count:
                accel, _ = decode_accel(self.regs.read(REG_FIFO_DATA, count * FIFO_FRAME_BYTES))
            else:
                accel = np.zeros((0, 3), dtype=np.int16)
            if FIFO_STATUS_OVERRUN.decode(fifo):
                # stream mode kept the newest frames; rewriting FIFO_CONFIG_1 clears the flag
                # (and the FIFO, just emptied). -1: the station measures the loss from time.
                self.regs.write(FIFO_MODE.reg, self._fifo_config())
                lost, note = -1, "FIFO overrun"
            elif count == 0 and new.any():
                # new data in the data registers but none in the FIFO: the FIFO stopped
                # filling. Restart it; report the loss once, when frames arrive again.
                self.regs.write(FIFO_MODE.reg, self._fifo_config())
                self._stuck = True
            elif count and self._stuck:
                self._stuck = False
                lost, note = -1, "FIFO stopped filling (new data without FIFO frames); restarted"
        temp = np.full(len(accel), temp_raw, dtype=np.int8)
        return Block({"accel": accel, "temp": temp}, lost=lost, note=note)

    def close(self) -> None:
        pass
