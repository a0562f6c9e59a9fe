"""docs/hardware.md's facts table against the drivers' constants, and its set-up steps against the commands."""

from __future__ import annotations

import re
from pathlib import Path

from imustation.acquisition import setupfiles
from imustation.acquisition.doctor import PROBE_BAUDS
from imustation.drivers import adis16448, bmx055, bmx055_accel, invensense, kvh_dsp3000, mcp9804, xsens_mti
from imustation.drivers.bus import spi_cp2130, spi_mcp2210

DOC = Path(__file__).resolve().parents[1] / "docs" / "hardware.md"


def facts() -> dict[str, str]:
    text = DOC.read_text()
    table = text.split("## Facts the drivers rely on", 1)[1]
    rows = [line for line in table.splitlines() if line.startswith("| ") and not line.startswith("| fact")]
    return {cells[0]: cells[1] for cells in ([c.strip() for c in row.strip("|").split("|")] for row in rows)}


def hexaddr(v: int) -> str:
    return f"0x{v:02X}"


def mhz(hz: float) -> str:
    return f"{hz / 1e6:g} MHz"


#: each fact of the table, from the code
FROM_CODE = {
    "BMX055 gyroscope default I2C address (SDO2 low)": lambda: hexaddr(bmx055.BMX055Gyro.default_address),
    "BMX055 accelerometer default I2C address (SDO1 low)": lambda: hexaddr(bmx055_accel.BMX055Accel.default_address),
    "MPU-9150 / MPU-6500 default I2C address (AD0 low)": lambda: hexaddr(invensense.InvenSenseIMU.default_address),
    "MCP9804 default I2C address (A2..A0 = 000)": lambda: hexaddr(mcp9804.MCP9804.default_address),
    "ADIS16448 SPI mode": lambda: str(adis16448.SPI_MODE),
    "ADIS16448 SCLK limit, register access": lambda: mhz(adis16448.SPI_MAX_HZ_REGISTER),
    "ADIS16448 SCLK limit, burst read": lambda: mhz(adis16448.SPI_MAX_HZ_BURST),
    "CP2130 clock used for a 1 MHz cap": lambda: f"{spi_cp2130.CLOCKS_HZ[spi_cp2130.clock_code(1e6)] / 1e3:g} kHz",
    "CP2130 USB VID:PID": lambda: f"{spi_cp2130.CP2130.DEFAULT_VID:04X}:{spi_cp2130.CP2130.DEFAULT_PID:04X}",
    "MCP2210 USB VID:PID": lambda: f"{spi_mcp2210.MCP2210.DEFAULT_VID:04X}:{spi_mcp2210.MCP2210.DEFAULT_PID:04X}",
    "Xsens USB VID": lambda: f"{setupfiles.XSENS_VID:04X}",
    "MTi factory baud rate": lambda: str(xsens_mti.FACTORY_BAUD),
    "MTi MTData2 message length of the driver's output": lambda: f"{xsens_mti.frame_length(xsens_mti.LAYOUT)} bytes",
    "MTi fastest output rate at the factory baud rate": lambda: f"{xsens_mti.fastest_rate(xsens_mti.FACTORY_BAUD)} Hz",
    "MTi internal rate the output rates divide": lambda: f"{xsens_mti.BASE_RATE_HZ} Hz",
    "DSP-3000 baud rate": lambda: str(kvh_dsp3000.KVHDSP3000.default_baud),
    "DSP-3000 nominal output rate": lambda: f"{kvh_dsp3000.NOMINAL_RATE_HZ:g} Hz",
}


def test_every_fact_matches_its_driver_constant():
    doc = facts()
    assert set(doc) == set(FROM_CODE), set(doc) ^ set(FROM_CODE)
    wrong = {k: (doc[k], FROM_CODE[k]()) for k in doc if doc[k] != FROM_CODE[k]()}
    assert not wrong, wrong


def test_prose_agrees_with_the_code():
    text = DOC.read_text()
    # the baud rates devices tries, in its order
    assert ", ".join(map(str, PROBE_BAUDS)) in text
    # the udev rules' groups and the Xsens FTDI range
    pids = setupfiles.XSENS_FTDI_PIDS
    assert f"PIDs 0x{pids[0]:04X}–0x{pids[-1]:04X}" in text
    for group in (setupfiles.I2C_GROUP, setupfiles.USB_GROUP, setupfiles.SERIAL_GROUP):
        assert group in text
    # the service's grants
    assert f"LimitRTPRIO={setupfiles.SERVICE_RTPRIO}" in text and f"Nice={setupfiles.SERVICE_NICE}" in text
    assert f"TimeoutStopSec={setupfiles.SERVICE_STOP_TIMEOUT_S}" in text
    # every CP2130 clock is listed
    listed = re.search(r"fixed clocks \(([^)]*)\)", text.replace("\n", " "))
    assert listed is not None
    assert "12, 6, 3, 1.5 MHz, 750, 375, 187.5, 93.75 kHz" in listed.group(1)
    assert [c / 1e3 for c in spi_cp2130.CLOCKS_HZ] == [12000, 6000, 3000, 1500, 750, 375, 187.5, 93.75]
