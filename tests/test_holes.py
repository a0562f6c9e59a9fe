"""Samples lost without a word (issue 24): written + logged losses = produced, for every device of the lab,
checked from the run file alone (imustation.runfile.holes) and against the simulators."""

from __future__ import annotations

import itertools
import shutil
import tomllib
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

import imustation.acquisition.buses as buses
from imustation.acquisition.capture import capture
from imustation.acquisition.config import parse_config
from imustation.acquisition.recorder import run_file_device
from imustation.acquisition.station import Station
from imustation.acquisition.timeline import SamplingPhase, Timeline
from imustation.analysis.pipeline.loaders import load_run
from imustation.cli import cli
from imustation.configs import config_path
from imustation.drivers.base import Block
from imustation.drivers.sim import station_device_seed
from imustation.errors import RateCorrected
from imustation.runfile import ChannelSpec, DeviceSpec, RunWriter, open_run
from imustation.runfile.holes import check_run, check_thermometer, check_thermometers, find_holes, match_losses

#: a 2 s stall of the BMX055 gyro's bus 3 s after its simulator starts: on the virtual clock it holds the
#: whole station (one thread), on the host clock its I2C bus (the BMX055 accelerometer shares it)
STALL = {"kind": "stall", "at_s": 3.0, "duration_s": 2.0}


def lab(stall: bool = True) -> dict:
    """configs/lab-example.toml, with the stall on the BMX055 gyro; no other fault (the ADIS16448's hourly
    bad CRC left out)."""
    raw = tomllib.loads(Path(config_path("lab-example.toml")).read_text())
    for dev in raw["device"]:
        dev.setdefault("sim", {})["faults"] = [STALL] if stall and dev["name"] == "bmx055" else []
    return raw


def capture_lab(tmp_path, raw: dict, seconds: float, monkeypatch, **station_kw):
    """Record ``raw`` through the station, logging when each device was read.

    Returns the run file and, per device, the samples its simulator made between the read that emptied it
    at the start and its last read (every simulator makes sample k at the k-th multiple of its period after
    its timing started; none restarts here).
    """
    cfg = parse_config(raw)
    chips: dict[int, object] = {}
    make = buses.make_simulator

    def keep(driver, clock, settings, sim, seed):
        chip, plan = make(driver, clock, settings, sim, seed)
        chips[seed] = chip
        return chip, plan

    monkeypatch.setattr(buses, "make_simulator", keep)
    station = Station(cfg, simulate=True, **station_kw)
    reads: dict[str, list[int]] = {}
    try:
        specs = station.open()
        for name, st in station.devices.items():
            for method in ("read_block", "drain"):
                call = getattr(st.driver, method, None)
                if call is not None:

                    def logged(call=call, name=name):
                        block = call()
                        reads.setdefault(name, []).append(station.clock.now_ns())
                        return block

                    setattr(st.driver, method, logged)
        path = tmp_path / "lab.h5"
        devices = [run_file_device(d) for d in specs]
        thermometers = {name: th.rate_hz for name, th in station.thermometers.items()}
        with RunWriter(
            path, station=cfg.name, config_text="", simulated=True, devices=devices, thermometers=thermometers
        ) as writer:
            station.run(writer, seconds)
    finally:
        station.close()
    produced = {}
    for name, times in reads.items():
        chip = chips[station_device_seed(cfg.seed, name)]
        rate = next(getattr(chip, a) for a in ("rate_hz", "odr_hz", "_rate") if hasattr(chip, a))
        made = [int((t - chip.t_start_ns) * rate / 1e9) for t in (times[0], times[-1])]
        produced[name] = made[1] - made[0]
    return path, produced


def assert_the_file_accounts_for_every_sample(path) -> dict:
    """Every device: every hole its data show is logged, every logged loss is in a hole or at an edge."""
    with open_run(path) as run:
        checks = check_run(run)
        assert set(checks) == set(run.devices)
        for name, c in checks.items():
            assert c.consistent, (name, c.unlogged[:3], c.unlocated)
            assert c.samples + c.logged == c.produced and c.samples > 0, name
            assert c.holes.short == 0, name  # times advance by the rate everywhere
        # the thermometers too (their polls made late by the stall are not losses)
        for name, c in check_thermometers(run).items():
            assert c is not None and c.consistent and c.samples > 0, (name, c)
    return checks


