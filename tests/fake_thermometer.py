"""A small stand-in for the MCP9804 thermometer driver and simulator (tests only).

The real driver is written on another branch; this fake keeps to the interface
the station uses (``check_settings``/``open``/``read_celsius``/``close`` and
``make_thermometer_simulator``) and to the chip's T_A register format
(sensors.md §7: pointer 0x05, 13-bit two's complement, 0.0625 degC/LSB, MSB
first), so the station side is exercised over a simulated I2C bus.
"""

from __future__ import annotations

import math
from typing import ClassVar

from imustation.drivers.sim.faults import FaultPlan, parse_faults
from imustation.errors import DeviceError, SettingError

REG_TA = 0x05  # sensors.md §7
REG_MANUFACTURER = 0x06  # reads 0x0054
MANUFACTURER_ID = 0x0054
LSB_C = 0.0625
TEMP_BITS = 13


class FakeThermometer:
    name: ClassVar[str] = "fakethermo"
    bus_kind: ClassVar[str] = "i2c"
    default_address: ClassVar[int] = 0x18

    @classmethod
    def check_settings(cls, settings) -> dict:
        out = {"rate_hz": 1.0}
        for key, value in settings.items():
            if key != "rate_hz":
                raise SettingError(f"{key}: not a setting of driver 'fakethermo' (known: rate_hz)")
            if not isinstance(value, (int, float)) or not 0 < value <= 10:
                raise SettingError(f"rate_hz = {value!r}: 0 < rate_hz <= 10")
            out["rate_hz"] = float(value)
        return out

    def __init__(self, regs, settings, *, sleep):
        self.regs = regs
        self.settings = self.check_settings(settings)

    def open(self) -> str:
        mid = int.from_bytes(self.regs.read(REG_MANUFACTURER, 2), "big")
        if mid != MANUFACTURER_ID:
            raise DeviceError(f"{self.regs.where}: manufacturer id 0x{mid:04X}")
        return f"manufacturer=0x{mid:04X}"

    def read_celsius(self) -> float:
        raw = int.from_bytes(self.regs.read(REG_TA, 2), "big") & ((1 << TEMP_BITS) - 1)
        if raw & (1 << (TEMP_BITS - 1)):
            raw -= 1 << TEMP_BITS
        return raw * LSB_C

    def close(self) -> None:
        pass


class FakeThermometerSim:
    """16-bit registers behind a pointer (sensors.md §7); T_A follows
    ``base_c + 0.5 sin(2 pi t / 1 h)`` on the station clock."""

    def __init__(self, clock, base_c: float):
        self.clock, self.base_c = clock, base_c
        self.words = {REG_MANUFACTURER: MANUFACTURER_ID, REG_TA: 0}
        self.pointer = 0
        self.sim_reads = 0

    def i2c_write(self, data: bytes) -> None:
        self.pointer = data[0] & 0x0F

    def i2c_read(self, n: int) -> bytes:
        if self.pointer == REG_TA:
            self.sim_reads += 1
            t = self.clock.now_ns() / 1e9
            c = self.base_c + 0.5 * math.sin(2 * math.pi * t / 3600.0)
            self.words[REG_TA] = round(c / LSB_C) & ((1 << TEMP_BITS) - 1)
        return self.words.get(self.pointer, 0).to_bytes(2, "big")[:n]


def make_fake_thermometer_simulator(driver, clock, settings, sim, seed):
    plan = FaultPlan(parse_faults(sim.get("faults", [])), clock, seed) if sim.get("faults") else None
    return FakeThermometerSim(clock, 20.0 + seed % 10), plan


def install(monkeypatch) -> None:
    """Register the fake driver and simulator factory for one test."""
    import imustation.drivers as drivers
    import imustation.drivers.sim as sim

    monkeypatch.setitem(drivers.THERMOMETER_DRIVERS, "fakethermo", FakeThermometer)
    monkeypatch.setattr(sim, "make_thermometer_simulator", make_fake_thermometer_simulator, raising=False)
