"""Xsens MTi: Xbus framing against docs/reference/sensors.md §5 examples, MTData2 parsing, resync, driver on sim."""

import struct

import numpy as np
import pytest

from imustation.acquisition.timeline import Timeline
from imustation.clock import VirtualClock
from imustation.drivers import xsens_mti as xb
from imustation.drivers.bus.serial_port import SerialPort
from imustation.drivers.sim.faults import FaultPlan, FaultSpec
from imustation.drivers.sim.serial_handlers import register, unregister
from imustation.drivers.sim.sources import NoiseSource
from imustation.drivers.sim.xsens_mti import MTiSim
from imustation.errors import BusClosed, DeviceError, SettingError

WORKED = bytes.fromhex(
    "FA FF 36 38 10 20 02 12 34 10 60 04 00 01 E2 40 08 10 04 42 16 80 00 40 20 0C 00 00 00 00 00 00 00 00 41 1D"
    "00 00 80 20 0C 00 00 00 00 00 00 00 00 3F 00 00 00 E0 20 04 00 00 00 03 D4"
)
SET_OUTPUT = bytes.fromhex(
    "FA FF C0 20 10 20 FF FF 10 60 FF FF 08 10 00 01 40 20 00 64 80 20 00 64 40 10 00 64 80 30 00 64 E0 20 FF FF DE"
)


@pytest.mark.parametrize(
    "mid,payload,wire",
    [
        (0x30, b"", "FA FF 30 00 D1"),
        (0x31, b"", "FA FF 31 00 D0"),
        (0x10, b"", "FA FF 10 00 F1"),
        (0x00, b"", "FA FF 00 00 01"),
        (0x1C, b"", "FA FF 1C 00 E5"),
        (0x40, b"", "FA FF 40 00 C1"),
        (0x3E, b"", "FA FF 3E 00 C3"),
        (0x3F, b"", "FA FF 3F 00 C2"),
        (0x12, b"", "FA FF 12 00 EF"),
        (0x18, b"\x02", "FA FF 18 01 02 E6"),
        (0x42, b"\x04", "FA FF 42 01 04 BA"),
    ],
)
def test_encode_matches_sensors_md(mid, payload, wire):
    assert xb.encode(mid, payload) == bytes.fromhex(wire)


def test_extended_length_roundtrip():
    payload = bytes(range(256)) + bytes(44)
    msg = xb.encode(0x36, payload)
    assert msg[:6] == bytes.fromhex("FA FF 36 FF 01 2C")
    assert sum(msg[1:]) & 0xFF == 0
    messages, used, garbage, bad = xb.parse_stream(b"\x00\x01" + msg)
    assert messages == [xb.Message(0x36, payload)] and used == len(msg) + 2 and garbage == 2 and bad == 0


def test_worked_mtdata2_message():
    messages, used, garbage, bad = xb.parse_stream(WORKED)
    assert (used, garbage, bad) == (len(WORKED), 0, 0)
    items = xb.parse_mtdata2(messages[0].payload)
    assert xb.decode_item(xb.ID_PACKET_COUNTER, items[0x1020])[0] == 0x1234
    assert xb.decode_item(xb.ID_SAMPLE_TIME_FINE, items[0x1060])[0] == 123456
    assert xb.decode_item(xb.ID_TEMPERATURE, items[0x0810])[0] == 37.625
    assert xb.decode_item(xb.ID_ACCELERATION, items[0x4020]).tolist() == [0.0, 0.0, 9.8125]
    assert xb.decode_item(xb.ID_RATE_OF_TURN, items[0x8020]).tolist() == [0.0, 0.0, 0.5]
    assert xb.decode_item(xb.ID_STATUS_WORD, items[0xE020])[0] == 3
    with pytest.raises(DeviceError, match="0x4022"):
        xb.decode_item(0x4022, bytes(18))


def test_set_output_configuration_example_is_a_valid_message():
    (m,), _, _, bad = xb.parse_stream(SET_OUTPUT)
    assert m.mid == 0xC0 and bad == 0
    pairs = [struct.unpack_from(">HH", m.payload, i) for i in range(0, len(m.payload), 4)]
    assert pairs[0] == (0x1020, 0xFFFF) and pairs[3] == (0x4020, 100)
    assert xb.output_configuration(100) == bytes.fromhex("10 20 FF FF 10 60 FF FF 08 10 00 64 40 20 00 64 80 20 00 64")


