"""ADIS16448: byte-level checks against docs/reference/sensors.md §4 worked examples, driver through both bridges."""

import numpy as np
import pytest

from imustation.clock import VirtualClock
from imustation.drivers import adis16448 as adis
from imustation.drivers.bus.spi_open import open_spi
from imustation.drivers.sim.adis16448 import ADIS16448Sim, burst_crc_rows
from imustation.drivers.sim.faults import FaultPlan, FaultSpec
from imustation.drivers.sim.sources import NoiseSource
from imustation.drivers.sim.spi_bridges import CP2130Sim, MCP2210Sim
from imustation.drivers.sim.usb_backend import SimUSBBackend
from imustation.errors import BusError, ChipIdMismatch, DeviceError, SettingError
from imustation.units import DEG2RAD, G0

JC_BYTES = bytes.fromhex("0F 00 F8 FF 0A 00 41 FE CC FF 56 04 27 02 A3 FD 12 F4 3C C1 6C FF")  # LSB first
JC_BURST = bytes.fromhex("00 00 00 0F FF F8 00 0A FE 41 FF CC 04 56 02 27 FD A3 F4 12 C1 3C FF 6C 9A F4")


def crc_bitwise(lsb_first: bytes) -> int:
    """Independent oracle: the bitwise loop exactly as docs/reference/sensors.md §4.6 states it."""
    crc = 0xFFFF
    for byte in lsb_first:
        for _ in range(8):
            crc = (crc >> 1) ^ 0x1021 if (crc ^ byte) & 1 else crc >> 1
            byte >>= 1
    crc = ~crc & 0xFFFF
    return ((crc << 8) | (crc >> 8)) & 0xFFFF


def msb_first(words):
    return b"".join(w.to_bytes(2, "big") for w in words)


def test_crc_reference_vectors():
    assert crc_bitwise(JC_BYTES) == 0x9AF4  # [JC] crc16adis.m
    words = [int.from_bytes(JC_BYTES[i : i + 2], "little") for i in range(0, 22, 2)]
    assert adis.burst_crc(msb_first(words)) == 0x9AF4
    second = [0x0019, 0xFFE7, 0, 0, 0, 0x04B0, 0x0007, 0, 0xFFF9, 0xC5E6, 0x00D8]
    assert adis.burst_crc(msb_first(second)) == 0x09E6 == crc_bitwise(b"".join(w.to_bytes(2, "little") for w in second))
    rng = np.random.default_rng(1)
    rows = rng.integers(0, 65536, (50, 11)).astype(np.uint16)
    expect = [crc_bitwise(b"".join(int(w).to_bytes(2, "little") for w in r)) for r in rows]
    assert burst_crc_rows(rows).tolist() == expect


def test_full_burst_example_and_scales():
    diag, *rest = adis.BURST.unpack(JC_BURST[:24])
    assert diag == 0 and adis.burst_crc(JC_BURST[2:24]) == int.from_bytes(JC_BURST[24:], "big")
    # §4.4 examples
    assert 25 * 0.04 == pytest.approx(1.00)
    assert 1200 * adis.ACCEL_G_PER_LSB == pytest.approx(1.0)
    assert 7 * adis.MAG_GAUSS_PER_LSB * 1e3 == pytest.approx(1.0)
    assert adis.decode_temperature(0x0FFF) == pytest.approx(30.926, abs=1e-3)
    assert adis.decode_temperature(0x00D8) == pytest.approx(46.95, abs=1e-2)
    assert adis.decode_temperature(0xFF6C) == pytest.approx(20.069, abs=1e-3)
    assert 50662 * adis.BARO_MBAR_PER_LSB == pytest.approx(1013.24)


def test_diag_decoding():
    assert adis.decode_diag(0) == []
    assert adis.decode_diag((1 << 3) | (1 << 15)) == ["Z accelerometer self-test failure", "SPI communication failure"]