def test_a_stall_on_one_device_virtual_clock_every_device_accounts_exactly(tmp_path, monkeypatch):
    """The stall holds the one-thread station 2 s: every FIFO overruns, the serial buffers fill, the ADIS16448
    (no FIFO) is not read. Every loss is logged where it is, and written + logged = what each simulator made."""
    path, produced = capture_lab(tmp_path, lab(), 10.0, monkeypatch)
    checks = assert_the_file_accounts_for_every_sample(path)
    for name, c in checks.items():
        assert c.samples + c.logged == produced[name], name
        assert len(c.holes) == 1 and c.holes.samples > 0, name  # the stall, in every record
    assert checks["adis"].holes.samples == 819  # 2 s at 409.6 Hz, less the sample read after it


def _stamped_late(monkeypatch, every: int, late_s: float) -> None:
    """Every ``every``-th ADIS16448 burst is stamped ``late_s`` after its transfer returned (the virtual
    clock moves on meanwhile): a reader preempted between a transfer and its time stamp, as on a loaded
    host, made deterministic."""
    open_ = Station.open

    def opened(self):
        specs = open_(self)
        clock, n = self.clock, itertools.count(1)

        def stamp() -> int:
            if next(n) % every == 0:
                clock.sleep(late_s)
            return clock.now_ns()

        self.devices["adis"].driver.clock_ns = stamp
        return specs

    monkeypatch.setattr(Station, "open", opened)


def test_reads_stamped_late_every_hole_is_logged_with_its_count(tmp_path, monkeypatch):
    """What failed the former host-clock version of the stall test (once in a few runs under load, a
    hole of 224 samples logged 223): a chip without a FIFO is dated at its reads, and a read stamped
    late moves its sample. Every 7th ADIS16448 burst stamped 8 ms late here: at the configured rate
    every hole the stamps show is logged with its count, written + logged = produced."""
    _stamped_late(monkeypatch, 7, 0.008)
    path, _ = capture_lab(tmp_path, lab(stall=False), 6.0, monkeypatch)
    with open_run(path) as run:
        t = run.read("adis", "t")
        events = [e for e in run.events() if e.source == "adis"]
    holes = find_holes(t, 1e9 / 409.6)
    logged, edge, unlocated, unlogged = match_losses(holes, events, int(t[0]), int(t[-1]))
    assert not unlogged and not unlocated and edge == 0
    assert logged == holes.samples > 500


def test_reads_stamped_late_the_file_reader_counts_holes_at_the_configured_rate(tmp_path, monkeypatch):
    """Read-dated stamps (every 7th burst 8 ms late) are not a rate: the reader's whole-span rule keeps
    409.6 Hz (the old first-4,097 fit read ~391 Hz and recounted every hole with it)."""
    _stamped_late(monkeypatch, 7, 0.008)
    path, _ = capture_lab(tmp_path, lab(stall=False), 6.0, monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RateCorrected)
        with open_run(path) as run:
            assert run.devices["adis"].rate_hz == 409.6
            assert check_run(run)["adis"].consistent


def test_a_paced_capture_from_the_command_line_accounts_for_every_sample(tmp_path):
    text = (
        Path(config_path("lab-example.toml"))
        .read_text()
        .replace("  seed = 11 ", '  faults = [{kind = "stall", at_s = 2.0, duration_s = 1.5}]\n  seed = 11 ', 1)
    )
    cfg = tmp_path / "lab.toml"
    cfg.write_text(text)
    out = tmp_path / "paced.h5"
    args = ["capture", str(cfg), "--simulate", "--duration", "6s", "--sim-speed", "40", "-o", str(out), "--quiet"]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    checks = assert_the_file_accounts_for_every_sample(out)
    assert checks["adis"].holes.samples > 500
    assert "holes found: 0 not logged" in CliRunner().invoke(cli, ["inspect", str(out)]).output