def frames_for(counters):
    r = xb.MTData2Reader()
    out = b""
    for c in counters:
        payload = b"".join(
            struct.pack(">HB", i, xb.ITEMS[i].size)
            + (struct.pack(">H", c) if i == xb.ID_PACKET_COUNTER else struct.pack(">I", c * 25))
            if i in (xb.ID_PACKET_COUNTER, xb.ID_SAMPLE_TIME_FINE)
            else struct.pack(">HB", i, xb.ITEMS[i].size) + np.full(xb.ITEMS[i].count, c / 8, ">f4").tobytes()
            for i in xb.LAYOUT
        )
        out += xb.encode(xb.MID_MTDATA2, payload)
    return r, out


def test_reader_resyncs_after_garbage_partial_and_bad_frames():
    r, stream = frames_for(range(10))
    L = r.frame_len
    damaged = bytearray(stream)
    damaged[3 * L + 10] ^= 0xFF  # frame 3: bad checksum
    garbage = bytes([0xFA, 0xFF, 0x36, 0x31, 0x00, 0xFA])  # a fake start between frames 5 and 6
    data = bytes(damaged[: 6 * L]) + garbage + bytes(damaged[6 * L : 8 * L + 7]) + bytes(damaged[8 * L + 12 :])
    found = []
    for i in range(0, len(data), 37):  # arrives in odd-sized pieces
        scan = r.feed(data[i : i + 37])
        found += r.column(scan.frames, xb.ID_PACKET_COUNTER).tolist()
    assert found == [0, 1, 2, 4, 5, 6, 7, 9]  # 3 (bad checksum) and 8 (bytes lost) dropped, never misread
    assert r.bad_checksums >= 1 and r.garbage_bytes >= len(garbage)
    vals = r.column(frames_for([9])[0].feed(frames_for([9])[1]).frames, xb.ID_RATE_OF_TURN)
    assert vals.dtype == np.float32 and vals.tolist() == [[1.125, 1.125, 1.125]]


def rig(baud=921600, faults=(), settings=None, name="mti-test"):
    clock = VirtualClock()
    plan = FaultPlan(list(faults), clock) if faults else None
    sim = MTiSim(clock, lambda fs: NoiseSource.for_device("mti", "xyz", fs, {}, 3), plan)
    url = register(name, sim)
    port = SerialPort(f"serial:/dev/ttyUSB9?baud={baud}", baud_default=115200, sim_url=url)
    clock.sleep(0.3)  # the device was streaming before the station opened it
    return xb.XsensMTi(port, settings or {}, sleep=clock.sleep), sim, clock


def test_driver_configures_and_counts_lost_packets_exactly():
    drv, sim, clock = rig(faults=[FaultSpec("checksum", at_s=2.0), FaultSpec("short_read", at_s=3.0),
                                  FaultSpec("corrupt", at_s=4.0)], settings={"rate_hz": 400})  # fmt: skip
    try:
        info = drv.open()
        assert info.model == "Xsens MTi-100-2A8G4" and info.rate_hz == 400 and info.has_counter
        assert sim.config == tuple(struct.unpack_from(">HH", xb.output_configuration(400), i) for i in range(0, 20, 4))
        # the driver unwraps the counter; the station's timeline counts what its jumps skipped
        timeline = Timeline(1e9 / info.rate_hz, overflow=info.overflow, buffer_s=info.buffer_s)
        counters, notes, n = [], [], 0
        for i in range(60):
            clock.sleep(info.poll_interval_s)
            b = drv.read_block()
            assert b.lost == 0
            counters.append(b.counter)
            n += b.n
            notes += [(e.lost, e.detail) for e in timeline.place(b, (i + 1) * 100_000_000).events]
        c = np.concatenate(counters)
        assert timeline.lost == 2 and n + timeline.lost == c[-1] - c[0] + 1  # checksum + short_read packets
        assert [lost for lost, _ in notes] == [1, 1] and "checksum" in notes[0][1]  # garbage costs none
        assert (np.diff(c) >= 1).all()
    finally:
        unregister("mti-test")


def test_baud_too_slow_for_rate_is_a_setting_error_naming_the_rate_that_fits():
    drv, _, _ = rig(baud=115200, name="mti-slow", settings={"rate_hz": 400})
    with pytest.raises(
        SettingError,
        match="rate_hz = 400: 54-byte MTData2 messages need 216000 bit/s, more than 115200 baud; "
        "rate_hz = 200 or less fits it, or configure",
    ):
        drv.open()
    unregister("mti-slow")


