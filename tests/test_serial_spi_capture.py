"""Simulated captures with the SPI (ADIS16448) and serial (MTi, DSP-3000) devices, file checked."""

import numpy as np
import pytest
from simchips import BurstLog

from imustation.acquisition import capture, load_config
from imustation.acquisition.config import parse_config
from imustation.configs import config_path
from imustation.drivers.sim import simulated_truth
from imustation.errors import ConfigError
from imustation.runfile import open_run

FAULTS = {
    "adis": [{"kind": "checksum", "at_s": 5}, {"kind": "disconnect", "at_s": 20, "duration_s": 2},
             {"kind": "nack", "every_s": 4}, {"kind": "reset", "at_s": 40}],
    "mti": [{"kind": "checksum", "at_s": 7}, {"kind": "corrupt", "at_s": 9}, {"kind": "short_read", "at_s": 11},
            {"kind": "disconnect", "at_s": 25, "duration_s": 2}],
    "fog": [{"kind": "corrupt", "at_s": 6}, {"kind": "disconnect", "at_s": 30, "duration_s": 2}],
}  # fmt: skip


def station(bridge="cp2130:", faults=True):
    return parse_config(
        {
            "station": {"seed": 2},
            "device": [
                {"name": "adis", "driver": "adis16448", "bus": bridge,
                 "sim": {"faults": FAULTS["adis"] if faults else []}},
                {"name": "mti", "driver": "mti", "bus": "serial:/dev/ttyUSB1?baud=921600",
                 "sim": {"faults": FAULTS["mti"] if faults else []}},
                {"name": "fog", "driver": "dsp3000", "bus": "serial:/dev/ttyUSB0",
                 "sim": {"faults": FAULTS["fog"] if faults else []}},
            ],
        }
    )  # fmt: skip


@pytest.fixture(scope="module")
def faulty_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("runs") / "serial_spi.h5"
    return path, capture(station(), path, 60.0, simulate=True)


def test_file_layout(faulty_run):
    path, summary = faulty_run
    with open_run(path) as run:
        devs = run.devices
        assert devs["adis"].channels["gyro"].dtype == np.int16 and devs["adis"].settings["decimation"] == 1
        assert devs["mti"].channels["gyro"].dtype == np.float32 and devs["mti"].has_counter
        assert devs["fog"].channels["gyro"].dtype == np.int32 and devs["fog"].channels["gyro"].axes == ("z",)
        for name in ("adis", "mti", "fog"):
            assert devs[name].n == summary.samples[name]
            expected = 60.0 * devs[name].rate_hz
            assert devs[name].n + summary.lost[name] == pytest.approx(expected, rel=0.01)
        counter = run.read("mti", "counter")
        jumps = np.diff(counter) - 1
        by_counter = [e.lost for e in run.events() if e.source == "mti" and "counter jump" in e.detail]
        # the exact losses the counter showed (checksum, bytes lost); the cable pull is the one big jump,
        # whose size the station estimated from time (a re-opened device may have restarted its counter)
        assert sorted(jumps[jumps > 0].tolist())[:-1] == sorted(by_counter) == [1, 1]


def test_faults_are_logged_never_stored(faulty_run):
    path, _ = faulty_run
    with open_run(path) as run:
        events = run.events()
        by = {(e.source, e.kind) for e in events}
        assert {("adis", "fault"), ("adis", "reconnect"), ("mti", "fault"), ("fog", "fault")} <= by
        assert any(e.source == "adis" and e.detail.startswith("checksum") for e in events)
        assert any(e.source == "adis" and "configuration lost" in e.detail for e in events)
        assert any(e.source == "mti" and "checksum" in e.detail for e in events)
        assert any(e.source == "fog" and "resync" in e.detail for e in events)
        gyro = run.read("mti", "gyro")
        # no misread float: every rate is what the simulator's noise can produce (|w| << 1 rad/s)
        assert np.isfinite(gyro).all() and np.abs(gyro).max() < 0.1
        fog = run.read("fog", "gyro") * run.devices["fog"].channels["gyro"].scale
        assert np.abs(fog).max() < 0.1


def test_adis_sample_times_follow_its_clock_across_batches_and_a_dropped_burst(faulty_run):
    path, _ = faulty_run
    with open_run(path) as run:
        t = run.read("adis", "t")
        period = 1e9 / run.devices["adis"].rate_hz
    steps = np.diff(t) / period
    assert (steps > 0).all()
    # the first 20 s (before the cable pull): one period per step, two across the dropped burst at 5 s
    # (within the time a retried transfer takes: the sample is dated by the read)
    early = steps[t[1:] < 20e9]
    assert np.abs(early - np.rint(early)).max() < 0.02
    assert sorted(set(np.rint(early).astype(int).tolist())) == [1, 2] and (np.rint(early) == 2).sum() == 1


def test_clean_capture_through_mcp2210(tmp_path):
    path = tmp_path / "m.h5"
    summary = capture(station("mcp2210:", faults=False), path, 10.0, simulate=True)
    assert summary.lost == {"adis": 0, "mti": 0, "fog": 0}
    assert summary.samples["adis"] == round(10 * 409.6)
    truth = simulated_truth(station(faults=False))
    assert set(truth) == {"adis/gyro/x", "adis/gyro/y", "adis/gyro/z", "mti/gyro/x", "mti/gyro/y", "mti/gyro/z",
                          "fog/gyro/z"}  # fmt: skip