def test_model_level_sample_times_are_exact_for_every_rate_of_the_lab():
    """An hour of the lab at the noise-model level: every step is the device's period within 1 ns
    (409.6 Hz: 2441406.25 ns), except the logged holes; written + logged = produced."""
    station = Station(parse_config(lab(stall=False)), simulate=True, sim_level="model")
    sink = _TimesSink()
    try:
        station.open()
        station.run(sink, 3600.0)
    finally:
        station.close()
    rates = set()
    for name, st in station.devices.items():
        t = np.concatenate(sink.t[name])
        period = 1e9 / st.info.rate_hz
        steps = np.diff(t)
        assert np.abs(steps - period).max() <= 1.0, name
        assert len(t) + st.lost == st.driver.produced - st.driver.stream.due(station.t0 - st.driver._origin_ns)
        rates.add(st.info.rate_hz)
    assert {409.6, 400.0, 200.0, 125.0, 100.0} <= rates


class _TimesSink:
    def __init__(self):
        self.t: dict[str, list[np.ndarray]] = {}

    def append(self, device, t_ns, channels, counter) -> None:
        self.t.setdefault(device, []).append(np.asarray(t_ns))

    def append_temperature(self, name, t_ns, celsius) -> None:
        pass

    def event(self, t_ns, source, kind, detail="", lost=0) -> None:
        pass


# --- the checker and the analysis, on made-up records ---------------------------------------------------


def test_holes_from_times_and_from_a_counter():
    period = 10_000_000  # 100 Hz
    t = np.array([0, 1, 2, 5, 6, 8, 9], dtype=np.int64) * period
    h = find_holes(t, period)
    assert h.at.tolist() == [3, 5] and h.lost.tolist() == [2, 1] and h.short == 0
    # a counter says what is missing; one that went back (a restart) is read by the times
    c = np.array([10, 11, 12, 15, 16, 0, 1])
    assert find_holes(t, period, c).lost.tolist() == [2, 1]
    assert find_holes(t, period, np.array([65534, 65535, 0, 3, 4, 5, 6]), modulus=65536).lost.tolist() == [2]
    # repeated and swapped times (an imported log) are not holes; they are counted as short steps
    bad = np.array([0, 1, 1, 3, 4, 6, 5, 7], dtype=np.int64) * period
    h = find_holes(bad, period)
    assert len(h) == 0 and h.short == 2


def _file(path, t_ns, events):
    spec = DeviceSpec(
        "g", "sim", "model", "sim", "id", 100.0, {}, (ChannelSpec("gyro", "<i2", "rad/s", 1e-3, 0.0, ("x", "y", "z")),)
    )
    with RunWriter(path, station="t", config_text="", simulated=True, devices=[spec]) as w:
        w.append("g", np.asarray(t_ns, dtype=np.int64), {"gyro": np.zeros((len(t_ns), 3), np.int16)})
        for t, kind, lost in events:
            w.event(t, "g", kind, "test", lost=lost)


def test_the_checker_finds_a_hole_no_event_states_and_analyze_splits_there(tmp_path):
    period = 10_000_000
    rows = np.r_[0:1000, 1003:2000, 2010:3000]  # 3 missing (logged), 10 missing (not logged)
    path = tmp_path / "h.h5"
    # the logged one dated at its first missing sample; a loss at the end the data cannot show
    _file(path, rows * period, [(1000 * period, "gap", 3), (3005 * period, "gap", 4)])
    with open_run(path) as run:
        c = check_run(run)["g"]
    assert [(u.row, u.lost, u.logged) for u in c.unlogged] == [(1997, 10, 0)]
    assert (c.logged, c.edge, c.unlocated, c.produced) == (7, 4, 0, len(rows) + 3 + 10 + 4) and not c.consistent
    out = CliRunner().invoke(cli, ["inspect", str(path)]).output
    assert "holes found: 1 not logged" in out and "NOT LOGGED: 1" in out
    assert load_run(str(path))[0].segments == [(0, 1000), (1000, 1997), (1997, len(rows))]