def test_a_config_naming_only_the_bus_opens_at_the_factory_baud_rate():
    """No rate_hz, no baud in the URL: the default rate is the fastest the factory 115200 baud carries (issue 23)."""
    assert xb.DEFAULT_RATE_HZ == 200 and xb.fastest_rate(921600) == 1000 and xb.fastest_rate(9600) == 10
    clock = VirtualClock()
    sim = MTiSim(clock, lambda fs: NoiseSource.for_device("mti", "xyz", fs, {}, 3), None)
    url = register("mti-factory", sim)
    port = SerialPort("serial:/dev/ttyUSB9", baud_default=xb.XsensMTi.default_baud, sim_url=url)
    try:
        drv = xb.XsensMTi(port, {}, sleep=clock.sleep)
        info = drv.open()
        assert port.baud == 115200 and info.rate_hz == 200
        n = 0
        for _ in range(10):  # polled as the station polls: the 4 KiB tty buffer holds ~75 messages
            clock.sleep(0.1)
            n += drv.read_block().n
        assert n > 190  # it streams at 200 Hz
    finally:
        unregister("mti-factory")


def test_reset_and_unplug_are_reported():
    drv, _, clock = rig(faults=[FaultSpec("reset", at_s=2.0), FaultSpec("disconnect", at_s=4.0, duration_s=1.0)],
                        name="mti-f")  # fmt: skip
    try:
        info = drv.open()
        with pytest.raises(DeviceError, match="WakeUp"):
            for _ in range(30):
                clock.sleep(info.poll_interval_s)
                drv.read_block()
        drv.open()
        with pytest.raises(BusClosed, match="port lost"):
            for _ in range(30):
                clock.sleep(info.poll_interval_s)
                drv.read_block()
        with pytest.raises(BusClosed, match="cannot open"):
            drv.open()
        clock.sleep(1.0)
        drv.open()
    finally:
        unregister("mti-f")


# --- Xbus states, as the simulator enforces them (docs/reference/conformance-mti.md) -----------------


def bare_mti():
    clock = VirtualClock()
    sim = MTiSim(clock, lambda fs: NoiseSource.for_device("mti", "xyz", fs, {}, 3))

    def ask(mid, payload=b""):
        sim.receive(xb.encode(mid, payload))
        return [m.mid for m in xb.parse_stream(sim.produce())[0] if m.mid != xb.MID_MTDATA2]

    return clock, sim, ask


def test_sim_answers_configuration_requests_only_in_config_state():
    clock, sim, ask = bare_mti()
    config = xb.output_configuration(100)
    for mid in (xb.MID_REQ_DID, xb.MID_REQ_PRODUCT_CODE, xb.MID_REQ_FW_REV):
        assert ask(mid) == [xb.MID_ERROR]  # measuring
    assert ask(xb.MID_SET_OUTPUT_CONFIG, config) == [xb.MID_ERROR]
    assert ask(xb.MID_GOTO_CONFIG) == [xb.MID_GOTO_CONFIG + 1]
    assert ask(xb.MID_REQ_DID) == [xb.MID_DEVICE_ID]
    assert ask(xb.MID_SET_OUTPUT_CONFIG, config) == [xb.MID_SET_OUTPUT_CONFIG + 1]


@pytest.mark.parametrize("answer", [True, False])
def test_sim_reset_sends_wakeup_and_waits_for_the_ack(answer):
    # after Reset the device sends WakeUp; WakeUpAck keeps it in config, else it measures with the
    # power-up configuration
    clock, sim, ask = bare_mti()
    assert ask(xb.MID_RESET) == [xb.MID_RESET + 1, xb.MID_WAKEUP]
    if answer:
        assert ask(xb.MID_WAKEUP_ACK) == []
    clock.sleep(1.0)
    packets = [m for m in xb.parse_stream(sim.produce())[0] if m.mid == xb.MID_MTDATA2]
    assert (not packets) is answer and sim.measuring is not answer


@pytest.mark.parametrize("stall_s", [1.0, 5.0])
def test_open_after_the_tty_overflowed_finds_the_acknowledgement(stall_s):
    """A port opened, then not read for a while (a loaded host starting its reader processes): the
    tty keeps 4096 bytes and drops the rest, so what waits ends in a cut MTData2 frame whose length
    field swallowed GoToConfig's acknowledgement on every try (seen as an intermittent open failure
    of 'capture --simulate --real-time' under load)."""
    drv, sim, clock = rig(name="mti-stall", settings={"rate_hz": 400})
    try:
        drv.port.ensure_open()
        clock.sleep(stall_s)  # streaming at the power-on configuration, nobody reading
        info = drv.open()
        assert info.rate_hz == 400 and sim.measuring
        assert drv.port._port.sim_dropped > 0  # the overflow really happened
    finally:
        unregister("mti-stall")
