"""Host-clock captures: bus readers in processes of their own, their hand-off, their scheduling, their death.

The scheduler and the hand-off are driven on a virtual clock or with explicit
triggers; the captures that spawn reader processes assert what the file must hold
whatever the machine's speed (every sample written or logged lost), never a count
that depends on timing.
"""

from __future__ import annotations

import itertools
import multiprocessing as mp
import os
import pickle
import signal
import threading
from multiprocessing.connection import Connection

import numpy as np
import pytest

from imustation.acquisition import capture, readers, realtime, restarts
from imustation.acquisition.config import parse_config
from imustation.acquisition.readers import HostOutbox
from imustation.acquisition.scheduler import DeadlineStats, Poller, run_deadline
from imustation.acquisition.sinks import APPEND, EVENT, MessageSink, shifted
from imustation.clock import VirtualClock
from imustation.errors import InputError
from imustation.runfile import open_run
from imustation.runfile.holes import check_run, check_thermometers

GYRO = {"driver": "bmx055", "rate_hz": 400, "bandwidth_hz": 47}


def _config(devices, flush=0.2):
    return parse_config({"station": {"seed": 3, "flush_interval_s": flush}, "device": list(devices)})


# -- the scheduler: polling against hold times ---------------------------------------------------
def _poller(clock, log, name, interval_ms, hold_ms, cost_ms=0.0):
    def poll(sink) -> int:
        log.append((name, clock.now_ns()))
        clock.advance_to(clock.now_ns() + int(cost_ms * 1e6))
        return int(interval_ms * 1e6)

    return Poller(name, "bus", int(interval_ms * 1e6), poll, int(hold_ms * 1e6))


def test_a_device_is_polled_at_least_twice_per_hold_time_and_the_shortest_hold_goes_first():
    """A no-FIFO chip (hold 2.5 ms, driver interval 2.5 ms) is polled every 1.25 ms; a FIFO device
    (interval 100 ms, hold 250 ms) due at the same instant waits for it (earliest deadline first)."""
    clock = VirtualClock()
    log: list[tuple[str, int]] = []
    between: list[int] = []
    pollers = [_poller(clock, log, "fifo", 100, 250), _poller(clock, log, "adis", 2.5, 2.5)]
    reason = run_deadline(
        clock,
        pollers,
        MessageSink(lambda m: None),
        t0=0,
        end=500_000_000,
        between=between.append,
        should_stop=lambda: False,
        sleep=clock.sleep,
    )
    assert reason == ""
    adis = [t for n, t in log if n == "adis"]
    fifo = [t for n, t in log if n == "fifo"]
    assert np.diff(adis).max() == 1_250_000 and len(adis) == 400
    assert fifo == [100_000_000, 200_000_000, 300_000_000, 400_000_000, 500_000_000]
    # at 100 ms both were due: the short hold was polled first
    assert log.index(("adis", 100_000_000)) < log.index(("fifo", 100_000_000))
    assert between  # the hand-over ran while nothing was due


def test_a_late_poll_is_not_made_up_for_and_a_stop_is_seen():
    """A poll that costs 7 ms on a 1.25 ms step: the next one comes a step after it ends, not at once in a
    burst of catch-up polls; should_stop ends the loop at the next turn."""
    clock = VirtualClock()
    log: list[tuple[str, int]] = []
    polls = []
    slow = _poller(clock, log, "adis", 2.5, 2.5, cost_ms=7.0)
    stop = lambda: len(polls) >= 3  # noqa: E731
    pollers = [Poller("adis", "bus", slow.interval_ns, lambda s: (polls.append(1), slow.poll(s))[1], slow.hold_ns)]
    reason = run_deadline(
        clock,
        pollers,
        MessageSink(lambda m: None),
        t0=0,
        end=10**9,
        between=lambda t: None,
        should_stop=stop,
        sleep=clock.sleep,
    )
    assert reason == "stopped by signal"
    assert [t for _, t in log] == [1_250_000, 9_500_000, 17_750_000]


