"""Bosch BMX055 gyroscope die (BMG160-compatible), I2C.

Register map, tables and worked examples: ``docs/reference/sensors.md`` §1
(sources there: Linux ``bmg160_core.c`` [L-BMG], Bosch BMG160 API [B-BMG],
kriswiner BMX-055 [KW]). Streaming uses the on-chip FIFO in stream mode with
X/Y/Z frames, read in one burst per poll, so no sample is lost to host
scheduling jitter as long as the station polls before 100 frames accumulate.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from imustation.channels import ChannelSpec, DriverInfo
from imustation.drivers.base import Block, Setting, Sleep, check_settings
from imustation.drivers.bus.base import RegisterDevice
from imustation.drivers.regs import Field, write_field
from imustation.errors import ChipIdMismatch, DeviceError
from imustation.units import DEG2RAD

# --- registers (docs/reference/sensors.md §1.2) ------------------------------
REG_CHIP_ID = 0x00  # reads CHIP_ID_VALUE
CHIP_ID_VALUE = 0x0F  # §1.2 [L-BMG][B-BMG][KW]
REG_RATE_X_LSB = 0x02  # 0x02..0x07 rate X/Y/Z, s16 little-endian, §1.2 [L-BMG]
REG_TEMP = 0x08  # s8, T = 23 + 0.5 * raw, §1.5 [KW]
REG_FIFO_STATUS = 0x0E  # bit7 overrun, bits6:0 frame count, §1.2 [B-BMG]
FIFO_STATUS_OVERRUN = Field(REG_FIFO_STATUS, 7, 1)
FIFO_STATUS_COUNT = Field(REG_FIFO_STATUS, 0, 7)
RANGE = Field(0x0F, 0, 3)  # §1.4
BW = Field(0x10, 0, 3)  # §1.3; bit 7 is read-only reserved, masked by Field
REG_LPM1 = 0x11  # 0x00 normal mode, §1.2 [L-BMG]
LPM1_NORMAL = 0x00
REG_SOFTRESET = 0x14  # write SOFTRESET_CMD, §1.2 [L-BMG]
SOFTRESET_CMD = 0xB6
REG_INT_EN_0 = 0x15  # bit7 data_en (new-data interrupt enable); reset value 0 (BMX055 data sheet, gyro map)
#: the data-enable bit doubles as a configuration marker: BW and RANGE code 0 (2000 Hz / 523 Hz,
#: +-2000 deg/s) equal their power-on values, so they alone cannot reveal a reset (after which
#: the FIFO is back in bypass and the chip goes silent); the interrupt is not mapped to a pin
CONFIG_MARKER = Field(REG_INT_EN_0, 7, 1)
FIFO_MODE = Field(0x3E, 6, 2)  # FIFO_CONFIG_1 bits7:6: 0 bypass, 1 FIFO, 2 stream, §1.2 [B-BMG]
FIFO_DATA_SELECT = Field(0x3E, 0, 2)  # 0 = X, Y, Z frames
FIFO_MODE_STREAM = 2
REG_FIFO_DATA = 0x3F  # 6-byte XYZ frames, §1.2 [B-BMG]
FIFO_FRAME_BYTES = 6
FIFO_DEPTH_FRAMES = 100  # §1.2 [B-BMG-LNX] MAX_FIFO_F_LEVEL

# --- delays --------------------------------------------------------------------
SOFTRESET_WAIT_S = 0.030  # "wait >= 30 ms" after soft reset, §1.2 [L-BMG]
#: normal-mode start-up before data are valid: the data sheet's start-up / wake-up times
#: (t_su, t_wusm) are 30 ms, but Linux bmg160_core.c waits BMG160_MAX_STARTUP_TIME_MS = 80 ms after
#: setting normal mode on resume; the longer wait is taken (docs/reference/conformance-bmx055.md)
STARTUP_WAIT_S = 0.080

# --- tables ----------------------------------------------------------------------


@dataclass(frozen=True)
class OdrRow:
    code: int
    odr_hz: float
    bandwidth_hz: float


#: BW register 0x10, docs/reference/sensors.md §1.3 (0x00 bandwidth from [KW][SM]; rest [L-BMG])
ODR_TABLE: tuple[OdrRow, ...] = (
    OdrRow(0x00, 2000, 523),
    OdrRow(0x01, 2000, 230),
    OdrRow(0x02, 1000, 116),
    OdrRow(0x03, 400, 47),
    OdrRow(0x04, 200, 23),
    OdrRow(0x05, 100, 12),
    OdrRow(0x06, 200, 64),
    OdrRow(0x07, 100, 32),
)


@dataclass(frozen=True)
class RangeRow:
    code: int
    range_dps: int
    lsb_per_dps: float  # datasheet sensitivity

    @property
    def scale(self) -> float:
        """rad/s per LSB."""
        return DEG2RAD / self.lsb_per_dps


#: RANGE register 0x0F, docs/reference/sensors.md §1.4; datasheet sensitivities (worked example
#: "34 12" at code 0 -> 284.146 deg/s uses 16.4 LSB/(deg/s)), not Linux's FS/32768.
RANGE_TABLE: tuple[RangeRow, ...] = (
    RangeRow(0, 2000, 16.4),
    RangeRow(1, 1000, 32.8),
    RangeRow(2, 500, 65.6),
    RangeRow(3, 250, 131.2),
    RangeRow(4, 125, 262.4),
)

#: gyro die temperature, docs/reference/sensors.md §1.5: T [degC] = 23 + 0.5 * s8(raw)
TEMP_SCALE_C = 0.5
TEMP_OFFSET_C = 23.0


def odr_row(rate_hz: float, bandwidth_hz: float) -> OdrRow:
    for row in ODR_TABLE:
        if row.odr_hz == rate_hz and row.bandwidth_hz == bandwidth_hz:
            return row
    raise ValueError(f"no BW code for {rate_hz} Hz / {bandwidth_hz} Hz")


def range_row(range_dps: int) -> RangeRow:
    for row in RANGE_TABLE:
        if row.range_dps == range_dps:
            return row
    raise ValueError(f"no RANGE code for {range_dps} deg/s")


def decode_rates(data: bytes) -> np.ndarray:
    """RATE_X_LSB..RATE_Z_MSB (or FIFO frames) -> counts, shape ``(k, 3)`` int16."""
    return np.frombuffer(data, dtype="<i2").reshape(-1, 3)


def decode_temperature(raw: int) -> float:
    """TEMP register byte -> degC (docs/reference/sensors.md §1.5)."""
    s8 = raw - 256 if raw >= 128 else raw
    return TEMP_OFFSET_C + TEMP_SCALE_C * s8


_PAIRS = tuple(sorted({(r.odr_hz, r.bandwidth_hz) for r in ODR_TABLE}))


class BMX055Gyro:
    """BMX055 gyroscope die streaming X/Y/Z rate through its FIFO.

    Parameters
    ----------
    regs : register device at the gyro's I2C address (0x68 or 0x69).
    settings : validated by :meth:`check_settings`: ``rate_hz`` and
        ``bandwidth_hz`` (one row of the BW table), ``gyro_range_dps``.
    sleep : delay function (the station's clock, virtual in simulation).
    """

    name: ClassVar[str] = "bmx055"
    bus_kind: ClassVar[str] = "i2c"
    default_address: ClassVar[int] = 0x68
    SETTINGS: ClassVar[tuple[Setting, ...]] = (
        Setting("rate_hz", 400, tuple(sorted({r.odr_hz for r in ODR_TABLE})), "output data rate, Hz"),
        Setting("bandwidth_hz", 47, tuple(sorted({r.bandwidth_hz for r in ODR_TABLE})), "filter bandwidth, Hz"),
        Setting("gyro_range_dps", 125, tuple(r.range_dps for r in RANGE_TABLE), "full scale, deg/s"),
    )

    def __init__(self, regs: RegisterDevice, settings: Mapping[str, Any], *, sleep: Sleep = time.sleep):
        self.regs = regs
        self.settings = self.check_settings(settings)
        self._sleep = sleep
        self._odr = odr_row(self.settings["rate_hz"], self.settings["bandwidth_hz"])
        self._range = range_row(self.settings["gyro_range_dps"])
        self._temp_c = float("nan")

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        out = check_settings(cls.name, cls.SETTINGS, settings)
        if (out["rate_hz"], out["bandwidth_hz"]) not in _PAIRS:
            pairs = ", ".join(f"{int(o)} Hz/{b:g} Hz" for o, b in _PAIRS)
            from imustation.errors import SettingError

            raise SettingError(
                f"rate_hz = {out['rate_hz']} with bandwidth_hz = {out['bandwidth_hz']}: "
                f"the BMX055 gyro allows rate/bandwidth pairs {pairs}"
            )
        return out

    # -- identity and configuration ------------------------------------------
    def identify(self) -> int:
        chip_id = self.regs.read(REG_CHIP_ID, 1)[0]
        if chip_id != CHIP_ID_VALUE:
            raise ChipIdMismatch("BMX055 gyro", CHIP_ID_VALUE, chip_id, self.regs.where)
        return chip_id

    def configure(self) -> None:
        """Soft reset, normal mode, BW/ODR, range, FIFO stream mode (XYZ frames)."""
        self.regs.write(REG_SOFTRESET, bytes([SOFTRESET_CMD]))
        self._sleep(SOFTRESET_WAIT_S)
        self.identify()
        self.regs.write(REG_LPM1, bytes([LPM1_NORMAL]))
        write_field(self.regs, BW, self._odr.code)
        write_field(self.regs, RANGE, self._range.code)
        self.regs.write(REG_INT_EN_0, bytes([CONFIG_MARKER.encode(1)]))
        bw_back = BW.decode(self.regs.read(BW.reg, 1)[0])
        range_back = RANGE.decode(self.regs.read(RANGE.reg, 1)[0])
        marker_back = CONFIG_MARKER.decode(self.regs.read(REG_INT_EN_0, 1)[0])
        if (bw_back, range_back, marker_back) != (self._odr.code, self._range.code, 1):
            raise DeviceError(
                f"{self.regs.where}: BW/RANGE/data_en read back 0x{bw_back:02X}/0x{range_back:02X}/{marker_back}, "
                f"wrote 0x{self._odr.code:02X}/0x{self._range.code:02X}/1"
            )
        self.regs.write(FIFO_MODE.reg, bytes([FIFO_MODE.encode(FIFO_MODE_STREAM) | FIFO_DATA_SELECT.encode(0)]))
        self._sleep(STARTUP_WAIT_S)
        # the start-up samples are not valid; empty the FIFO once
        self.read_block()

    def open(self) -> DriverInfo:
        chip_id = self.identify()
        self.configure()
        return DriverInfo(
            model="BMX055 gyro (BMG160)",
            identity=f"chip_id=0x{chip_id:02X}",
            rate_hz=float(self._odr.odr_hz),
            settings={
                "rate_hz": float(self._odr.odr_hz),
                "bandwidth_hz": float(self._odr.bandwidth_hz),
                "gyro_range_dps": int(self._range.range_dps),
                "gyro_sensitivity_lsb_per_dps": self._range.lsb_per_dps,
                "bw_code": self._odr.code,
                "range_code": self._range.code,
                "fifo_mode": "stream",
            },
            channels=(
                ChannelSpec("gyro", "int16", "rad/s", self._range.scale, 0.0, ("x", "y", "z")),
                ChannelSpec("temp", "int8", "degC", TEMP_SCALE_C, TEMP_OFFSET_C),
            ),
            has_counter=False,
            # poll when the FIFO is at most 40 % full
            poll_interval_s=0.4 * FIFO_DEPTH_FRAMES / self._odr.odr_hz,
        )

    # -- streaming --------------------------------------------------------------
    def read_rates(self) -> np.ndarray:
        """Burst-read RATE_X_LSB..RATE_Z_MSB: the latest sample, counts (3,)."""
        return decode_rates(self.regs.read(REG_RATE_X_LSB, 6))[0]

    def read_block(self) -> Block:
        # One burst 0x08..0x15 gives TEMP, FIFO_STATUS, the RANGE/BW settings and the
        # data_en marker: a chip that lost its configuration (power glitch, reset) is
        # caught here instead of silently delivering nothing or data at another scale.
        status = self.regs.read(REG_TEMP, REG_INT_EN_0 - REG_TEMP + 1)
        temp_raw = status[0] - 256 if status[0] >= 128 else status[0]
        fifo = status[REG_FIFO_STATUS - REG_TEMP]
        range_code = RANGE.decode(status[RANGE.reg - REG_TEMP])
        bw_code = BW.decode(status[BW.reg - REG_TEMP])
        marker = CONFIG_MARKER.decode(status[REG_INT_EN_0 - REG_TEMP])
        if (range_code, bw_code, marker) != (self._range.code, self._odr.code, 1):
            raise DeviceError(
                f"{self.regs.where}: configuration lost (RANGE/BW/data_en read 0x{range_code:02X}/0x{bw_code:02X}/"
                f"{marker}, set 0x{self._range.code:02X}/0x{self._odr.code:02X}/1); chip reset?"
            )
        count = FIFO_STATUS_COUNT.decode(fifo)
        overrun = bool(FIFO_STATUS_OVERRUN.decode(fifo))
        if count == 0:
            rates = np.zeros((0, 3), dtype=np.int16)
        else:
            rates = decode_rates(self.regs.read(REG_FIFO_DATA, count * FIFO_FRAME_BYTES))
        lost, note = 0, ""
        if overrun:
            # Stream mode kept the newest frames; rewriting FIFO_CONFIG_1 clears the
            # flag (and the FIFO, which was just emptied). The chip cannot say how
            # many frames were lost: -1 asks the station to estimate it from time.
            self.regs.write(FIFO_MODE.reg, bytes([FIFO_MODE.encode(FIFO_MODE_STREAM) | FIFO_DATA_SELECT.encode(0)]))
            lost, note = -1, "FIFO overrun"
        temp = np.full(len(rates), temp_raw, dtype=np.int8)
        return Block({"gyro": rates, "temp": temp}, lost=lost, note=note)

    def close(self) -> None:
        pass
