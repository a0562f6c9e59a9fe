"""Simulated captures at the noise-model level (``--sim-level model``, acquisition/modelsim.py)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.acquisition import capture, load_config
from imustation.acquisition.config import parse_config
from imustation.acquisition.recorder import run_file_device
from imustation.acquisition.station import Station
from imustation.cli import cli
from imustation.configs import config_path
from imustation.drivers.sim import device_sources, station_device_seed
from imustation.errors import ConfigError, InputError
from imustation.runfile import RunWriter, open_run
from imustation.runfile.holes import check_run


def _record(cfg, path, seconds: float, **kw):
    """A model-level capture through the station itself, so the devices' own counts can be checked."""
    station = Station(cfg, simulate=True, sim_level="model", **kw)
    try:
        specs = station.open()
        with RunWriter(
            path,
            station=cfg.name,
            config_text="",
            simulated=True,
            devices=[run_file_device(d) for d in specs],
            thermometers=list(station.thermometers),
        ) as writer:
            summary = station.run(writer, seconds)
        produced = {n: st.driver.produced for n, st in station.devices.items() if st.driver is not None}
    finally:
        station.close()
    return summary, produced


def _one(driver: str, faults=(), **settings):
    bus = "sim:" if driver in ("adis16448", "mti", "dsp3000") else "i2c:1"
    dev = {"name": "d", "driver": driver, "bus": bus, **settings}
    if faults:
        dev["sim"] = {"faults": list(faults)}
    return parse_config({"station": {"seed": 5}, "device": [dev]})


@pytest.fixture(scope="module")
def lab_model_run(tmp_path_factory):
    cfg = load_config(config_path("lab-example.toml"))
    path = tmp_path_factory.mktemp("model") / "lab.h5"
    summary, produced = _record(cfg, path, 120.0)
    return cfg, path, summary, produced


def test_every_device_and_thermometer_of_the_lab_is_recorded_at_its_rate(lab_model_run):
    cfg, path, summary, produced = lab_model_run
    with open_run(path) as run:
        assert set(run.devices) == {d.name for d in cfg.devices}
        for name, dev in run.devices.items():
            t = run.read(name, "t")
            # samples written = samples produced since the start - logged losses, exactly
            lost = sum(e.lost for e in run.events() if e.source == name)
            assert dev.n == summary.samples[name] and summary.lost[name] == lost
            assert np.all(np.diff(t) > 0), name
            # the last poll is at most one poll interval before the end
            assert dev.n + lost == pytest.approx(120.0 * dev.rate_hz, abs=1.0 * dev.rate_hz + 1), name
        # and the file alone shows it: every hole logged, every logged loss in a hole
        assert all(c.consistent and c.holes.short == 0 for c in check_run(run).values())
        for th in cfg.thermometers:
            t, c = run.temperatures(th.name)
            assert len(t) == summary.readings[th.name] == 120
            assert np.all((c > 15) & (c < 30))


def _run_one(cfg, seconds: float):
    """Record the config's device ``d`` at the model level into a list sink.

    Returns its state, the sink and the samples it produced before the start (dropped then).
    """
    station = Station(cfg, simulate=True, sim_level="model")
    try:
        station.open()
        sink = _ListSink()
        station.run(sink, seconds)
    finally:
        station.close()
    st = station.devices["d"]
    due_at_start = st.driver.stream.due(station.t0 - st.driver._origin_ns)
    return st, sink, due_at_start


def test_samples_written_equal_samples_produced_minus_losses():
    # a disconnect and a checksum fault, on a device with a counter (ADIS16448) and one without
    faults = [{"kind": "disconnect", "at_s": 30.5, "duration_s": 4.2}, {"kind": "checksum", "every_s": 7}]
    for driver in ("adis16448", "bmx055"):
        fl = faults if driver == "adis16448" else faults[:1]
        st, writer, due_at_start = _run_one(_one(driver, fl), 90.0)
        # every sample the device produced was dropped at the start (due before t0), written or lost
        assert st.driver.produced == due_at_start + st.samples + st.lost, driver
        assert writer.samples == st.samples and writer.lost == st.lost > 4 * st.info.rate_hz
        kinds = [e[2] for e in writer.events]
        assert "fault" in kinds and "reconnect" in kinds, driver
        if driver == "adis16448":
            bad = [e for e in writer.events if "checksum" in e[3]]
            assert len(bad) >= 5 and all(e[4] >= 1 for e in bad)


