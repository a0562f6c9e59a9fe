"""InvenSense MPU-6050-family IMUs (MPU-9150, MPU-6500), I2C: one core, chip variants as data.

Register map, tables and worked examples: ``docs/reference/sensors.md`` §2
(MPU-9150 = MPU-6050 register set [L-MPU-C]) and §3 (MPU-6500 differences).
Sources there: Linux ``inv_mpu6050`` [L-MPU-H][L-MPU-C], i2cdevlib [I2CDEV],
the MPU-6050 register map [RM6050], PX4's MPU-6500 driver [PX4-6500].

The chip samples gyro, accelerometer and temperature together; frames of
ACCEL(6) TEMP(2) GYRO(6) = 14 big-endian bytes go through the on-chip FIFO,
read once per poll (at most 40 % full). The FIFO is a byte stream whose size is
not a multiple of 14, so an overflow loses the frame alignment: the driver then
resets the FIFO, drops its contents and reports a lost-sample block (``lost=-1``:
the station measures the loss from time). Field quirks the register maps leave out
are handled as Linux ``inv_mpu6050`` does: overflow is decided by the byte count
(capacity less three frames), never by FIFO_OFLOW_INT, which some chips always set;
the FIFO reset turns the sensors' routing (FIFO_EN, 0x23) off first, so no frame
is being written when the (MPU-6500: asynchronous) reset acts, and the FIFO must
read empty before the routing is turned on again; nothing is written for 10 ms
after SLEEP is cleared; the clock moves to the gyro PLL only once the gyro runs.
Datasheet rules, quirks, sources and tests: ``docs/reference/conformance-invensense.md``.
Only whole frames are read; a partial frame stays in the FIFO for the next poll.
INT_ENABLE doubles as a configuration marker (power-on value 0): a chip reset is
detected on the next poll.

The AK8975 magnetometer of the MPU-9150 (§2.6) is not read.

Over 500 lines on purpose: the register tables of both variants (each row with its
register-map section) sit beside the one driver that reads them.
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
from imustation.drivers.bus.base import RegisterDevice
from imustation.drivers.regs import Field
from imustation.errors import ChipIdMismatch, DeviceError, SettingError
from imustation.units import DEG2RAD, G0

# --- registers (docs/reference/sensors.md §2, §3) --------------------------------
REG_SMPLRT_DIV = 0x19  # rate = internal / (1 + div), §2.2 [I2CDEV][RM6050-p12]
DLPF_CFG = Field(0x1A, 0, 3)  # CONFIG bits2:0, §2.2
CONFIG_FIFO_MODE = Field(0x1A, 6, 1)  # MPU-6500 only: 1 = keep old data when full, §3 [PX4-6500]
GYRO_FS_SEL = Field(0x1B, 3, 2)  # §2.3, shift 3 [L-MPU-H]
GYRO_FCHOICE_B = Field(0x1B, 0, 2)  # MPU-6500 only, 00 = use DLPF_CFG, §3 [PX4-6500][CR]
ACCEL_FS_SEL = Field(0x1C, 3, 2)  # §2.3
A_FCHOICE_B = Field(0x1D, 3, 1)  # MPU-6500 ACCEL_CONFIG2, §3 [PX4-6500][INV-F]
A_DLPF_CFG = Field(0x1D, 0, 3)
REG_FIFO_EN = 0x23  # §2.5: bit7 TEMP, bit6 XG, bit5 YG, bit4 ZG, bit3 ACCEL [I2CDEV][L-MPU-H]
FIFO_EN_TEMP, FIFO_EN_XG, FIFO_EN_YG, FIFO_EN_ZG, FIFO_EN_ACCEL = 0x80, 0x40, 0x20, 0x10, 0x08
FIFO_EN_FRAME = FIFO_EN_TEMP | FIFO_EN_XG | FIFO_EN_YG | FIFO_EN_ZG | FIFO_EN_ACCEL
REG_INT_ENABLE = 0x38  # bit4 FIFO_OFLOW_EN, bit0 DATA_RDY_EN, §2.5 [L-MPU-H][I2CDEV]
INT_FIFO_OFLOW = 0x10  # same bit in INT_ENABLE and INT_STATUS, §2.5
INT_DATA_RDY = 0x01
REG_INT_STATUS = 0x3A  # bit4 FIFO_OFLOW_INT, bit0 DATA_RDY_INT; cleared by reading [RM6050]
REG_ACCEL_XOUT_H = 0x3B  # 0x3B..0x48: ACCEL xyz, TEMP, GYRO xyz, s16 big-endian, §2.4
REG_USER_CTRL = 0x6A  # bit6 FIFO_EN, bit2 FIFO_RST, §2.5 [L-MPU-H]
USER_CTRL_FIFO_EN = 0x40
USER_CTRL_FIFO_RST = 0x04  # 6050 set: resets only while FIFO_EN = 0 (RM-MPU-6000A rev 4.2, Register 106)
REG_PWR_MGMT_1 = 0x6B  # bit7 DEVICE_RESET, bit6 SLEEP, bits2:0 CLKSEL, §2.1
PWR1_DEVICE_RESET = 0x80
PWR1_SLEEP = 0x40
CLKSEL = Field(REG_PWR_MGMT_1, 0, 3)
CLKSEL_INTERNAL = 0  # internal oscillator: the clock while the gyro starts (Linux inv_mpu6050_set_power_itg)
CLKSEL_PLL_XGYRO = 1  # PLL with X gyro reference: recommended over the internal oscillator [I2CDEV]
#: what CLKSEL = 1 selects, per chip (Register 107 of each register map), for the run file's metadata
CLKSEL_1_6050 = "PLL with X axis gyroscope reference"
CLKSEL_1_6500 = "auto: PLL if ready, else internal oscillator"
CLKSEL_STOP = 7
REG_PWR_MGMT_2 = 0x6C  # standby bits; 0 = every axis on, §2.1
REG_FIFO_COUNT_H = 0x72  # byte count, big-endian, read H first, §2.5
REG_FIFO_R_W = 0x74  # FIFO data port
REG_WHO_AM_I = 0x75  # §2.1 / §3

#: one FIFO frame with FIFO_EN_FRAME: ACCEL(6) TEMP(2) GYRO(6) in register order, §2.5
FRAME_BYTES = 14
FRAME_DTYPE = ">i2"  # big-endian s16, §2.4 [L-MPU-C]
#: INT_ENABLE value written; read back every poll as the configuration marker
INT_ENABLE_VALUE = INT_FIFO_OFLOW | INT_DATA_RDY
#: an overflow is decided by the byte count alone: at the capacity less this many frames the
#: FIFO is reset (Linux inv_mpu_ring.c since commit 6e82ae6b8d11 "iio: imu: inv_mpu6050: fix no
#: data on MPU6050": on some chips FIFO_OFLOW_INT is always set, and a driver that trusts it drops
#: every sample; the margin covers the samples written between the count and the data read)
FIFO_MARGIN_FRAMES = 3
#: FIFO resets tried before a FIFO that will not come out empty is an error
FIFO_RESET_TRIES = 3

# --- delays -----------------------------------------------------------------------
#: after DEVICE_RESET before the registers answer again (not in docs/reference/sensors.md; the
#: MPU-6050 register map's 100 ms figure is used for both chips - UNCONFIRMED)
RESET_WAIT_S = 0.100
#: after wake-up before samples are valid: gyro start-up 70 ms (accel 30 ms), §3 [L-MPU-H];
#: also the time the gyro runs before the clock takes it as its PLL reference
STARTUP_WAIT_S = 0.070
#: after clearing SLEEP before the next register write: Linux inv_mpu6050_set_power_itg sleeps
#: INV_MPU6050_REG_UP_TIME_MIN..MAX = 5..10 ms there; a write sooner may be lost
WAKE_WAIT_S = 0.010
#: after wake-up before the temperature is valid: Linux inv_mpu_iio.h INV_MPU6050_TEMP_UP_TIME
#: (100 ms, waited after enabling the temperature sensor; older versions after any sensor): the
#: FIFO, which carries the temperature in every frame, is enabled no sooner
TEMP_UP_WAIT_S = 0.100


# --- tables --------------------------------------------------------------------------
@dataclass(frozen=True)
class DlpfRow:
    code: int
    gyro_bw_hz: float
    accel_bw_hz: float
    internal_hz: float  # gyroscope output rate feeding SMPLRT_DIV
    #: SMPLRT_DIV divides this row's rate (MPU-6500: only for 0 < DLPF_CFG < 7, Register 25)
    div_applies: bool = True


#: MPU-6050/9150 CONFIG.DLPF_CFG, docs/reference/sensors.md §2.2 [I2CDEV] (code 7 reserved)
DLPF_6050: tuple[DlpfRow, ...] = (
    DlpfRow(0, 256, 260, 8000),
    DlpfRow(1, 188, 184, 1000),
    DlpfRow(2, 98, 94, 1000),
    DlpfRow(3, 42, 44, 1000),
    DlpfRow(4, 20, 21, 1000),
    DlpfRow(5, 10, 10, 1000),
    DlpfRow(6, 5, 5, 1000),
)

#: MPU-6500 DLPF_CFG with FCHOICE_B = 00, docs/reference/sensors.md §3 (MPU-9250 map [CR]; direct 6500
#: check UNCONFIRMED); accel: same code in A_DLPF_CFG as Linux does [L-MPU-C], nominal
#: bandwidths 460/184/92/41/20/10/5/460 Hz
DLPF_6500: tuple[DlpfRow, ...] = (
    DlpfRow(0, 250, 460, 8000, div_applies=False),
    DlpfRow(1, 184, 184, 1000),
    DlpfRow(2, 92, 92, 1000),
    DlpfRow(3, 41, 41, 1000),
    DlpfRow(4, 20, 20, 1000),
    DlpfRow(5, 10, 10, 1000),
    DlpfRow(6, 5, 5, 1000),
    DlpfRow(7, 3600, 460, 8000, div_applies=False),
)


@dataclass(frozen=True)
class GyroRange:
    code: int
    range_dps: int
    lsb_per_dps: float

    @property
    def scale(self) -> float:
        """rad/s per LSB."""
        return DEG2RAD / self.lsb_per_dps


@dataclass(frozen=True)
class AccelRange:
    code: int
    range_g: int
    lsb_per_g: float

    @property
    def scale(self) -> float:
        """m/s^2 per LSB."""
        return G0 / self.lsb_per_g


#: GYRO_CONFIG.FS_SEL / ACCEL_CONFIG.AFS_SEL, docs/reference/sensors.md §2.3 [I2CDEV][RM6050-p29] (same on the 6500, §3)
GYRO_RANGES = (GyroRange(0, 250, 131.0), GyroRange(1, 500, 65.5), GyroRange(2, 1000, 32.8), GyroRange(3, 2000, 16.4))
ACCEL_RANGES = (
    AccelRange(0, 2, 16384.0),
    AccelRange(1, 4, 8192.0),
    AccelRange(2, 8, 4096.0),
    AccelRange(3, 16, 2048.0),
)

#: the SMPLRT_DIV register is 8 bits
MAX_DIV = 255
#: the accelerometer output rate; above it samples repeat, §2.2 [RM6050-p12]
ACCEL_OUTPUT_HZ = 1000.0
#: the chips' I2C runs at most in fast mode, 400 kHz (I2C timing tables of the MPU-6000/6050 and
#: MPU-6500 product specifications); a byte takes 9 SCL clocks (8 bits + ACK)
I2C_MAX_HZ = 400_000
I2C_CLOCKS_PER_BYTE = 9
#: the fastest sample rate whose FIFO frames an otherwise idle I2C bus can carry, Hz
MAX_I2C_RATE_HZ = I2C_MAX_HZ / (14 * I2C_CLOCKS_PER_BYTE)


@dataclass(frozen=True)
class Variant:
    """What differs between the chips of the family (one row per chip)."""

    driver: str
    model: str
    who_am_i: int
    fifo_bytes: int
    temp_lsb_per_c: float  # T = raw / temp_lsb_per_c + temp_offset_c
    temp_offset_c: float
    dlpf: tuple[DlpfRow, ...]
    #: MPU-6500 has ACCEL_CONFIG2 (0x1D), GYRO_CONFIG.FCHOICE_B and CONFIG.FIFO_MODE
    has_accel_config2: bool
    #: PWR_MGMT_1 after power-on (the simulator's; the driver always writes it)
    por_pwr_mgmt_1: int
    default_bandwidth_hz: float
    #: what CLKSEL = 1 (the driver's clock) means on this chip (Register 107)
    clock_source: str
    #: the register map whose rules this row follows (named in error messages)
    register_map: str
    #: USER_CTRL.FIFO_RST acts only while USER_CTRL.FIFO_EN is 0, and FIFO_EN = 0 stops
    #: FIFO writes (MPU-6050 set); else FIFO_RST is asynchronous and FIFO_EN = 0 only
    #: stops serial access (MPU-6500). The driver's reset sequence suits both.
    fifo_rst_needs_disable: bool
    #: CLKSEL = 1 is the X-gyro PLL with no fallback (MPU-6050 set): the gyro must run before
    #: it is selected (Linux inv_mpu6050_switch_engine); the MPU-6500's CLKSEL = 1 falls back
    #: to the internal oscillator until the PLL is ready (Register 107)
    pll_needs_running_gyro: bool

    @property
    def fifo_frames(self) -> int:
        return self.fifo_bytes // FRAME_BYTES

    @property
    def overflow_bytes(self) -> int:
        """A FIFO holding this many bytes is treated as overflowed (capacity less the margin)."""
        return self.fifo_bytes - FIFO_MARGIN_FRAMES * FRAME_BYTES


MPU9150 = Variant(
    driver="mpu9150",
    model="InvenSense MPU-9150 (MPU-6050 core)",
    who_am_i=0x68,  # §2.1 [L-MPU-H]
    fifo_bytes=1024,  # §2.5 [L-MPU-C]
    temp_lsb_per_c=340.0,  # T = raw/340 + 36.53, §2.4 [DIN]
    temp_offset_c=36.53,
    dlpf=DLPF_6050,
    has_accel_config2=False,
    por_pwr_mgmt_1=PWR1_SLEEP,  # powers up asleep, §2.1 [I2CDEV]
    default_bandwidth_hz=42,
    clock_source=CLKSEL_1_6050,
    register_map="MPU-6000/6050 Register Map rev 4.2",
    fifo_rst_needs_disable=True,  # RM-MPU-6000A rev 4.2, Register 106
    pll_needs_running_gyro=True,  # RM-MPU-6000A Register 107; Linux inv_mpu6050_switch_engine
)

MPU6500 = Variant(
    driver="mpu6500",
    model="InvenSense MPU-6500",
    who_am_i=0x70,  # §3 [L-MPU-H][PX4-6500]
    fifo_bytes=512,  # §3 [L-MPU-C][PX4-6500]
    temp_lsb_per_c=333.87,  # T = raw/333.87 + 21.0, §3 [PX4-6500]
    temp_offset_c=21.0,
    dlpf=DLPF_6500,
    has_accel_config2=True,
    # the MPU-6500 register map lists PWR_MGMT_1 reset value 0x01 (awake, auto clock): not
    # in docs/reference/sensors.md, UNCONFIRMED; only the simulator uses it
    por_pwr_mgmt_1=0x01,
    default_bandwidth_hz=41,
    clock_source=CLKSEL_1_6500,
    register_map="MPU-6500 Register Map rev 2.1",
    fifo_rst_needs_disable=False,  # RM-MPU-6500A rev 2.1, Register 106: "Reset is asynchronous"
    pll_needs_running_gyro=False,  # RM-MPU-6500A Register 107: "PLL if ready, else internal oscillator"
)

VARIANTS = {v.driver: v for v in (MPU9150, MPU6500)}


def decode_frames(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """14-byte frames (FIFO, or registers 0x3B..0x48) -> (accel (k,3), temp (k,), gyro (k,3)) int16."""
    words = np.frombuffer(data, dtype=FRAME_DTYPE).reshape(-1, 7).astype(np.int16)
    return words[:, 0:3], words[:, 3], words[:, 4:7]


def decode_temperature(raw: int, variant: Variant) -> float:
    """TEMP_OUT (s16) -> degC with the variant's constants (docs/reference/sensors.md §2.4, §3)."""
    return raw / variant.temp_lsb_per_c + variant.temp_offset_c


