"""Simulated captures split over worker processes (``capture --workers N``)."""

import multiprocessing
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from click.testing import CliRunner
from procs import wait_for_file, wait_for_rows

from imustation.acquisition import capture, load_config
from imustation.acquisition.config import parse_config
from imustation.acquisition.workers import bus_groups, partition, picklable
from imustation.cli import cli
from imustation.configs import config_path
from imustation.errors import BusError, ChipIdMismatch, DeviceError, DiskFullError, InputError
from imustation.runfile import RunWriter, open_run


def two_buses(adis_faults=()):
    return parse_config(
        {
            "station": {"seed": 3},
            "device": [
                {"name": "gyro", "driver": "bmx055", "bus": "i2c:1", "address": 0x68, "rate_hz": 400,
                 "bandwidth_hz": 47},
                {"name": "adis", "driver": "adis16448", "bus": "cp2130:", "sim": {"faults": list(adis_faults)}},
            ],
            "thermometer": [{"name": "amb", "driver": "mcp9804", "bus": "i2c:1", "address": 0x18}],
        }
    )  # fmt: skip


def test_partition_puts_the_heavy_bus_alone_and_keeps_buses_whole():
    cfg = load_config(config_path("lab-example.toml"))
    shares = partition(cfg, 2)
    assert shares[1][0] == "adis" and "adis" not in shares[0]  # the FIFO-less SPI device costs most per sample
    assert sorted(shares[0] + shares[1]) == sorted([d.name for d in cfg.devices] + [t.name for t in cfg.thermometers])
    for names in bus_groups(cfg).values():
        assert any(set(names) <= set(s) for s in shares)
    assert len(partition(cfg, 1)) == 1


def test_a_capture_on_two_processes_records_what_one_does(tmp_path):
    faults = [{"kind": "checksum", "at_s": 5}]
    one = capture(two_buses(faults), tmp_path / "one.h5", 30.0, simulate=True)
    statuses = []
    two = capture(two_buses(faults), tmp_path / "two.h5", 30.0, simulate=True, workers=2, on_status=statuses.append)
    assert two.samples == one.samples and two.lost == one.lost and two.readings == one.readings
    assert two.samples["adis"] + two.lost["adis"] == round(30 * 409.6)
    with open_run(tmp_path / "one.h5") as r1, open_run(tmp_path / "two.h5") as r2:
        assert sorted(r2.devices) == sorted(r1.devices) == ["adis", "gyro"]
        assert r2.devices["adis"].settings == r1.devices["adis"].settings
        for dev in ("gyro", "adis"):
            assert r2.devices[dev].n == two.samples[dev]
            t = r2.read(dev, "t")
            assert (np.diff(t) > 0).all() and t[0] >= 0
            # same turn-on bias (seeded by the device name), another noise realisation
            g1, g2 = r1.read(dev, "gyro").astype(float), r2.read(dev, "gyro").astype(float)
            assert np.abs(g1.mean(0) - g2.mean(0)).max() < 6 * g1.std(0).max() / np.sqrt(len(g1))
        ev = [(e.source, e.kind, e.lost) for e in r2.events()]
        assert ("adis", "gap", 1) in ev  # the worker's device event reached the file
        assert len(r2.temperatures("amb")[1]) == two.readings["amb"]
    final = statuses[-1]
    assert final["state"] == "done" and final["devices"]["adis"]["samples"] == two.samples["adis"]
    # each device's rate over its own process's time
    assert final["devices"]["adis"]["rate_hz"] == pytest.approx(409.6, rel=0.01)
    assert final["devices"]["gyro"]["rate_hz"] == pytest.approx(400.0, rel=0.01)
    assert not multiprocessing.active_children()


def test_a_worker_device_that_cannot_open_stops_the_capture_with_its_error(tmp_path):
    dead = [{"kind": "disconnect", "at_s": 0, "duration_s": 1e6}]
    with pytest.raises(BusError, match="CP2130") as info:
        capture(two_buses(dead), tmp_path / "x.h5", 30.0, simulate=True, workers=2)
    assert "simulation worker for adis" in "".join(getattr(info.value, "__notes__", []))
    assert not (tmp_path / "x.h5").exists()
    assert not multiprocessing.active_children()


def test_sigterm_stops_every_process_and_finishes_the_file(tmp_path):
    sent = []

    def on_status(status):
        # SIGTERM once both processes have recorded (a timer would race the workers' start on a loaded machine)
        if not sent and all(d["samples"] > 0 for d in status["devices"].values()):
            sent.append(status)
            os.kill(os.getpid(), signal.SIGTERM)

    summary = capture(
        two_buses(),
        tmp_path / "s.h5",
        3600.0,
        simulate=True,
        workers=2,
        pace=20.0,
        on_status=on_status,
        status_interval_s=0.05,
    )
    assert sent
    assert summary.stop_reason == "stopped by signal SIGTERM"
    with open_run(tmp_path / "s.h5") as run:
        assert run.complete
        for dev in ("gyro", "adis"):
            assert 0 < run.devices[dev].n == summary.samples[dev]
    assert not multiprocessing.active_children()