def test_the_last_poll_is_at_the_end_wherever_a_late_poll_moved_the_others():
    """A first poll of 150 ms moves the 100 ms grid (350, 450 ms); the capture ends at 500 ms, and its
    last poll is there, not at 450 ms with 50 ms of samples left unread."""
    clock = VirtualClock()
    log: list[tuple[str, int]] = []
    costs = iter([150.0])

    def poll(sink) -> int:
        log.append(("fifo", clock.now_ns()))
        clock.advance_to(clock.now_ns() + int(next(costs, 0.0) * 1e6))
        return 100_000_000

    run_deadline(
        clock,
        [Poller("fifo", "bus", 100_000_000, poll, 250_000_000)],
        MessageSink(lambda m: None),
        t0=0,
        end=500_000_000,
        between=lambda t: None,
        should_stop=lambda: False,
        sleep=clock.sleep,
    )
    assert [t // 1_000_000 for _, t in log] == [100, 350, 450, 500]


def _oversleeping(clock, late_s: float, late_at: dict[int, float] | None = None):
    """A sleep that returns ``late_s`` late (and ``late_at[k]`` late at its k-th call): a loaded host."""
    calls = itertools.count()

    def sleep(s: float) -> None:
        k = next(calls)
        clock.sleep(s + (late_at or {}).get(k, late_s))

    return sleep


def test_hybrid_sleep_starts_the_polls_of_a_chip_without_fifo_on_time_despite_late_sleeps():
    """Every sleep returns 0.3 ms late. Without spinning each ADIS16448 poll starts 0.3 ms after due; with
    0.5 ms of hybrid sleep the reader wakes 0.2 ms early and reads the clock until due (each turn 1 us
    here): on time. The FIFO device's polls are slept for as before (no spinning for a long hold)."""
    starts = {}
    for spin_ns in (0, 500_000):
        clock = VirtualClock()
        log: list[tuple[str, int]] = []
        turns = []
        stats = DeadlineStats()
        pollers = [_poller(clock, log, "fifo", 100, 250), _poller(clock, log, "adis", 2.5, 2.5)]
        run_deadline(
            clock,
            pollers,
            MessageSink(lambda m: None),
            t0=0,
            end=200_000_000,
            between=lambda t: None,
            should_stop=lambda: False,
            sleep=_oversleeping(clock, 0.0003),
            spin_ns=spin_ns,
            spin=lambda turns=turns, clock=clock: (turns.append(1), clock.sleep(1e-6)),
            stats=stats,
        )
        adis = np.array([t for n, t in log if n == "adis"])
        starts[spin_ns] = adis % 1_250_000, turns, stats  # how long after its due (the 1.25 ms grid)
    late, _, stats0 = starts[0]
    on_time, turns, stats = starts[500_000]
    assert np.median(late) == 300_000 and stats0.late == 0 and stats0.worst_ns >= 300_000
    assert on_time.max() <= 1_000 and 150 <= len(turns) / stats.polls <= 250 and stats.spun_ns > 0
    assert stats.hold_ns == 2_500_000 and stats.worst_ns <= 1_000


def test_polls_started_late_are_counted_and_noted_with_the_hosts_steal():
    """One sleep returns 20 ms late (the reader not run, as a virtual machine's throttled vCPU): the
    polls after it started over half a hold late are counted, the latest kept, and the reader's note
    names them and the hypervisor's steal time."""
    clock = VirtualClock()
    log: list[tuple[str, int]] = []
    stats = DeadlineStats()
    run_deadline(
        clock,
        [_poller(clock, log, "adis", 2.5, 2.5)],
        MessageSink(lambda m: None),
        t0=0,
        end=100_000_000,
        between=lambda t: None,
        should_stop=lambda: False,
        sleep=_oversleeping(clock, 0.0, {10: 0.020}),
        stats=stats,
    )
    assert stats.late == 1 and 20_000_000 <= stats.worst_ns < 21_250_000 and stats.polls == len(log)
    cfg = _config([{"name": "adis", "driver": "adis16448", "bus": "cp2130:?cs=0&hz=1000000"}])
    note = readers.lateness_note(cfg, stats, 0, 1.5)
    assert note.startswith(f"reader process for cp2130:?cs=0&hz=1000000: 1 of {stats.polls} polls started over 1.25 ms")
    assert "(the latest 20." in note and "1.50 s of CPU meanwhile (steal)" in note
    assert readers.lateness_note(cfg, DeadlineStats(hold_ns=2_500_000), 0, 0.0) == ""


# -- the hand-off ---------------------------------------------------------------------------------
def test_the_outbox_never_blocks_on_a_full_pipe_and_delivers_every_message_in_order():
    """Nobody reads the pipe while the reader sends 16 MiB: every send returns at once (the pipe is
    non-blocking, the rest waits in memory); then a main side reads every message, in order, with
    Connection.recv, while the reader goes on ticking; a "stop" on the control pipe is seen at a send."""
    data_r, data_w = mp.Pipe(duplex=False)
    ctl_main, ctl_reader = mp.Pipe()
    out = HostOutbox(data_w, lambda: ({}, {}), ctl_reader)
    block = np.arange(2**17, dtype=np.int64)  # 1 MiB
    for k in range(8):
        out.append("dev", block + k, {"gyro": block}, None)
        out.send("items", k)
    assert len(out.pending) > 0  # the pipe is full: the rest waits, and send() returned
    got: list[tuple] = []

    def main_side():
        while not got or got[-1][3] != 7:
            msg = data_r.recv()
            if msg[1]:
                got.append(msg)

    th = threading.Thread(target=main_side, daemon=True)
    th.start()
    while th.is_alive() and out.pending:
        out.tick(-1)
    th.join()
    assert [m[3] for m in got] == list(range(8))
    assert all(m[1][0][0] == APPEND and m[1][0][2][0] == k for k, m in enumerate(got))
    ctl_main.send(("stop",))
    out.send("items", 8)
    assert out.should_stop()
    for c in (data_r, data_w, ctl_main, ctl_reader):
        c.close()


def test_a_readers_times_move_onto_the_runs_origin():
    t = np.array([10, 20], dtype=np.int64)
    msg = (APPEND, "dev", t, {"gyro": np.zeros((2, 3))}, None)
    assert shifted(msg, 5)[2].tolist() == [15, 25] and t.tolist() == [10, 20]
    assert shifted((EVENT, 7, "dev", "gap", "", 3), 5) == (EVENT, 12, "dev", "gap", "", 3)


# -- scheduling asked of the OS -------------------------------------------------------------------
def test_priority_ranks_readers_by_hold_time():
    assert realtime.reader_priority(40, 1 / 409.6) == 48  # ADIS16448: 2.4 ms
    assert realtime.reader_priority(40, 0.21) == 42  # a FIFO of a fifth of a second
    assert realtime.reader_priority(40, float("inf")) == 40  # thermometers only
    assert realtime.reader_priority(45, 1e-5) == realtime.READER_PRIORITY_MAX
    assert realtime.reader_priority(0, 0.001) == 0


def test_refused_scheduling_is_one_line_saying_how_to_grant_it(monkeypatch):
    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(os, "setpriority", refuse)
    monkeypatch.setattr(realtime, "_mlockall", lambda: False)
    got = realtime.request_scheduling(priority=48)
    assert got.policy == "normal" and not got.memory_locked
    assert "\n" not in got.missing
    for word in ("LimitRTPRIO=48", "CAP_SYS_NICE", "LimitMEMLOCK=infinity", "CAP_IPC_LOCK"):
        assert word in got.missing
    granted = []
    monkeypatch.setattr(os, "sched_setscheduler", lambda *a: granted.append(a))
    monkeypatch.setattr(realtime, "_mlockall", lambda: True)
    got = realtime.request_scheduling(priority=48)
    assert got.missing == "" and got.describe() == "SCHED_FIFO 48, memory locked"
    assert granted[0][1] == os.SCHED_FIFO
    with pytest.raises(InputError, match="--reader-cpus 4096"):
        realtime.request_scheduling(priority=0, cpus=(4096,))


def test_real_time_options_are_checked(tmp_path):
    from click.testing import CliRunner

    from imustation.cli import cli
    from imustation.configs import config_path

    demo = str(config_path("demo.toml"))
    for args, words in [
        (["--real-time"], "needs --simulate"),
        (["--simulate", "--real-time", "--workers", "2"], "--workers 2"),
        (["--simulate", "--real-time", "--sim-level", "model"], "--sim-level model"),
        (["--simulate", "--real-time", "--reader-cpus", "x"], "--reader-cpus 'x'"),
    ]:
        res = CliRunner().invoke(cli, ["capture", demo, "-o", str(tmp_path / "r.h5"), *args])
        assert res.exit_code == 2 and words in res.output, (args, res.output)
    assert not (tmp_path / "r.h5").exists()


# -- whole captures with reader processes -----------------------------------------------------------
def _consistent(path):
    with open_run(path) as run:
        checks = check_run(run)
        assert run.complete
        for name, check in checks.items():
            assert check.consistent and not check.unlogged, (name, check)
            assert (np.diff(run.read(name, "t")) > 0).all()
        return run.devices, run.events()


def test_every_bus_in_its_own_reader_process_hands_everything_to_the_writer(tmp_path):
    """Two buses, two reader processes; the writer keeps every sample and every loss; each reader's
    scheduling is noted in the file."""
    cfg = _config([{"name": "a", "bus": "i2c:1", **GYRO}, {"name": "b", "bus": "i2c:2", **GYRO}])
    out = tmp_path / "rt.h5"
    statuses = []
    summary = capture(
        cfg, out, 1.0, simulate=True, real_time=True, reader_priority=0, on_status=statuses.append,
        status_interval_s=0.05,
    )  # fmt: skip
    devices, events = _consistent(out)
    for name in ("a", "b"):
        lost = sum(e.lost for e in events if e.source == name)
        assert devices[name].n == summary.samples[name] > 0
        assert lost == summary.lost[name]
    notes = [e.detail for e in events if e.kind == "note"]
    assert "reader process for i2c:1: normal, memory not locked" in notes
    assert "reader process for i2c:2: normal, memory not locked" in notes
    assert set(summary.reader_cpu_s) == {"i2c:1", "i2c:2"}
    assert statuses[-1]["state"] == "done"


def test_a_chip_without_fifo_polled_on_its_phase_accounts_for_every_sample(tmp_path):
    """The ADIS16448 (no FIFO) in a reader process on the host clock, its reads aimed just after each sample
    (acquisition/pollphase.py): whatever this host loses, every sample is written or logged lost, by the
    file's own check (reads about a period apart, near the instant the chip makes its samples, are what
    the Timeline's loss count must get right here)."""
    cfg = _config([{"name": "adis", "driver": "adis16448", "bus": "cp2130:?cs=0", "decimation": 1}])
    out = tmp_path / "adis.h5"
    summary = capture(cfg, out, 1.5, simulate=True, real_time=True, reader_priority=0)
    devices, events = _consistent(out)
    assert devices["adis"].n == summary.samples["adis"] > 400
    assert sum(e.lost for e in events if e.source == "adis") == summary.lost["adis"]


def test_a_reader_process_that_dies_is_a_logged_fault_not_a_lost_capture(tmp_path, monkeypatch):
    """Trigger: at the first status showing samples from bus i2c:2, its reader process is killed
    (SIGKILL); restarts are off (a cap of 0 an hour). The capture goes on with i2c:1 and finishes the
    file: the dead reader's device has a fault event naming it, and a gap counting what it did not read
    to the end; the status says failed."""
    monkeypatch.setattr(restarts, "RESTARTS_PER_HOUR", 0)
    cfg = _config([{"name": "a", "bus": "i2c:1", **GYRO}, {"name": "b", "bus": "i2c:2", **GYRO}])
    out = tmp_path / "dead.h5"
    killed = []
    statuses = []

    def on_status(status):
        statuses.append(status)
        if not killed and status["devices"]["b"]["samples"] > 0:
            reader = next(p for p in mp.active_children() if p.name == "imustation-reader-2")
            os.kill(reader.pid, signal.SIGKILL)
            killed.append(reader.pid)

    summary = capture(
        cfg, out, 1.5, simulate=True, real_time=True, reader_priority=0, on_status=on_status, status_interval_s=0.02
    )
    assert killed
    devices, events = _consistent(out)
    fault = [e for e in events if e.source == "b" and e.kind == "fault"]
    assert len(fault) == 1 and "reader process for b ended during the run" in fault[0].detail
    assert "exit code -9" in fault[0].detail and "not read for the rest of the capture" in fault[0].detail
    gap = [e for e in events if e.source == "b" and e.kind == "gap" and "not read to the end" in e.detail]
    assert len(gap) == 1 and gap[0].lost > 0
    assert devices["b"].n == summary.samples["b"] > 0
    assert not [e for e in events if e.source == "a" and e.kind == "fault"]
    assert devices["a"].n == summary.samples["a"] > devices["b"].n
    final = statuses[-1]["devices"]["b"]
    assert final["state"] == "failed" and final["faults"] == 1 and final["lost"] == summary.lost["b"]


def test_a_dead_reader_process_is_started_again_and_its_devices_record_again(tmp_path):
    """Triggers: at the first status showing samples from bus i2c:2 its reader process is killed
    (and the thermometer beside it) its reader process is killed (SIGKILL); at the first status after
    that showing b recording again, with more samples and readings than before the kill, the capture
    is stopped (SIGINT). The reader was started again after its first
    back-off (1 s: the outage is at least that long, so b and the thermometer beside it miss samples
    whatever the machine's speed): b has one fault, one reconnect, one gap for the outage, samples after
    it, and the file's hole check
    holds (written + logged losses = produced), for the thermometer on that bus too; the status went
    failed, then ok; a's reader never died."""
    cfg = parse_config(
        {
            "station": {"seed": 3, "flush_interval_s": 0.2},
            "device": [{"name": "a", "bus": "i2c:1", **GYRO}, {"name": "b", "bus": "i2c:2", **GYRO}],
            "thermometer": [{"name": "amb", "driver": "mcp9804", "bus": "i2c:2", "address": 0x18, "rate_hz": 4}],
        }
    )
    out = tmp_path / "restart.h5"
    killed: list[int] = []
    states: list[str] = []
    statuses = []

    def on_status(status):
        statuses.append(status)
        b, amb = status["devices"]["b"], status["thermometers"]["amb"]
        if not killed and b["samples"] > 0 and amb["readings"] > 0:
            reader = next(p for p in mp.active_children() if p.name == "imustation-reader-2")
            os.kill(reader.pid, signal.SIGKILL)
            killed.extend((b["samples"], amb["readings"]))
        elif killed and "stop" not in states:
            states.append(b["state"])
            again = b["samples"] > killed[0] and amb["readings"] > killed[1]
            if b["state"] == "ok" and "failed" in states and again:
                os.kill(os.getpid(), signal.SIGINT)
                states.append("stop")

    summary = capture(
        cfg, out, 120.0, simulate=True, real_time=True, reader_priority=0, on_status=on_status, status_interval_s=0.02
    )
    assert killed and "stop" in states and summary.stop_reason.startswith("stopped by signal")
    devices, events = _consistent(out)
    mine = [e for e in events if e.source == "b"]
    fault = [e for e in mine if e.kind == "fault"]
    assert len(fault) == 1 and "exit code -9" in fault[0].detail and "starting it again in 1 s" in fault[0].detail
    again = [e for e in mine if e.kind == "reconnect"]
    assert len(again) == 1 and "started again after 1 attempt(s)" in again[0].detail
    outage = [e for e in mine if e.kind == "gap" and "was not running" in e.detail]
    assert len(outage) == 1 and outage[0].lost > 0
    assert not [e for e in mine if "not read to the end" in e.detail]
    with open_run(out) as run:
        t = run.read("b", "t")
        amb = check_thermometers(run)["amb"]
    # the thermometer on the dead reader's bus: its readings missed in the outage are logged too
    assert amb is not None and amb.consistent and amb.holes.samples > 0, amb
    assert [e.kind for e in events if e.source == "amb" and e.lost] == ["gap"]
    assert (t > again[0].t_ns).sum() > 0 and (t < fault[0].t_ns).sum() > 0
    assert devices["b"].n == summary.samples["b"] and sum(e.lost for e in mine) == summary.lost["b"]
    assert not [e for e in events if e.source == "a" and e.kind in ("fault", "reconnect")]
    final = statuses[-1]["devices"]["b"]
    assert final["state"] == "ok" and final["faults"] == 1 and final["lost"] == summary.lost["b"]


def test_a_successor_killed_too_is_another_attempt_and_the_devices_still_come_back(tmp_path):
    """Triggers: the reader of i2c:2 is killed at b's first samples, and its successor as soon as a status
    sees it (mostly while it opens its devices: a failed attempt; if it was already recording, a second
    fault); once b records again with more samples the capture is stopped. Either way b comes back after
    its back-offs (1 s, 2 s), every fault has its reconnect, and the file's hole check holds."""
    cfg = _config([{"name": "a", "bus": "i2c:1", **GYRO}, {"name": "b", "bus": "i2c:2", **GYRO}])
    out = tmp_path / "twice.h5"
    pids: list[int] = []
    seen = {"samples": 0, "stop": False}
    statuses = []

    def on_status(status):
        statuses.append(status)
        b = status["devices"]["b"]
        reader = next((p for p in mp.active_children() if p.name == "imustation-reader-2"), None)
        if reader is not None and len(pids) < 2 and reader.pid not in pids and (pids or b["samples"] > 0):
            os.kill(reader.pid, signal.SIGKILL)
            pids.append(reader.pid)
            seen["samples"] = b["samples"]
        elif len(pids) == 2 and not seen["stop"] and b["state"] == "ok" and b["samples"] > seen["samples"]:
            seen["stop"] = True
            os.kill(os.getpid(), signal.SIGINT)

    summary = capture(
        cfg, out, 120.0, simulate=True, real_time=True, reader_priority=0, on_status=on_status, status_interval_s=0.02
    )
    assert len(pids) == 2 and seen["stop"] and summary.stop_reason.startswith("stopped by signal")
    devices, events = _consistent(out)
    mine = [e for e in events if e.source == "b"]
    faults = [e for e in mine if e.kind == "fault"]
    again = [e for e in mine if e.kind == "reconnect"]
    assert 1 <= len(faults) == len(again) <= 2
    if len(faults) == 1:  # the successor died opening: one fault, two attempts
        assert "started again after 2 attempt(s)" in again[0].detail
    assert devices["b"].n == summary.samples["b"] and sum(e.lost for e in mine) == summary.lost["b"]
    final = statuses[-1]["devices"]["b"]
    assert final["state"] == "ok" and final["faults"] == len(faults)


def test_the_restart_state_of_a_lost_reader(monkeypatch):
    """restarts.Restarts on explicit times: lost -> backed off 1 s -> due -> started (opening) -> reopened
    after 1 attempt; lost again -> 2 s; a successor that takes longer than the open timeout is too long;
    a cap of 0 never starts it again."""
    r = restarts.Restarts(open_timeout_s=120.0)
    assert not r.pending and r.lost(100.0) == 1.0 and r.pending
    assert not r.due(100.5) and r.due(101.0)
    r.started(101.0)
    assert r.reopening and not r.due(200.0) and not r.opening_too_long(221.0) and r.opening_too_long(221.5)
    assert r.reopened() == 1 and not r.pending
    assert r.lost(300.0) == 2.0  # one restart within the hour before
    r.cancel()
    assert not r.pending
    monkeypatch.setattr(restarts, "RESTARTS_PER_HOUR", 0)
    assert r.lost(400.0) is None and not r.pending


def test_restarts_back_off_and_are_capped_per_hour(monkeypatch):
    """A reader that dies at once is started again after 1, 2, 4 ... s, at most 60 s; the eleventh restart
    within an hour waits for the first to be an hour old; a cap of 0 never starts it again."""
    started: list[float] = []
    delays = []
    now = 1000.0
    for _ in range(10):
        delays.append(restarts.restart_delay(started, now))
        now += delays[-1]
        started.append(now)
    assert delays == [1, 2, 4, 8, 16, 32, 60, 60, 60, 60]
    assert restarts.restart_delay(started, now) == pytest.approx(1001.0 + 3600.0 - now)
    assert restarts.restart_delay(started, 1001.0 + 3600.0 + 1.0) == 60.0  # the first has aged out
    assert restarts.restart_delay([], 5000.0 + 3 * 3600) == 1.0
    monkeypatch.setattr(restarts, "RESTARTS_PER_HOUR", 0)
    assert restarts.restart_delay([], now) is None


def test_reader_messages_pickle_as_the_main_side_expects():
    """A frame of the outbox is what Connection.recv reads (length prefix and pickle)."""
    r, w = mp.Pipe(duplex=False)
    ctl_a, ctl_b = mp.Pipe()
    out = HostOutbox(w, lambda: ({"x": 1}, {}), ctl_b)
    out.event(5, "dev", "note", "hello")
    out.send("started", 0, 123)
    msg = r.recv()
    assert msg == ("started", [(EVENT, 5, "dev", "note", "hello", 0)], ({"x": 1}, {}), 0, 123)
    assert isinstance(r, Connection) and pickle.loads(pickle.dumps(msg)) == msg
    for c in (r, w, ctl_a, ctl_b):
        c.close()


def test_rotation_with_reader_processes_keeps_every_sample(tmp_path):
    """Parts are cut at the time every reader has reached: 2.5 s in parts of 1 s are three complete
    files holding every sample the summary counts."""
    from imustation.acquisition.recorder import part_path

    cfg = _config([{"name": "a", "bus": "i2c:1", **GYRO}])
    out = tmp_path / "rot.h5"
    summary = capture(cfg, out, 2.5, simulate=True, real_time=True, reader_priority=0, rotate_s=1.0)
    assert summary.paths == [part_path(str(out), k) for k in (1, 2, 3)]
    total = 0
    for path in summary.paths:
        with open_run(path) as run:
            assert run.complete
            total += run.devices["a"].n
    assert total == summary.samples["a"] > 0