class RecordingSPI:
    def __init__(self, inner):
        self.inner, self.frames = inner, []
        self.where, self.mode, self.hz = inner.where, inner.mode, inner.hz

    def transfer(self, tx):
        rx = self.inner.transfer(tx)
        self.frames.append((bytes(tx), rx))
        return rx

    def transfer_frames(self, frames, gap_s):
        rx = self.inner.transfer_frames(frames, gap_s)  # the bridge keeps CS high for gap_s between them
        self.frames += [(bytes(tx), r) for tx, r in zip(frames, rx, strict=True)]
        return rx

    def ensure_open(self):
        self.inner.ensure_open()
        self.hz = self.inner.hz

    def close(self):
        self.inner.close()


def rig(scheme="cp2130", settings=None, faults=(), mode=None, seed=4):
    clock = VirtualClock()
    plan = FaultPlan(list(faults), clock) if faults else None
    chip = ADIS16448Sim(clock, lambda fs: NoiseSource.for_device("adis16448", "xyz", fs, {}, seed), plan)
    fn = CP2130Sim("1", plan) if scheme == "cp2130" else MCP2210Sim("1", plan)
    fn.attach(0, chip)
    spi = open_spi(
        f"{scheme}:", mode=adis.SPI_MODE if mode is None else mode, sleep=clock.sleep, backend=SimUSBBackend([fn])
    )
    rec = RecordingSPI(spi)
    drv = adis.ADIS16448(rec, settings or {}, sleep=clock.sleep)
    drv.clock_ns = clock.now_ns  # as the station sets it: every burst is stamped
    return drv, rec, chip, clock


def test_register_frames_match_worked_examples():
    drv, rec, _, _ = rig()
    rec.ensure_open()
    assert drv.read_regs([adis.REG_PROD_ID]) == [0x4040]
    assert [tx for tx, _ in rec.frames] == [bytes.fromhex("56 00"), bytes.fromhex("00 00")]
    assert rec.frames[1][1] == bytes.fromhex("40 40")  # data comes on the next frame
    rec.frames.clear()
    drv.write_reg(adis.REG_SMPL_PRD, 0x0201)
    assert [tx for tx, _ in rec.frames] == [bytes.fromhex("B6 01"), bytes.fromhex("B7 02")]
    assert drv.read_regs([adis.REG_SMPL_PRD]) == [0x0201]


@pytest.mark.parametrize("scheme", ["cp2130", "mcp2210"])
def test_open_and_stream(scheme):
    drv, rec, chip, clock = rig(scheme, {"decimation": 2, "gyro_range_dps": 500, "filter_taps": 4})
    info = drv.open()
    assert info.rate_hz == pytest.approx(204.8) and info.identity.startswith("prod_id=0x4040")
    assert chip.regs[adis.REG_SMPL_PRD] == 0x0201 and chip.regs[adis.REG_SENS_AVG] == 0x0202
    assert chip.regs[adis.REG_MSC_CTRL] & adis.MSC_CTRL_CRC
    gyro = next(c for c in info.channels if c.name == "gyro")
    assert gyro.scale == pytest.approx(0.02 * DEG2RAD)
    accel = next(c for c in info.channels if c.name == "accel")
    n, rows = 0, []
    for _ in range(415):
        clock.sleep(info.poll_interval_s)
        block = drv.read_block()
        assert block.n in (0, round(adis.BATCH_S * 204.8))  # handed over in batches
        n += block.n
        rows.append(block.channels["accel"])
    held = drv.drain()
    # the newest was read at the last poll (stamped when its transfer returned, before the 9 us stall)
    assert 0 < held.n < round(adis.BATCH_S * 204.8) and 0 <= clock.now_ns() - held.read_ns[-1] <= 9_000
    assert np.all(np.diff(held.read_ns) > 0) and np.array_equal(held.previous_read_ns[1:], held.read_ns[:-1])
    n += held.n
    rows.append(held.channels["accel"])
    assert 410 <= n <= 415  # one sample per period; a poll that finds the same sample stores nothing
    acc = np.concatenate(rows) * accel.scale
    assert acc[:, 2].mean() == pytest.approx(G0, abs=0.01)  # the simulator's gravity on +z
    burst = [tx for tx, _ in rec.frames if len(tx) == 28]
    assert burst and all(tx == bytes([0x3E, 0x00]) + bytes(26) for tx in burst)