def test_an_event_dated_at_the_read_after_its_hole_still_counts_for_it(tmp_path):
    """Files of earlier versions dated a loss at the read that found it, after the hole."""
    period = 10_000_000
    rows = np.r_[0:1000, 1005:2000]
    path = tmp_path / "old.h5"
    _file(path, rows * period, [(1040 * period, "overrun", 5)])
    with open_run(path) as run:
        c = check_run(run)["g"]
    assert c.consistent and c.produced == 2000


# --- the timeline of a chip without a FIFO -----------------------------------------------------------------


def test_the_sampling_phase_is_learnt_from_which_reads_found_a_new_sample():
    """Reads every 0.9-1.1 periods of a chip sampling at phase 0.37: after a few dozen reads the samples made
    between any two reads are counted exactly, however long apart."""
    period = 1000.0
    rng = np.random.default_rng(3)
    made_at = 370.0
    phase = SamplingPhase(period)
    reads = np.cumsum(rng.uniform(0.9, 1.1, 200) * period)
    index = np.floor((reads - made_at) / period)
    for a, b, ia, ib in zip(reads[:-1], reads[1:], index[:-1], index[1:], strict=True):
        (phase.made_in if ib > ia else phase.none_in)(a, b)
    assert phase.width < 0.1 * period and (made_at - phase.lo) % period < phase.width  # it holds the truth
    exact = 0
    for a, b in np.sort(rng.uniform(0, 1e6, (500, 2)), axis=1):
        if all((x - phase.lo) % period >= phase.width for x in (a, b)):  # neither read inside the arc
            assert phase.count(a, b) == np.floor((b - made_at) / period) - np.floor((a - made_at) / period)
            exact += 1
    assert exact > 400