def _rates_of(rows: list[DlpfRow]) -> str:
    """'bandwidth_hz 184, 92 give 1000/(1+div) Hz' for rows of one internal rate."""
    bws = ", ".join(f"{r.gyro_bw_hz:g}" for r in rows)
    internal = int(rows[0].internal_hz)
    rate = f"{internal}/(1+div) Hz" if rows[0].div_applies else f"{internal} Hz"
    return f"bandwidth_hz {bws} give {rate}"


def sample_divider(variant: Variant, rate_hz: float, bandwidth_hz: float) -> tuple[DlpfRow, int]:
    """(DLPF row, SMPLRT_DIV) for a rate (Hz) and gyro bandwidth (Hz); SettingError if the chip cannot run so.

    The sample rate is the gyro output rate / (1 + SMPLRT_DIV); on the MPU-6500 the
    divider is ignored for DLPF_CFG 0 and 7 (Register 25), so those rows give their
    8 kHz and nothing else.
    """
    row = next(r for r in variant.dlpf if r.gyro_bw_hz == bandwidth_hz)
    groups: dict[tuple[float, bool], list[DlpfRow]] = {}
    for r in variant.dlpf:
        if (r.internal_hz, r.div_applies) != (row.internal_hz, row.div_applies):
            groups.setdefault((r.internal_hz, r.div_applies), []).append(r)
    others = "; ".join(_rates_of(rows) for rows in groups.values())
    internal = int(row.internal_hz)
    if not row.div_applies:
        if math.isclose(row.internal_hz, rate_hz, rel_tol=1e-9):
            return row, 0
        raise SettingError(
            f"rate_hz = {rate_hz:g} with bandwidth_hz = {bandwidth_hz:g}: with this filter (DLPF_CFG {row.code}) the "
            f"{variant.model} samples at {internal} Hz and ignores SMPLRT_DIV ({variant.register_map}, Register 25: "
            f"the divider applies only for 0 < DLPF_CFG < 7); {others}"
        )
    div = round(row.internal_hz / float(rate_hz) - 1.0)
    if not (0 <= div <= MAX_DIV and math.isclose(row.internal_hz / (1 + div), rate_hz, rel_tol=1e-6)):
        examples = ", ".join(f"{internal / (1 + d):g}" for d in (0, 1, 2, 3, 4, 7, 9, 19))
        raise SettingError(
            f"rate_hz = {rate_hz:g} with bandwidth_hz = {bandwidth_hz:g}: the {variant.model} samples at "
            f"{internal}/(1+div) Hz, div 0..{MAX_DIV} ({examples}, ...); {others}"
        )
    return row, div