def test_bad_crc_drops_the_sample_and_says_so():
    drv, _, chip, clock = rig(faults=[FaultSpec("checksum", at_s=1.0)])
    info = drv.open()
    notes, aged, n = [], [], 0
    for _ in range(1000):
        clock.sleep(info.poll_interval_s)
        b = drv.read_block()
        n += b.n
        if b.lost:
            notes.append((b.n, b.lost, b.note))
            after = b.previous_read_ns[0]  # the bad burst: the read before the sample after it
        if b.n and b.read_ns[-1] < clock.now_ns() - 9_000:
            aged.append((b.n, b.read_ns[-1]))
    # the samples held before the bad burst are handed over at once, the newest read one poll before;
    # the loss comes with the next sample, before which it happened
    assert notes == [(1, 1, "checksum: burst CRC mismatch, sample dropped")]
    assert len(aged) == 1 and 0 < aged[0][0] < round(adis.BATCH_S * 409.6)
    assert after - aged[0][1] == pytest.approx(info.poll_interval_s * 1e9, abs=20_000)  # + the driver's stalls
    assert n + drv.drain().n + 1 == 1000


def test_reset_is_detected_as_lost_configuration():
    drv, _, chip, clock = rig(settings={"crc": False}, faults=[FaultSpec("reset", at_s=1.0)])
    info = drv.open()
    with pytest.raises(DeviceError, match="configuration lost"):
        for _ in range(2000):
            clock.sleep(info.poll_interval_s)
            drv.read_block()
    clock.sleep(0.3)
    drv.open()  # re-initialised after the start-up time


def test_wrong_spi_mode_or_chip():
    drv, _, _, _ = rig(mode=0)
    with pytest.raises(ChipIdMismatch, match="expected ADIS16448 \\(id 0x4040\\), found id 0xFFFF"):
        drv.open()


@pytest.mark.parametrize(
    "settings,needle",
    [({"decimation": 9}, "decimation = 9"), ({"stall_us": 2}, "stall_us = 2"), ({"filter_taps": 3}, "filter_taps = 3")],
)
def test_bad_settings(settings, needle):
    with pytest.raises(SettingError, match=needle):
        adis.ADIS16448.check_settings(settings)


def test_a_failed_transfer_hands_over_the_held_samples_first():
    drv, _, _, clock = rig(faults=[FaultSpec("disconnect", at_s=1.0, duration_s=0.5)])
    info = drv.open()
    n, blocks = 0, []
    with pytest.raises(BusError):
        for _ in range(1000):
            clock.sleep(info.poll_interval_s)
            b = drv.read_block()
            n += b.n
            blocks.append((b.n, clock.now_ns() - b.read_ns[-1] if b.n else 0))
    # the poll that failed returned what it held (its newest read one poll before); the next raised
    k, age_ns = blocks[-1]
    assert 0 < k < round(adis.BATCH_S * 409.6) and age_ns == pytest.approx(info.poll_interval_s * 1e9, rel=0.01)
    assert n == len(blocks) - 1  # every poll before the failure read one new sample
    assert drv.drain().n == 0


# --- the simulator holds the chip to its data sheet (docs/reference/conformance-adis16448.md) ----------


def bare_adis():
    clock = VirtualClock()
    return clock, ADIS16448Sim(clock, lambda fs: NoiseSource.for_device("adis16448", "xyz", fs, {}, 1))