def test_a_chip_without_a_fifo_read_late_loses_what_it_made_meanwhile():
    """One sample per read (a BMX055 accelerometer in data_ready mode), read twice per period; the station
    does not read it for 5.5 periods: 4 or 5 samples lost depending on the chip's phase, which the reads tell
    (the nearest whole number of periods would say 5 for both)."""
    period = 8_000_000  # 125 Hz
    for made_at in (1_000_000, 7_000_000):
        timeline = Timeline(period, overflow="newest", buffer_s=period / 1e9)
        newest, written, logged = -1, 0, 0
        early = [i * period // 2 + 100 for i in range(1, 41)]
        reads = early + [25 * period + period // 2 + 300 + i * period // 2 for i in range(40)]
        for t_read in reads:
            i = (t_read - made_at) // period
            block = Block({"accel": np.zeros((1 if i > newest else 0, 3), np.int16)})
            newest = max(newest, i)
            placed = timeline.place(block, t_read)
            written += block.n
            logged += sum(e.lost for e in placed.events)
        assert written + logged == newest + 1, made_at  # every sample made up to the last read


# --- thermometers: readings against the poll rate the file stores ------------------------------------------

#: a 4 Hz thermometer that is gone 2.2 s (nine failed polls, logged at the reconnect, whose reading is dated one
#: 250 ms conversion late), on a station a 3.5 s stall of the gyro holds (the overdue polls made at once after it)
THERMO_RAW = {
    "station": {"seed": 3},
    "device": [
        {
            "name": "gyro", "driver": "bmx055", "bus": "i2c:1", "rate_hz": 100, "bandwidth_hz": 32,
            "sim": {"faults": [{"kind": "stall", "at_s": 10.0, "duration_s": 3.5}]},
        }
    ],
    "thermometer": [
        {
            "name": "amb", "driver": "mcp9804", "bus": "i2c:2", "address": 0x18, "rate_hz": 4,
            "sim": {"faults": [{"kind": "disconnect", "at_s": 30.0, "duration_s": 2.2}]},
        }
    ],
}  # fmt: skip


@pytest.fixture(scope="module")
def thermo_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("thermo") / "thermo.h5"
    summary = capture(parse_config(THERMO_RAW), path, 60.0, simulate=True)
    return path, summary


def _thermo_line(out: str) -> str:
    lines = out.splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith("  thermometer amb:"))
    return lines[i] + "\n" + lines[i + 1]


def test_a_thermometer_s_logged_missed_readings_are_its_only_hole(thermo_run):
    path, summary = thermo_run
    with open_run(path) as run:
        assert run.thermometer_rate_hz("amb") == 4.0
        c = check_thermometer(run, "amb")
        t, _ = run.temperatures("amb")
    assert c.consistent and len(c.holes) == 1 and c.holes.samples == c.logged == 9
    assert c.samples + c.logged == summary.readings["amb"] + 9 == c.produced
    assert c.holes.short == 15  # the 14 polls made at once after the stall, one after the reconnect
    assert t[c.holes.at[0]] - t[c.holes.at[0] - 1] == 11 * 250_000_000
    out = CliRunner().invoke(cli, ["inspect", str(path)]).output
    assert "holes found: 0 not logged" in out
    line = _thermo_line(out)
    assert "polled at 4 Hz" in line and "holes in the data: 1 (9 readings), every one logged" in line, line


def _edited_copy(path, tmp_path, edit):
    out = tmp_path / "edited.h5"
    shutil.copyfile(path, out)
    with h5py.File(out, "r+") as f:
        edit(f["thermometers/amb"])
    return out


def test_readings_dropped_without_an_event_are_flagged(thermo_run, tmp_path):
    def drop(g):
        t = g["t"][()]
        keep = (t < 40_000_000_000) | (t > 40_500_000_000)  # the readings of 40, 40.25 and 40.5 s go, no event says so
        for key in ("t", "celsius"):
            data = g[key][()][keep]
            g[key].resize(len(data), axis=0)
            g[key][:] = data

    path = _edited_copy(thermo_run[0], tmp_path, drop)
    with open_run(path) as run:
        c = check_thermometer(run, "amb")
    assert not c.consistent and [(u.t_ns, u.lost, u.logged) for u in c.unlogged] == [(40_750_000_000, 3, 0)]
    out = CliRunner().invoke(cli, ["inspect", str(path)]).output
    assert "holes found: 1 not logged" in out
    line = _thermo_line(out)
    assert "holes in the data: 2 (12 readings); NOT LOGGED: 1 (first at t=40.750s" in line
    assert "3 missing, 0 logged" in line


def test_a_file_without_the_thermometer_s_rate_says_it_is_not_checked(thermo_run, tmp_path):
    path = _edited_copy(thermo_run[0], tmp_path, lambda g: g.attrs.__delitem__("rate_hz"))
    with open_run(path) as run:
        assert check_thermometer(run, "amb") is None and check_thermometers(run) == {"amb": None}
    line = _thermo_line(CliRunner().invoke(cli, ["inspect", str(path)]).output)
    assert "poll rate not stored" in line and "holes: not checked (no rate stored)" in line, line


def test_late_polls_are_not_holes_missed_ones_are():
    """Poll times (periods): late polls are followed by polls on time (short steps); only missed ones lose."""
    period = 250_000_000
    t = np.array([0, 1, 2, 3, 4.6, 5, 6, 7, 10, 10, 10, 11, 13, 14, 17, 17, 18]) * period
    h = find_holes(t.astype(np.int64), period, late_polls=True)
    # 3 -> 4.6 -> 5: late; 7 -> 10 and two at once: three readings over three periods; 11 -> 13: one
    # missed; 14 -> 17, 17: two readings over three periods, one missed
    assert h.at.tolist() == [12, 14] and h.lost.tolist() == [1, 1] and h.short == 4
    # the same times as a chip's samples: 7 -> 10 is not counted (next to a short step), nor is 14 -> 17
    assert find_holes(t.astype(np.int64), period).at.tolist() == [12]
    assert find_holes(t[:8].astype(np.int64), period, late_polls=True).samples == 0