def test_workers_option_is_checked(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[[device]]\nname = "g"\ndriver = "bmx055"\nbus = "i2c:1"\n')
    runner = CliRunner()
    res = runner.invoke(cli, ["capture", str(cfg), "--simulate", "--workers", "0", "-o", str(tmp_path / "a.h5")])
    assert res.exit_code == 2 and "--workers '0': a whole number >= 1, or auto" in res.output
    res = runner.invoke(cli, ["capture", str(cfg), "--workers", "2", "-o", str(tmp_path / "b.h5")])
    assert res.exit_code == 2 and "only a simulated capture" in res.output


TWO_BUSES_TOML = (
    '[[device]]\nname = "gyro"\ndriver = "bmx055"\nbus = "i2c:1"\nrate_hz = 400\nbandwidth_hz = 47\n'
    '[[device]]\nname = "adis"\ndriver = "adis16448"\nbus = "cp2130:"\n'
)


def _children(pid: int) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    stat = fh.read()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry))
    return out


def test_workers_end_when_the_main_process_is_killed(tmp_path):
    cfg = tmp_path / "two.toml"
    cfg.write_text(TWO_BUSES_TOML)
    out = tmp_path / "k.h5"
    cmd = [sys.executable, "-m", "imustation", "capture", str(cfg), "--simulate", "-o", str(out), "--quiet"]
    proc = subprocess.Popen([*cmd, "--duration", "1h", "--workers", "2", "--sim-speed", "50"], stderr=subprocess.PIPE)
    try:
        wait_for_file(out, proc)
        kids = _children(proc.pid)
        assert kids  # the worker polling the ADIS16448
        proc.kill()
        proc.wait()
        t_end = time.monotonic() + 20
        while any(os.path.exists(f"/proc/{k}") and _alive(k) for k in kids) and time.monotonic() < t_end:
            time.sleep(0.1)
        assert not [k for k in kids if os.path.exists(f"/proc/{k}") and _alive(k)]
    finally:
        if proc.poll() is None:
            proc.kill()
    with open_run(out) as run:  # the main process wrote the file; it opens after the kill
        assert run.rows("gyro") >= 0


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_rotation_is_refused_with_workers(tmp_path):
    # parts must end at their times for every device; processes reach a time at different moments
    with pytest.raises(InputError, match="--workers 2 with --rotate"):
        capture(two_buses(), tmp_path / "rot.h5", 50.0, simulate=True, workers=2, rotate_s=20.0)
    assert not list(tmp_path.iterdir())


def test_a_stop_signal_to_the_whole_process_group_finishes_the_file(tmp_path):
    """systemd and ``kill -- -PGID`` signal every process of the group, workers included."""
    cfg = tmp_path / "two.toml"
    cfg.write_text(TWO_BUSES_TOML)
    out = tmp_path / "g.h5"
    cmd = [sys.executable, "-m", "imustation", "capture", str(cfg), "--simulate", "-o", str(out), "--quiet"]
    cmd += ["--duration", "1h", "--workers", "2", "--sim-speed", "50"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        wait_for_file(out, proc)
        wait_for_rows(out, proc, ("adis", "gyro"))  # both processes' devices are recording
        os.killpg(proc.pid, signal.SIGTERM)
        outp, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, err
    assert "stopped by signal SIGTERM" in outp
    with open_run(out) as run:
        assert run.complete and run.rows("adis") > 0 and run.rows("gyro") > 0


def test_a_full_disk_stops_every_process_with_a_complete_file(tmp_path, monkeypatch):
    def free_bytes(self):
        # the disk "fills" once both processes' devices have data on it: a trigger on the
        # data, not on how many flushes the machine's speed allowed
        on_disk = all(self._f[f"devices/{name}/t"].shape[0] > 0 for name in ("adis", "gyro"))
        return 1000 if on_disk else 10**12

    monkeypatch.setattr(RunWriter, "free_bytes", free_bytes)
    out = tmp_path / "full.h5"
    with pytest.raises(DiskFullError, match="disk full"):
        capture(two_buses(), out, 600.0, simulate=True, workers=2)
    with open_run(out) as run:
        assert run.complete and run.attrs["stopped"] == "disk full"
        assert run.rows("adis") > 0 and run.rows("gyro") > 0
    assert not multiprocessing.active_children()


def test_a_worker_device_pulled_and_replugged_is_logged_and_resumed(tmp_path):
    pulled = [{"kind": "disconnect", "at_s": 10, "duration_s": 2}]
    summary = capture(two_buses(pulled), tmp_path / "p.h5", 30.0, simulate=True, workers=2)
    with open_run(tmp_path / "p.h5") as run:
        kinds = [(e.source, e.kind) for e in run.events()]
        t = run.read("adis", "t")
    assert ("adis", "fault") in kinds and ("adis", "reconnect") in kinds
    assert summary.lost["adis"] > 0.5 * 2 * 409.6  # about the 2 s it was gone
    assert summary.samples["adis"] + summary.lost["adis"] == pytest.approx(30 * 409.6, abs=3)
    assert (t[-1] - t[0]) / 1e9 > 28 and (np.diff(t) > 0).all()


def test_worker_errors_that_do_not_pickle_keep_their_class_family_and_message():
    exc = ChipIdMismatch("ADIS16448", 0x4040, 0xFFFF, "cp2130:")
    twin = picklable(exc)
    assert isinstance(twin, DeviceError) and str(twin) == str(exc)
    assert picklable(BusError("gone")) is not None and str(picklable(BusError("gone"))) == "gone"