def test_sim_needs_the_stall_time_between_transfers():
    clock, chip = bare_adis()
    chip.spi_transfer(bytes([adis.REG_PROD_ID, 0]), adis.SPI_MODE, 1e6)
    assert chip.spi_transfer(bytes(2), adis.SPI_MODE, 1e6) == b"\xff\xff"  # CS high for 0 us: not understood
    clock.sleep(9e-6)
    chip.spi_transfer(bytes([adis.REG_PROD_ID, 0]), adis.SPI_MODE, 1e6)
    clock.sleep(9e-6)
    assert chip.spi_transfer(bytes(2), adis.SPI_MODE, 1e6) == b"\x40\x40"
    assert chip.sim_stall_violations == 1


@pytest.mark.parametrize("scheme", ["cp2130", "mcp2210"])
def test_driver_keeps_the_stall_time_between_every_transfer(scheme):
    # t_STALL 9 us between 16-bit frames; the driver used to rely on the USB turnaround between
    # two register sequences (none on the simulated bus), so back-to-back writes were not understood
    drv, _, chip, clock = rig(scheme)
    info = drv.open()
    for _ in range(1000):  # ~2.4 s: two configuration checks
        clock.sleep(info.poll_interval_s)
        drv.read_block()
    assert chip.sim_stall_violations == 0


def test_sim_smpl_prd_bit0_clear_waits_for_an_external_clock():
    clock, chip = bare_adis()
    for frame in (bytes([0x80 | adis.REG_SMPL_PRD, 0x00]), bytes([0x80 | adis.REG_SMPL_PRD + 1, 0x01])):
        clock.sleep(9e-6)
        chip.spi_transfer(frame, adis.SPI_MODE, 1e6)
    clock.sleep(1.0)
    assert chip._newest() == -1  # no sample without the external clock
    clock.sleep(9e-6)
    chip.spi_transfer(bytes([0x80 | adis.REG_SMPL_PRD, 0x01]), adis.SPI_MODE, 1e6)
    clock.sleep(0.01)
    assert chip._newest() >= 0


def test_sim_ignores_a_reserved_range_code():
    clock, chip = bare_adis()
    clock.sleep(9e-6)
    chip.spi_transfer(bytes([0x80 | adis.REG_SENS_AVG + 1, 0x03]), adis.SPI_MODE, 1e6)  # range 011: reserved
    assert chip.regs[adis.REG_SENS_AVG] >> 8 == 0x04  # still +-1000 deg/s


def test_filter_taps_the_data_sheet_allows():
    # SENS_AVG B = 7 (128 taps) is no valid setting (Linux adis16400.c: "Not a valid setting"); the reduced
    # gyro ranges need a minimum filter (+-500 deg/s: 4 taps, +-250 deg/s: 16 taps); before, all were written
    with pytest.raises(SettingError, match=r"filter_taps = 128: driver 'adis16448' allows 1, 2, 4, 8, 16, 32, 64$"):
        adis.ADIS16448.check_settings({"filter_taps": 128})
    with pytest.raises(SettingError, match=r"filter_taps = 8 with gyro_range_dps = 250.*at least 16.*16, 32, 64"):
        adis.ADIS16448.check_settings({"gyro_range_dps": 250, "filter_taps": 8})
    with pytest.raises(SettingError, match=r"filter_taps = 2 with gyro_range_dps = 500.*at least 4"):
        adis.ADIS16448.check_settings({"gyro_range_dps": 500, "filter_taps": 2})
    assert adis.ADIS16448.check_settings({"gyro_range_dps": 250, "filter_taps": 16})["filter_taps"] == 16
    assert adis.ADIS16448.check_settings({"gyro_range_dps": 500, "filter_taps": 4})["filter_taps"] == 4
    assert adis.ADIS16448.check_settings({"gyro_range_dps": 1000, "filter_taps": 1})["filter_taps"] == 1