def test_lab_example_config_loads():
    cfg = load_config(config_path("lab-example.toml"))
    drivers = {d.name: d.driver for d in cfg.devices}
    assert drivers["adis"] == "adis16448" and drivers["mti"] == "mti" and drivers["fog"] == "dsp3000"


def test_bus_kind_mismatch_is_a_config_error(tmp_path):
    cfg = parse_config({"device": [{"name": "a", "driver": "adis16448", "bus": "serial:/dev/ttyUSB0"}]})
    with pytest.raises(ConfigError, match="driver 'adis16448' needs a spi bus \\(cp2130:, mcp2210:, sim:\\)"):
        capture(cfg, tmp_path / "x.h5", 1.0, simulate=True)


@pytest.mark.parametrize(
    "faults",
    [
        [{"kind": "disconnect", "at_s": 10, "duration_s": 2}],
        [{"kind": "disconnect", "at_s": 8, "duration_s": 1}, {"kind": "disconnect", "at_s": 20, "duration_s": 2}],
        [{"kind": "reset", "at_s": 10}],
        [{"kind": "checksum", "every_s": 2}],
    ],
    ids=["pulled", "pulled-twice", "reset", "crc"],
)
def test_adis_samples_plus_logged_losses_are_exact(tmp_path, faults):
    """The driver holds samples between hand-overs: a re-opened device's loss is measured at its first block."""
    adis = {"name": "adis", "driver": "adis16448", "bus": "cp2130:", "sim": {"faults": faults}}
    cfg = parse_config({"device": [adis]})
    summary = capture(cfg, tmp_path / "a.h5", 30.0, simulate=True)
    assert summary.lost["adis"] > 0
    assert summary.samples["adis"] + summary.lost["adis"] == round(30 * 409.6)


def stress(stall_at_s):
    """A 1 s stall at ``stall_at_s``, a 5 s slow window (0.5 ms per transfer), a burst of two NACKs."""
    return [
        {"kind": "stall", "at_s": stall_at_s, "duration_s": 1.0},
        {"kind": "slow", "at_s": 20.0, "duration_s": 5.0, "delay_s": 0.0005},
        {"kind": "nack", "at_s": 27.0},
        {"kind": "nack", "at_s": 27.0},  # two USB timeouts in a row: within the bridge's three tries
    ]


def test_spi_and_serial_drivers_through_stalls_a_slow_bus_and_a_nack_burst(tmp_path, monkeypatch):
    """The ADIS16448, MTi and DSP-3000 simulators, strict, with stalls, a slow window and NACK bursts.

    The simulated clock is shared: each device's 1 s stall (at 10, 12, 14 s) holds all three.
    """
    bursts = BurstLog(monkeypatch)
    devices = [
        {"name": "adis", "driver": "adis16448", "bus": "cp2130:", "sim": {"faults": stress(10.0)}},
        {
            "name": "mti",
            "driver": "mti",
            "bus": "serial:/dev/ttyUSB1?baud=921600",
            "rate_hz": 400,
            "sim": {"faults": stress(12.0)},
        },  # fmt: skip
        {"name": "fog", "driver": "dsp3000", "bus": "serial:/dev/ttyUSB0", "sim": {"faults": stress(14.0)}},
    ]
    path = tmp_path / "stress.h5"
    summary = capture(parse_config({"station": {"seed": 2}, "device": devices}), path, 30.0, simulate=True)
    with open_run(path) as run:
        events = run.events()
        # MTi at 400 Hz sends 23.6 kB/s; the tty keeps 4096 bytes, so each stall loses ~0.83 s of
        # packets - counted exactly by the packet counter
        mti = [e for e in events if e.source == "mti"]
        assert [e.kind for e in mti] == ["gap"] * 3 and all("counter jump" in e.detail for e in mti)
        counter = run.read("mti", "counter")
        assert counter[-1] - counter[0] + 1 == summary.samples["mti"] + summary.lost["mti"]
        assert all(300 < e.lost < 400 for e in mti)
        # DSP-3000: 2.2 kB/s fit the buffer through a 1 s stall: every line arrives, late
        assert not [e for e in events if e.source == "fog"] and summary.samples["fog"] == 30 * 100
        # ADIS16448: no FIFO, no counter: a sample made while the bus is held is never read. The station
        # counts them from its read times, hole by hole, as the chip made them: the three stalls, and in the
        # slow window (0.5 ms more per transfer of every device) the reads that came more than a period
        # after the one before and missed a sample
        adis = [e for e in events if e.source == "adis"]  # the NACK burst was absorbed
        truth = bursts.holes()
        assert [e.lost for e in adis] == truth and [e.kind for e in adis] == ["gap"] * len(truth)
        assert sorted(truth)[-3:] == [409, 409, 410] and set(sorted(truth)[:-3]) == {1}
        t = run.read("adis", "t")
        steps = np.diff(t) * run.devices["adis"].rate_hz / 1e9
        assert (np.rint(steps[steps > 1.5]).astype(int) - 1).tolist() == truth  # the time stamps show them
        assert np.abs(steps - np.rint(steps))[(t[1:] < 9e9)].max() < 0.01  # one period apart before