class _ListSink:
    def __init__(self):
        self.samples = 0
        self.lost = 0
        self.events: list[tuple] = []
        self.counters: list[np.ndarray] = []

    def append(self, device, t_ns, channels, counter) -> None:
        self.samples += len(t_ns)
        if counter is not None:
            self.counters.append(np.asarray(counter))

    def append_temperature(self, name, t_ns, celsius) -> None:
        pass

    def event(self, t_ns, source, kind, detail="", lost=0) -> None:
        self.events.append((t_ns, source, kind, detail, lost))
        self.lost += lost


def test_the_counts_are_the_noise_sources_converted_as_the_chips_do(tmp_path):
    """Oracle: the device's source with the same seed, asked in the chips' pieces, rint(value / scale)."""
    cfg = _one("bmx055")
    path = tmp_path / "g.h5"
    summary, produced = _record(cfg, path, 20.0)
    dev = cfg.devices[0]
    src = device_sources(dev, station_device_seed(cfg.seed, dev.name))["gyro"]
    with open_run(path) as run:
        raw = run.read("d", "gyro")
        scale = run.devices["d"].channels["gyro"].scale
    skipped = produced["d"] - len(raw)  # drawn before the start
    expected = np.concatenate([src.next(100) for _ in range((produced["d"] + 99) // 100)])
    np.testing.assert_array_equal(raw, np.rint(expected[skipped : skipped + len(raw)] / scale))
    assert summary.samples["d"] == len(raw)


def test_the_model_level_records_what_the_bus_level_records(tmp_path):
    """Same sources and seeds: the bus-level gyro samples appear, in order, in the model-level stream."""
    cfg = _one("bmx055")
    capture(cfg, tmp_path / "bus.h5", 20.0, simulate=True)
    capture(cfg, tmp_path / "model.h5", 20.0, simulate=True, sim_level="model")
    with open_run(tmp_path / "bus.h5") as a, open_run(tmp_path / "model.h5") as b:
        bus, model = a.read("d", "gyro"), b.read("d", "gyro")
        assert a.devices["d"].channels["gyro"].scale == b.devices["d"].channels["gyro"].scale
        assert any("noise-model level" in e.detail for e in b.events())
        assert not any("noise-model level" in e.detail for e in a.events())
    head = bus[:64]
    hits = [i for i in range(len(model) - 64) if np.array_equal(model[i : i + 64], head)]
    assert len(hits) == 1
    k = min(len(bus), len(model) - hits[0])
    assert k > 0.9 * 20 * 400
    np.testing.assert_array_equal(model[hits[0] : hits[0] + k], bus[:k])


@pytest.mark.parametrize(
    "driver,fault,needle",
    [
        (
            "bmx055",
            {"kind": "nack", "every_s": 5},
            r"sim.faults\[0\].kind: 'nack' is simulated at --sim-level bus only",
        ),
        ("bmx055", {"kind": "checksum", "every_s": 5}, r"'checksum': driver 'bmx055' reads no checksum"),
        ("adis16448", {"kind": "stall", "at_s": 5, "duration_s": 1}, "'stall' is simulated at --sim-level bus only"),
    ],
)
def test_faults_the_model_level_cannot_simulate_are_refused_at_open(driver, fault, needle):
    station = Station(_one(driver, [fault]), simulate=True, sim_level="model")
    try:
        with pytest.raises(ConfigError, match=needle):
            station.open()
    finally:
        station.close()


def test_adis_without_crc_refuses_checksum_faults():
    station = Station(
        _one("adis16448", [{"kind": "checksum", "every_s": 5}], crc=False), simulate=True, sim_level="model"
    )
    try:
        with pytest.raises(ConfigError, match="reads no checksum"):
            station.open()
    finally:
        station.close()


def test_sim_level_is_checked(tmp_path):
    cfg = _one("bmx055")
    with pytest.raises(InputError, match="--sim-level 'fast': bus or model"):
        capture(cfg, tmp_path / "a.h5", 1.0, simulate=True, sim_level="fast")
    with pytest.raises(InputError, match="--sim-level model: only a simulated capture"):
        capture(cfg, tmp_path / "a.h5", 1.0, simulate=False, sim_level="model")
    assert not (tmp_path / "a.h5").exists()
    res = CliRunner().invoke(cli, ["capture", "x.toml", "--sim-level", "model"])
    assert res.exit_code != 0
    res = CliRunner().invoke(
        cli, ["capture", config_path("demo.toml"), "-o", str(tmp_path / "b.h5"), "--sim-level", "model"]
    )
    assert res.exit_code == 2 and "--sim-level model: needs --simulate" in res.output
    assert not (tmp_path / "b.h5").exists()


def test_cli_model_level_capture_on_two_processes(tmp_path):
    out = tmp_path / "lab.h5"
    res = CliRunner().invoke(
        cli,
        [
            "capture",
            config_path("lab-example.toml"),
            "-o",
            str(out),
            "--simulate",
            "--sim-level",
            "model",
            "--duration",
            "60s",
            "--workers",
            "2",
            "--quiet",
        ],
    )
    assert res.exit_code == 0, res.output
    with open_run(out) as run:
        assert len(run.devices) == 7
        for name, dev in run.devices.items():
            lost = sum(e.lost for e in run.events() if e.source == name)
            assert dev.n + lost == pytest.approx(60 * dev.rate_hz, abs=dev.rate_hz + 1), name
        assert any("noise-model level" in e.detail for e in run.events())


def test_a_fault_the_model_level_cannot_simulate_is_one_line_naming_file_and_key(tmp_path):
    cfg = tmp_path / "st.toml"
    cfg.write_text(
        'station.name = "t"\n[[device]]\nname = "g"\ndriver = "bmx055"\nbus = "i2c:1"\n'
        '[device.sim]\nfaults = [{kind = "nack", every_s = 10}]\n'
    )
    out = tmp_path / "r.h5"
    args = ["capture", str(cfg), "-o", str(out), "--simulate", "--duration", "10s", "--quiet"]
    res = CliRunner().invoke(cli, [*args, "--sim-level", "model"])
    assert res.exit_code == 2, res.output
    line = res.output.strip().splitlines()[-1]
    assert str(cfg) in line and "g.sim.faults[0].kind: 'nack' is simulated at --sim-level bus only" in line
    assert not out.exists()
    assert CliRunner().invoke(cli, args).exit_code == 0  # the bus level simulates it


def test_a_disconnect_shorter_than_a_poll_is_not_missed():
    st, sink, due_at_start = _run_one(_one("bmx055", [{"kind": "disconnect", "at_s": 30.2, "duration_s": 0.3}]), 60.0)
    kinds = [e[2] for e in sink.events]
    assert kinds.count("fault") == 1 and kinds.count("reconnect") == 1
    # everything since the last read before the disconnect is gone, at most two polls' worth
    assert 0.3 * 400 <= st.lost <= 2 * 400
    assert st.driver.produced == due_at_start + st.samples + st.lost


def test_every_part_of_a_rotated_model_level_capture_names_the_level(tmp_path):
    summary = capture(_one("bmx055"), tmp_path / "r.h5", 30.0, simulate=True, sim_level="model", rotate_s=10.0)
    assert len(summary.paths) == 3
    for path in summary.paths:
        with open_run(path) as run:
            assert any("noise-model level" in e.detail for e in run.events()), path


def test_the_cli_offers_the_station_levels():
    from imustation.acquisition.modes import SIM_LEVELS
    from imustation.cli.capture import capture as command

    (option,) = [p for p in command.params if p.name == "sim_level"]
    assert tuple(option.type.choices) == SIM_LEVELS