def check_bus_throughput(variant: Variant, rate_hz: float, bandwidth_hz: float) -> None:
    """SettingError if the FIFO frames at ``rate_hz`` (Hz) need more than the chip's 400 kHz I2C."""
    if rate_hz <= MAX_I2C_RATE_HZ:
        return
    row = next(r for r in variant.dlpf if r.gyro_bw_hz == bandwidth_hz)
    need_kbit = rate_hz * FRAME_BYTES * I2C_CLOCKS_PER_BYTE / 1000
    hint = (
        f"bandwidth_hz {bandwidth_hz:g} runs the chip at {row.internal_hz:g} Hz only: choose another bandwidth"
        if not row.div_applies
        else f"at most {math.floor(MAX_I2C_RATE_HZ)} Hz, e.g. {row.internal_hz / 3:g} (div 2) or 1000"
    )
    raise SettingError(
        f"rate_hz = {rate_hz:g}: {FRAME_BYTES}-byte FIFO frames at that rate need {need_kbit:g} kbit/s of I2C "
        f"({I2C_CLOCKS_PER_BYTE} clocks per byte), more than the {variant.model}'s 400 kHz fast-mode bus carries; "
        f"{hint}"
    )


class InvenSenseIMU:
    """Gyro + accelerometer + temperature through the FIFO; subclasses name a :class:`Variant`.

    Parameters
    ----------
    regs : register device at the chip's I2C address (0x68, or 0x69 with AD0 high).
    settings : validated by :meth:`check_settings`: ``rate_hz``, ``bandwidth_hz``
        (gyro DLPF bandwidth, Hz), ``gyro_range_dps``, ``accel_range_g``.
    sleep : delay function (the station's clock, virtual in simulation).
    """

    VARIANT: ClassVar[Variant]
    name: ClassVar[str]
    bus_kind: ClassVar[str] = "i2c"
    default_address: ClassVar[int] = 0x68  # AD0 low, §2.1 [I2CDEV]
    SETTINGS: ClassVar[tuple[Setting, ...]]

    @classmethod
    def settings_table(cls, variant: Variant) -> tuple[Setting, ...]:
        return (
            Setting("rate_hz", 200.0, None, "sample rate, Hz: internal/(1+div)"),
            Setting("bandwidth_hz", variant.default_bandwidth_hz, tuple(r.gyro_bw_hz for r in variant.dlpf),
                    "gyro DLPF bandwidth, Hz"),
            Setting("gyro_range_dps", 250, tuple(r.range_dps for r in GYRO_RANGES), "gyro full scale, deg/s"),
            Setting("accel_range_g", 2, tuple(r.range_g for r in ACCEL_RANGES), "accel full scale, g"),
        )  # fmt: skip

    def __init__(self, regs: RegisterDevice, settings: Mapping[str, Any], *, sleep: Sleep = time.sleep):
        self.regs = regs
        self.settings = self.check_settings(settings)
        self._sleep = sleep
        v = self.VARIANT
        self._dlpf, self._div = sample_divider(v, self.settings["rate_hz"], self.settings["bandwidth_hz"])
        self._gyro = next(r for r in GYRO_RANGES if r.range_dps == self.settings["gyro_range_dps"])
        self._accel = next(r for r in ACCEL_RANGES if r.range_g == self.settings["accel_range_g"])
        self.rate_hz = self._dlpf.internal_hz / (1 + self._div)
        self._stuck = False

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        out = check_settings(cls.name, cls.SETTINGS, settings)
        rate = out["rate_hz"]
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not rate > 0:
            raise SettingError(f"rate_hz = {rate!r}: a positive number of Hz")
        sample_divider(cls.VARIANT, rate, out["bandwidth_hz"])
        check_bus_throughput(cls.VARIANT, rate, out["bandwidth_hz"])
        return out

    # -- register values ---------------------------------------------------------------
    def _config_bytes(self) -> bytes:
        """SMPLRT_DIV, CONFIG, GYRO_CONFIG, ACCEL_CONFIG[, ACCEL_CONFIG2] as written (0x19..)."""
        out = [
            self._div,
            DLPF_CFG.encode(self._dlpf.code),  # 6500: FIFO_MODE 0 = overwrite oldest, as on the 6050
            GYRO_FS_SEL.encode(self._gyro.code),  # 6500: FCHOICE_B 00 = use DLPF_CFG
            ACCEL_FS_SEL.encode(self._accel.code),
        ]
        if self.VARIANT.has_accel_config2:
            out.append(A_FCHOICE_B.encode(0) | A_DLPF_CFG.encode(self._dlpf.code))
        return bytes(out)

    # -- identity and configuration ----------------------------------------------------
    def identify(self) -> int:
        who = self.regs.read(REG_WHO_AM_I, 1)[0]
        if who != self.VARIANT.who_am_i:
            raise ChipIdMismatch(self.VARIANT.model, self.VARIANT.who_am_i, who, self.regs.where)
        return who

    def configure(self) -> None:
        """Reset, wake on the internal oscillator, rate/filter/ranges, gyro PLL once the gyro runs, FIFO on.

        The order is Linux inv_mpu6050's: after clearing SLEEP nothing is written for
        ``WAKE_WAIT_S`` (a write sooner may be lost); the clock is switched to the gyro PLL only
        after the gyro has run its start-up time (``STARTUP_WAIT_S``); the FIFO is enabled only
        once the temperature is valid too (``TEMP_UP_WAIT_S`` after waking), so no start-up
        sample enters it. Every setting is read back.
        """
        self.regs.write(REG_PWR_MGMT_1, bytes([PWR1_DEVICE_RESET]))
        self._sleep(RESET_WAIT_S)
        self.identify()
        self.regs.write(REG_PWR_MGMT_1, bytes([CLKSEL.encode(CLKSEL_INTERNAL)]))  # SLEEP = 0
        self._sleep(WAKE_WAIT_S)
        self.regs.write(REG_PWR_MGMT_2, bytes([0]))
        config = self._config_bytes()
        self.regs.write(REG_SMPLRT_DIV, config)
        self.regs.write(REG_INT_ENABLE, bytes([INT_ENABLE_VALUE]))
        self._read_back(config, CLKSEL.encode(CLKSEL_INTERNAL))
        self._sleep(STARTUP_WAIT_S)  # the gyro runs (on the internal oscillator)
        self.regs.write(REG_PWR_MGMT_1, bytes([CLKSEL.encode(CLKSEL_PLL_XGYRO)]))
        self._read_back(config, CLKSEL.encode(CLKSEL_PLL_XGYRO))
        self._sleep(max(0.0, TEMP_UP_WAIT_S - WAKE_WAIT_S - STARTUP_WAIT_S))  # the temperature is valid
        self._reset_fifo()  # leaves FIFO_EN routing and USER_CTRL.FIFO_EN set
        self.regs.read(REG_INT_STATUS, 1)  # clear the flags the start-up raised
        self._stuck = False

    def _read_back(self, config: bytes, power: int) -> None:
        """DeviceError unless SMPLRT_DIV.. and PWR_MGMT_1 read as written."""
        back = self.regs.read(REG_SMPLRT_DIV, len(config))
        got = self.regs.read(REG_PWR_MGMT_1, 1)[0]
        if back != config or got != power:
            raise DeviceError(
                f"{self.regs.where}: configuration read back {back.hex(' ')} / PWR_MGMT_1 0x{got:02X}, "
                f"wrote {config.hex(' ')} / 0x{power:02X}"
            )

    def _reset_fifo(self) -> None:
        """Empty the FIFO in frame: routing off, FIFO reset, check it is empty, routing on.

        The order is Linux inv_mpu6050's (``inv_mpu6050_prepare_fifo``): FIFO_EN (0x23) ← 0 so
        no sensor is writing a frame into the FIFO when it is reset (the MPU-6500's reset is
        asynchronous: a frame being written would leave its tail at the head of the FIFO, and
        every frame after it would be read shifted); USER_CTRL ← 0, ← FIFO_RST (the MPU-6050
        set resets only while USER_CTRL.FIFO_EN is 0, Register 106). Then the FIFO must read
        empty while nothing routes into it - a known instant at which the byte count must be
        zero, checked after every reset (repeated up to ``FIFO_RESET_TRIES`` times, then a
        DeviceError); only then FIFO_EN ← the frame's sensors and USER_CTRL ← FIFO_EN. Whole
        samples are written from there on, so the FIFO holds whole frames from its head.
        """
        self.regs.write(REG_FIFO_EN, bytes([0]))
        for _ in range(FIFO_RESET_TRIES):
            self.regs.write(REG_USER_CTRL, bytes([0]))
            self.regs.write(REG_USER_CTRL, bytes([USER_CTRL_FIFO_RST]))
            left = int.from_bytes(self.regs.read(REG_FIFO_COUNT_H, 2), "big")
            if left == 0:
                break
        else:
            raise DeviceError(
                f"{self.regs.where}: FIFO holds {left} bytes after {FIFO_RESET_TRIES} resets with no sensor routed "
                "into it; its frames cannot be aligned"
            )
        self.regs.write(REG_FIFO_EN, bytes([FIFO_EN_FRAME]))
        self.regs.write(REG_USER_CTRL, bytes([USER_CTRL_FIFO_EN]))

    def open(self) -> DriverInfo:
        who = self.identify()
        self.configure()
        v = self.VARIANT
        return DriverInfo(
            model=v.model,
            identity=f"who_am_i=0x{who:02X}",
            rate_hz=self.rate_hz,
            settings={
                "rate_hz": self.rate_hz,
                "bandwidth_hz": float(self._dlpf.gyro_bw_hz),
                "accel_bandwidth_hz": float(self._dlpf.accel_bw_hz),
                "internal_rate_hz": float(self._dlpf.internal_hz),
                "smplrt_div": self._div,
                "dlpf_cfg": self._dlpf.code,
                "gyro_range_dps": self._gyro.range_dps,
                "gyro_fs_sel": self._gyro.code,
                "gyro_sensitivity_lsb_per_dps": self._gyro.lsb_per_dps,
                "accel_range_g": self._accel.range_g,
                "accel_fs_sel": self._accel.code,
                "accel_sensitivity_lsb_per_g": self._accel.lsb_per_g,
                "clock_source": f"{v.clock_source} (CLKSEL = {CLKSEL_PLL_XGYRO})",
                "fifo": "accel+temp+gyro, 14-byte frames",
                "fifo_bytes": v.fifo_bytes,
            },
            channels=(
                ChannelSpec("gyro", "int16", "rad/s", self._gyro.scale, 0.0, ("x", "y", "z")),
                ChannelSpec("accel", "int16", "m/s^2", self._accel.scale, 0.0, ("x", "y", "z")),
                ChannelSpec("temp", "int16", "degC", 1.0 / v.temp_lsb_per_c, v.temp_offset_c),
            ),
            has_counter=False,
            # at most 40 % of the FIFO, a whole number of sample periods
            poll_interval_s=math.floor(0.4 * v.fifo_frames) / self.rate_hz,
        )

    # -- streaming -----------------------------------------------------------------------
    def read_block(self) -> Block:
        """FIFO_COUNT, the whole frames, FIFO_COUNT again, then INT_ENABLE..INT_STATUS.

        An overflow is decided by the byte count, never by FIFO_OFLOW_INT (always set on
        some chips, Linux commit 6e82ae6b8d11): the FIFO is reset and its contents dropped
        when it held ``Variant.overflow_bytes`` or more - at the first count, or, counted
        again after the data, the bytes read plus those left (an overflow while the poll
        read: a stalled host; the 14-byte frames in the byte FIFO are then shifted).
        """
        v = self.VARIANT
        count = int.from_bytes(self.regs.read(REG_FIFO_COUNT_H, 2), "big")  # H first: latches both
        full = count >= v.overflow_bytes
        frames = 0 if full else count // FRAME_BYTES  # a partial frame stays for the next poll
        data = self.regs.read(REG_FIFO_R_W, frames * FRAME_BYTES) if frames else b""
        after = int.from_bytes(self.regs.read(REG_FIFO_COUNT_H, 2), "big") if frames else 0
        head = self.regs.read(REG_INT_ENABLE, REG_INT_STATUS - REG_INT_ENABLE + 1)
        if head[0] != INT_ENABLE_VALUE:
            raise DeviceError(
                f"{self.regs.where}: configuration lost (INT_ENABLE reads 0x{head[0]:02X}, "
                f"set 0x{INT_ENABLE_VALUE:02X}); chip reset?"
            )
        status = head[-1]
        empty = np.zeros((0, 3), dtype=np.int16)
        if full or after + len(data) >= v.overflow_bytes:
            # oldest bytes were (or may have been) overwritten: frame alignment is gone
            self._reset_fifo()
            self._stuck = False
            held = max(count, after + len(data))
            note = f"FIFO overrun ({held} of {v.fifo_bytes} bytes); FIFO reset, contents dropped"
            return Block({"gyro": empty, "accel": empty, "temp": np.zeros(0, np.int16)}, lost=-1, note=note)
        lost, note = 0, ""
        if frames:
            accel, temp, gyro = decode_frames(data)
            if self._stuck:
                self._stuck = False
                lost, note = -1, "FIFO stopped filling (data ready without FIFO data); reset"
        else:
            accel, temp, gyro = empty, np.zeros(0, np.int16), empty
            if status & INT_DATA_RDY and count == 0:
                # new samples were taken but none reached the FIFO: it stopped filling.
                # Reset it; the loss is reported once, when frames arrive again.
                self._reset_fifo()
                self._stuck = True
        return Block({"gyro": gyro, "accel": accel, "temp": temp}, lost=lost, note=note)

    def close(self) -> None:
        pass


class MPU9150Driver(InvenSenseIMU):
    """MPU-9150 (MPU-6050 register set, WHO_AM_I 0x68, 1024-byte FIFO)."""

    VARIANT = MPU9150
    name = "mpu9150"
    SETTINGS = InvenSenseIMU.settings_table(MPU9150)


class MPU6500Driver(InvenSenseIMU):
    """MPU-6500 (WHO_AM_I 0x70, 512-byte FIFO, ACCEL_CONFIG2)."""

    VARIANT = MPU6500
    name = "mpu6500"
    SETTINGS = InvenSenseIMU.settings_table(MPU6500)
