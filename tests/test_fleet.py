"""Fleet characterisation: parallel analysis on dask.distributed, the fleet table, repeatability, outliers."""

from __future__ import annotations

import csv
import json
import math
import warnings
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.acquisition import capture, load_config
from imustation.analysis.pipeline import parallel
from imustation.analysis.pipeline.channel import channel_document
from imustation.analysis.pipeline.fleet import (
    FleetRow,
    device_key,
    flag_outliers,
    repeatability,
    robust_z,
)
from imustation.analysis.pipeline.parallel import AnalysisOptions, plan_tasks, run_tasks
from imustation.analysis.reports.fleettable import fleet_rows
from imustation.analysis.reports.tables import DOUBTFUL
from imustation.cli import cli

GLOB = "*/gyro/z"
SIGMA_W = 9.97e-5  # rad/s/sqrt(Hz): the BMX055's Table IV value, given explicitly
_DEVICE = """
[[device]]
name = "{name}"
driver = "bmx055"
bus = "i2c:{bus}"
address = {addr}
rate_hz = 400
bandwidth_hz = 47
gyro_range_dps = 125
  [device.sim]
  sigma_w = {sigma_w}
"""


def _config(tmp_path, seed: int):
    """Four BMX055 gyros on one station; gyro_d has 3x the white noise of the others."""
    text = f'[station]\nname = "fleet"\nseed = {seed}\n'
    for name, bus, addr, k in (("gyro_a", 1, "0x68", 1), ("gyro_b", 1, "0x69", 1), ("gyro_c", 2, "0x68", 1),
                               ("gyro_d", 2, "0x69", 3)):  # fmt: skip
        text += _DEVICE.format(name=name, bus=bus, addr=addr, sigma_w=k * SIGMA_W)
    p = tmp_path / f"fleet{seed}.toml"
    p.write_text(text)
    return load_config(p)


@pytest.fixture(scope="module")
def fleet_runs(tmp_path_factory):
    """Two 5-minute simulated captures of the same four devices, a corrupt file and a missing one."""
    d = tmp_path_factory.mktemp("fleet")
    runs = []
    for seed in (3, 4):
        path = d / f"night{seed}.h5"
        capture(_config(d, seed), path, 300.0, simulate=True)
        runs.append(str(path))
    bad = d / "corrupt.h5"
    bad.write_bytes(b"not an HDF5 file at all")
    return runs, str(bad), str(d / "missing.h5")


@pytest.fixture(scope="module")
def fleet_out(fleet_runs, tmp_path_factory):
    runs, bad, missing = fleet_runs
    out = tmp_path_factory.mktemp("fleet_out")
    # the paper's model on every run: its sigma_b, tau_b are compared across runs (model auto may
    # choose differently per run)
    args = ["fleet", runs[0], bad, runs[1], missing, "-o", str(out), "--channel", GLOB, "--model", "wn+gm"]
    r = CliRunner().invoke(cli, args)
    return r, out


@pytest.fixture(scope="module")
def cluster():
    """A small in-process dask cluster (threads, no dashboard)."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as lc:  # fmt: skip
        yield lc


def _rows(out):
    with open(out / "fleet.csv", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_scheduler_json_identical_to_serial(fleet_runs, cluster):
    runs = fleet_runs[0]
    serial = CliRunner().invoke(cli, ["analyze", *runs, "--channel", GLOB, "--json"])
    assert serial.exit_code == 0, serial.output
    dist = CliRunner().invoke(
        cli, ["analyze", *runs, "--channel", GLOB, "--json", "--scheduler", cluster.scheduler_address]
    )
    assert dist.exit_code == 0, dist.stderr
    assert dist.stdout == serial.stdout  # byte for byte, same channel order
    assert "dask dashboard" in dist.stderr
    assert [c["id"] for c in json.loads(dist.stdout)["channels"]] == [
        f"gyro_{x}/gyro/z" for x in "abcd"
    ] * 2  # fmt: skip


def test_local_workers_identical_to_serial(fleet_runs):
    """The real --workers path: a local cluster of worker processes."""
    run = fleet_runs[0][0]
    args = ["analyze", run, "--channel", "gyro_a/gyro/z", "--json"]
    serial = CliRunner().invoke(cli, args)
    dist = CliRunner().invoke(cli, [*args, "--workers", "1"])
    assert dist.exit_code == 0, dist.stderr
    assert dist.stdout == serial.stdout


# slow (10 s): the scheduler and local-worker tests above check the cluster path in the default suite
@pytest.mark.slow
def test_run_tasks_client_matches_serial_and_orders_results(fleet_runs, cluster):
    from distributed import Client

    tasks, failures = plan_tasks([*fleet_runs[0], fleet_runs[2]], [GLOB])
    assert [f.path for f in failures] == [fleet_runs[2]] and failures[0].channel is None
    seen = []
    with Client(cluster, set_as_default=False) as client:
        res_d, fail_d = run_tasks(tasks, AnalysisOptions(), client, on_done=lambda d, n, f: seen.append((d, n)))
    res_s, fail_s = run_tasks(tasks, AnalysisOptions())
    assert not fail_d and not fail_s
    assert seen[-1] == (len(tasks), len(tasks))
    assert [r.channel.id for r in res_d] == [t.channel for t in tasks]
    for a, b in zip(res_d, res_s, strict=True):
        assert json.dumps(channel_document(a)) == json.dumps(channel_document(b))
        assert a.channel._data is None  # no samples came back through the scheduler


def test_failed_runs_reported_others_finish(fleet_runs, fleet_out):
    runs, bad, missing = fleet_runs
    r, out = fleet_out
    assert r.exit_code == 0, r.stderr
    assert f"failed: {bad}" in r.stderr and f"failed: {missing}" in r.stderr
    rows = _rows(out)
    failed = [x for x in rows if x["status"] == "failed"]
    assert [x["run"] for x in failed] == [bad, missing]
    assert all(x["error"] for x in failed)
    assert len([x for x in rows if x["status"] != "failed"]) == 8
    md = (out / "fleet.md").read_text()
    assert "**Failures**" in md and "corrupt.h5" in md and "missing.h5" in md


def test_every_run_failed_exits_2(fleet_runs, tmp_path):
    _, bad, missing = fleet_runs
    r = CliRunner().invoke(cli, ["fleet", bad, missing, "-o", str(tmp_path / "o")])
    assert r.exit_code == 2
    assert "every run failed" in r.stderr


def test_bad_channel_fails_only_its_task(fleet_runs):
    tasks, _ = plan_tasks(fleet_runs[0][:1], [GLOB])
    tasks.insert(1, parallel.ChannelTask(fleet_runs[0][0], "nodevice/gyro/z"))
    res, failures = run_tasks(tasks, AnalysisOptions())
    assert res[1] is None and all(r is not None for i, r in enumerate(res) if i != 1)
    assert len(failures) == 1 and "nodevice/gyro/z" in failures[0].error


def test_fleet_table_identity_and_intervals(fleet_runs, fleet_out):
    _, out = fleet_out
    rows = [x for x in _rows(out) if x["status"] != "failed"]
    assert {x["device_key"] for x in rows} == {f"fleet/gyro_{c}" for c in "abcd"}
    assert {x["identity"] for x in rows} == {"chip_id=0x0F"}
    for x in rows:
        for q in ("sigma_w", "sigma_b", "tau_b", "N"):
            lo, v, hi = float(x[f"{q}_lo90"]), float(x[q]), float(x[f"{q}_hi90"])
            assert math.isnan(lo) or lo <= v <= hi
        assert x["sigma_w_unit"] == "rad/s/√Hz"
        # sigma_w recovered within 10 % of what each device simulates
        k = 3 if x["device"] == "gyro_d" else 1
        assert float(x["sigma_w"]) == pytest.approx(k * SIGMA_W, rel=0.1)


def test_repeatability_matches_numpy(fleet_runs, fleet_out):
    _, out = fleet_out
    rows = [x for x in _rows(out) if x["status"] != "failed"]
    res, _ = run_tasks(plan_tasks(fleet_runs[0], [GLOB])[0], AnalysisOptions(model="wn+gm"))
    rep = {r.key: r for r in repeatability(flag_outliers(fleet_rows(res)))}
    assert set(rep) == {x["device_key"] for x in rows}
    for key, rr in rep.items():
        assert rr.runs == 2
        for q in ("sigma_w", "sigma_b", "tau_b"):
            # a flagged value (at bound, not identified, doubtful) is no estimate: not averaged
            mine = [x for x in rows if x["device_key"] == key]
            v = np.array([float(x[q]) for x in mine if f"{q} " not in x["value_flags"]])
            assert rr.counted[q] == len(v)
            if len(v):
                assert rr.mean[q] == pytest.approx(np.mean(v), rel=1e-12)
            if len(v) > 1:
                assert rr.std[q] == pytest.approx(np.std(v, ddof=1), rel=1e-12)
    md = (out / "fleet.md").read_text()
    assert "repeatability per device" in md


def test_outlier_device_flagged(fleet_out):
    r, out = fleet_out
    rows = [x for x in _rows(out) if x["status"] != "failed"]
    for x in rows:
        if x["device"] == "gyro_d":
            assert x["status"] == "outlier" and "sigma_w" in x["outliers"].split()
            assert float(x["z_sigma_w"]) > 3.5
        else:
            assert "sigma_w" not in x["outliers"].split()
            assert abs(float(x["z_sigma_w"])) <= 3.5
    assert "outlier:" in r.stderr and "gyro_d" in r.stderr


def test_outputs_written(fleet_out):
    _, out = fleet_out
    page = (out / "fleet.html").read_text()
    assert "data:image/png;base64," in page and "<table>" in page
    png = (out / "fleet_allan.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    md = (out / "fleet.md").read_text()
    assert "°/h/√Hz" in md and "**Outliers (robust z" in md
    assert "<h3>Outliers (robust z" in page


def test_robust_z_and_device_key():
    z = robust_z(np.array([1.0, 1.1, 0.9, 1.05, 0.95, 5.0, np.nan]))
    assert math.isnan(z[-1]) and z[5] > 3.5 and np.all(np.abs(z[:5]) <= 3.5)
    assert np.all(robust_z(np.array([2.0, 2.0, 2.0])) == 0)
    adis = "prod_id=0x4040 lot=0x12345678 serial=0x0042"
    assert device_key("adis16448", adis, "lab", "adis") == "adis16448:serial=0x0042,lot=0x12345678"
    assert device_key("bmx055", "chip_id=0x0F", "lab", "gyro") == "lab/gyro"
    assert device_key("bmx055", "chip_id=0x0F", "lab", "gyro", {"serial": "SN7"}) == "bmx055:serial=SN7"


def test_robust_z_spread_has_a_floor_from_the_standard_errors():
    """sigma_w equal to three digits: the MAD is ~0 and the plain robust z explodes (issue 23 saw -4392);
    with the values' stated standard errors (0.2 %) as the floor they agree, and a real outlier stays one."""
    sw = np.array([1.2340000e-4, 1.2340001e-4, 1.2340002e-4, 1.2340003e-4, 1.2346e-4])
    logv = np.log10(sw)
    se_log = np.full(len(sw), 0.002 / math.log(10.0))  # 0.2 % relative standard error, in log10
    assert abs(robust_z(logv)[-1]) > 1000  # the old behaviour
    assert np.all(np.abs(robust_z(logv, se_log)) < 1.0)
    out = np.log10(np.append(sw, 3 * 1.234e-4))
    z = robust_z(out, np.append(se_log, 0.5))  # one degenerate standard error does not move the median floor
    assert z[-1] > 3.5 and np.all(np.abs(z[:-1]) < 1.0)


def test_a_doubtful_noise_density_is_not_judged():
    """Five runs whose sigma_w agree within 0.2 % and a sixth 8 % low, whose interval (-25..+1 %:
    the slow terms reach the fine scales) holds the others: no outlier (the group's spread, floored
    by its median standard error, is not the scale of that value), but a plain value would be one."""

    def row(sw: float, lo: float, hi: float, flags: dict) -> FleetRow:
        vals = {"sigma_w": sw, "sigma_b": 1e-6, "tau_b": 300.0}
        se = {"sigma_w": 0.002 * sw, "sigma_b": 1e-7, "tau_b": 30.0}
        return FleetRow("r", "lab", "g", "mpu9150", "", "k", "gyro", "x", 2_160_000, 200.0, "wn+gm", True, vals, se,
                        {**vals, "sigma_w": lo}, {**vals, "sigma_w": hi}, flags=flags)  # fmt: skip

    sws = [1.000e-4, 1.001e-4, 0.999e-4, 1.002e-4, 0.998e-4]
    rows = [row(s, 0.997 * s, 1.003 * s, {}) for s in sws] + [row(0.92e-4, 0.69e-4, 0.93e-4, {"sigma_w": DOUBTFUL})]
    judged = flag_outliers(rows)
    assert math.isnan(judged[-1].z["sigma_w"]) and not judged[-1].outliers
    assert all(math.isfinite(r.z["sigma_w"]) and not r.outliers for r in judged[:-1])
    # each run is judged with its own 90 % interval: unflagged, this one's (-25..+1 %) holds the others too
    assert not flag_outliers([*rows[:-1], replace(rows[-1], flags={})])[-1].outliers
    tight = row(0.92e-4, 0.997 * 0.92e-4, 1.003 * 0.92e-4, {})  # the same value with the others' precision
    assert "sigma_w" in flag_outliers([*rows[:-1], tight])[-1].outliers


def test_help():
    for cmd in ("fleet", "analyze"):
        r = CliRunner().invoke(cli, [cmd, "--help"])
        assert r.exit_code == 0
        assert "--workers" in r.output and "--scheduler" in r.output


def test_bad_scheduler_one_line_exit_2(fleet_runs, monkeypatch):
    monkeypatch.setattr(parallel, "CONNECT_TIMEOUT_S", 1.0)
    for cmd in (["analyze", fleet_runs[0][0]], ["fleet", fleet_runs[0][0], "-o", "unused"]):
        r = CliRunner().invoke(cli, [*cmd, "--scheduler", "tcp://127.0.0.1:1"])
        assert r.exit_code == 2, r.output
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("imustation: error: scheduler tcp://127.0.0.1:1")


def test_workers_and_scheduler_exclusive(fleet_runs):
    r = CliRunner().invoke(cli, ["analyze", fleet_runs[0][0], "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"])
    assert r.exit_code == 2 and "not both" in r.stderr


def test_glob_matching_nothing_in_one_run_is_not_a_failure(fleet_runs, tmp_path):
    runs = fleet_runs[0]
    tasks, failures = plan_tasks(runs, ["gyro_a/gyro/z"])
    assert [t.path for t in tasks] == runs and not failures
    with pytest.raises(parallel.NoChannelsError):
        plan_tasks(runs, ["nothing/*"])
    r = CliRunner().invoke(cli, ["fleet", *runs, "-o", str(tmp_path), "--channel", "nothing/*"])
    assert r.exit_code == 2 and "no channels matching nothing/*" in r.stderr


def test_channels_in_memory_run_on_a_cluster_as_serially(fleet_runs, cluster):
    """Tasks that carry their channel (a streamed field recording: no file to read back) give
    the same results on a cluster as in this process, and the same as their file's tasks."""
    from distributed import Client

    from imustation.analysis.pipeline.loaders import load_inputs
    from imustation.analysis.pipeline.parallel import tasks_of_channels

    run = fleet_runs[0][0]
    tasks = tasks_of_channels(load_inputs([run], [GLOB]))
    assert all(t.data is not None and t.path == run for t in tasks)
    with Client(cluster, set_as_default=False) as client:
        res_d, fail_d = run_tasks(tasks, AnalysisOptions(), client)
    res_s, fail_s = run_tasks(tasks, AnalysisOptions())
    res_f, _ = run_tasks(plan_tasks([run], [GLOB])[0], AnalysisOptions())
    assert not fail_d and not fail_s
    docs = [[json.dumps(channel_document(r)) for r in res] for res in (res_d, res_s, res_f)]
    assert docs[0] == docs[1] == docs[2]


def test_model_auto_gives_one_model_per_driver_sensor_and_axis():
    """Repeats of one device where the automatic choice differs run by run: the fleet keeps, per
    driver/sensor/axis, the candidate every run passes with the smallest summed BIC (issue 22)."""
    from imustation.analysis.pipeline.channel import analyze_channel
    from imustation.analysis.pipeline.fleet import common_models
    from imustation.analysis.pipeline.loaders import Channel
    from tests.realistic_records import record

    results = []
    for seed in range(4):
        x, fs = record("mpu9150", 0.5, 2.44e-4, B=1.5e-5, K=2e-7, seed=seed)
        ch = Channel("imu/gyro/x", fs, "rad/s", x, source=f"run{seed}.h5", meta={"driver": "mpu9150"})
        results.append(analyze_channel(ch))
    assert len({r.noise_model.model for r in results}) > 1  # the runs chose differently on their own
    kept = common_models(results)
    assert len({r.noise_model.model for r in kept}) == 1
    model = kept[0].noise_model.model
    cands = [{c.result.model: c for c in r.choice.candidates} for r in results]
    shared = [m for m in set.intersection(*(set(c) for c in cands)) if all(c[m].passes for c in cands)]
    assert model == min(shared, key=lambda m: sum(c[m].result.bic for c in cands))
    for before, after, c in zip(results, kept, cands, strict=True):
        assert after.noise_model is (before.noise_model if before.noise_model.model == model else c[model].result)
        assert after.adequacy["noise_model"] is (
            before.adequacy["noise_model"] if before.noise_model.model == model else c[model].check
        )
    assert common_models(results[:1])[0] is results[0]  # a group of one is left alone


def _row(run: str, sw: float, sw_se: float, *, model: str = "wn+gm", n: int = 2_160_000, key: str = "k",
         sb: float = 1e-6) -> FleetRow:  # fmt: skip
    vals = {"sigma_w": sw, "sigma_b": sb, "tau_b": 300.0}
    se = {"sigma_w": sw_se, "sigma_b": 0.01 * sb, "tau_b": 3.0}
    lo = {q: v - 1.645 * se[q] for q, v in vals.items()}
    hi = {q: v + 1.645 * se[q] for q, v in vals.items()}
    return FleetRow(run, "lab", "g", "mti", "", key, "gyro", "x", n, 200.0, model, True, vals, se, lo, hi)


def test_a_short_run_is_listed_and_left_out_and_each_run_is_judged_with_its_own_interval():
    """A 12 s run's sigma_w 25.4 +- 0.32 was an outlier (z -5.2) against six 3 h runs at 25.6 +- 0.01: it is
    left out as too short; a 20 min run of 25.4 +- 0.32 is judged with its own interval: no outlier."""
    long = [_row(f"r{i}", 25.6 + 0.01 * (i % 3 - 1), 0.01) for i in range(6)]
    short = _row("short", 25.4, 0.32, n=2400)  # 12 s at 200 Hz
    judged = flag_outliers([*long, short])
    assert judged[-1].excluded.startswith("too short (12 s") and not judged[-1].outliers
    assert math.isnan(judged[-1].z["sigma_w"])
    assert all(r.key != "short" for r in repeatability(judged)) and repeatability(judged)[0].runs == 6
    medium = _row("medium", 25.4, 0.32, n=240_000)  # 20 min: kept, within its own interval of the others
    judged = flag_outliers([*long, medium])
    assert not judged[-1].excluded and abs(judged[-1].z["sigma_w"]) < 1.0 and not judged[-1].outliers
    # the same value with the long runs' precision is an outlier
    assert "sigma_w" in flag_outliers([*long, _row("precise", 25.4, 0.01)])[-1].outliers


def test_fleet_statistics_compare_only_comparable_models_and_groups_of_five():
    """sigma_b of a random-walk model is its rate random walk: never averaged or judged with a Gauss-Markov
    sigma_b; sigma_w means the same in every model. Four runs are not judged (the MAD of 3-4 values is noise)."""
    gm = [_row(f"g{i}", 25.6, 0.01, sb=1e-6 * (1 + 0.01 * i)) for i in range(4)]
    rw = [_row("w0", 25.6, 0.01, model="wn+rw", sb=1e-9)]
    judged = flag_outliers(gm + rw)
    assert math.isfinite(judged[-1].z["sigma_w"])  # five runs for sigma_w, over both models
    assert all(math.isnan(r.z["sigma_b"]) for r in judged)  # four wn+gm, one wn+rw: not judged
    assert not any(r.outliers for r in judged)
    rep = repeatability(judged)
    assert [(r.model, r.runs) for r in rep] == [("wn+gm", 4), ("wn+rw", 1)]
    assert rep[0].mean["sigma_b"] == pytest.approx(1.015e-6) and rep[1].mean["sigma_b"] == 1e-9
    # without the model split the sigma_b of the wn+rw run (1e-9) was the outlier of one mixed group of 5
    assert not flag_outliers(gm[:3] + rw)[-1].outliers


def test_repeatability_leaves_out_flagged_values_and_random_walks_without_warnings():
    rows = [_row(f"r{i}", 25.6, 0.01) for i in range(3)]
    rows = [replace(r, values={**r.values, "tau_b": math.inf}) for r in rows]
    rows[0] = replace(rows[0], flags={"sigma_b": "at bound"})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # np.std of [inf, inf] warned 'invalid value' in fleet
        (rep,) = repeatability(flag_outliers(rows))
    assert rep.mean["tau_b"] == math.inf and math.isnan(rep.std["tau_b"])
    assert rep.counted["sigma_b"] == 2 and rep.counted["sigma_w"] == 3


def test_a_too_short_run_is_listed_and_left_out_in_every_output(fleet_runs, tmp_path):
    """A 12 s run was accepted and judged an outlier; it is listed (stderr, CSV status 'left out', the
    Markdown's left-out table) and counted in neither the repeatability nor the outlier test."""
    runs = fleet_runs[0]
    short = tmp_path / "short.h5"
    capture(_config(tmp_path, 5), short, 20.0, simulate=True)
    out = tmp_path / "o"
    r = CliRunner().invoke(cli, ["fleet", *runs, str(short), "-o", str(out), "--channel", GLOB, "--model", "wn+gm"])
    assert r.exit_code == 0, r.output
    left = [ln for ln in r.stderr.splitlines() if ln.startswith("left out: ")]
    assert len(left) == 4 and all("short.h5" in ln and "too short (20 s < 60 s)" in ln for ln in left)
    rows = _rows(out)
    assert {x["status"] for x in rows if x["run"] == str(short)} == {"left out"}
    assert all(x["z_sigma_w"] == "nan" for x in rows if x["run"] == str(short))
    assert all(x["warmup"].endswith("(auto: no temperature channel)") or "cut" in x["warmup"] for x in rows)
    md = (out / "fleet.md").read_text()
    assert "**Left out of the repeatability and the outlier test**" in md and "4 axes left out" in r.stdout
    assert "| wn+gm | 2 |" in md  # repeatability per device and model, the short run not counted


def test_fleet_gives_the_model_n_b_k_of_analyze_and_report(fleet_runs, fleet_out):
    """One answer (issue 34): fleet's N, B, K of a channel are the noise model's ieee952 terms, as analyze's
    table, the report's summary and export give them, with the same 90 % interval or upper bound; before,
    fleet printed the classical Allan fit's B and K (e.g. '—' where the summary gave K = 2.1e-6)."""
    from imustation.analysis.reports.summary import channel_estimates
    from imustation.analysis.reports.tables import UPPER_BOUND

    _, out = fleet_out
    rows = {(x["run"], x["device"]): x for x in _rows(out) if x["status"] != "failed"}
    res, _ = run_tasks(plan_tasks(fleet_runs[0][:1], [GLOB])[0], AnalysisOptions(model="wn+gm"))
    assert res
    for r in res:
        x = rows[(r.channel.source, r.channel.meta["device"])]
        est = channel_estimates(r)
        for q in ("N", "B", "K"):
            assert float(x[q]) == pytest.approx(est[q].value, rel=1e-12)
            if est[q].flag == UPPER_BOUND:
                assert f"{q} {UPPER_BOUND}" in x["value_flags"] and x[f"{q}_lo90"] == "nan"
            else:
                assert float(x[f"{q}_lo90"]) == pytest.approx(est[q].lo, rel=1e-12)
                assert float(x[f"{q}_hi90"]) == pytest.approx(est[q].hi, rel=1e-12)
    doc = json.loads((out / "fleet.json").read_text())
    assert doc["format"] == "imustation-fleet" and len(doc["rows"]) == len(rows)
    assert {"N", "B", "K"} <= set(doc["rows"][0]["values"]) and "B" in doc["rows"][0]["z"]
    md = (out / "fleet.md").read_text()
    assert "value [90 % interval]" in md and "run-to-run scatter per device" in md


def _nbk_row(run: str, b: float, half: float, *, flag: str = "") -> FleetRow:
    """A run whose B is ``b`` with a 90 % interval of +-``half`` (relative, in the logarithm)."""
    r = _row(run, 25.6, 0.01)
    lo, hi = (math.nan, math.nan) if flag else (b * math.exp(-half), b * math.exp(half))
    return replace(r, values={**r.values, "B": b, "K": math.nan, "N": 25.6}, lo={**r.lo, "B": lo},
                   hi={**r.hi, "B": hi}, flags={"B": flag} if flag else {})  # fmt: skip


def test_b_and_k_outliers_use_each_runs_own_interval_and_an_undetected_term_is_no_candidate():
    from imustation.analysis.reports.tables import UPPER_BOUND

    base = [_nbk_row(f"r{i}", 1e-5 * (1 + 0.01 * (i - 2)), 0.02) for i in range(5)]
    # 3x the others with a +-2 % interval: an outlier; the same value with a factor-5 interval: none
    assert "B" in flag_outliers([*base, _nbk_row("hi", 3e-5, 0.02)])[-1].outliers
    wide = flag_outliers([*base, _nbk_row("wide", 3e-5, math.log(5.0))])[-1]
    assert math.isfinite(wide.z["B"]) and abs(wide.z["B"]) < 3.5 and not wide.outliers
    # a B the run does not show is its upper bound: never a z-score candidate, however far from the median
    bound = flag_outliers([*base, _nbk_row("bound", 3e-4, 0.0, flag=UPPER_BOUND)])[-1]
    assert math.isnan(bound.z["B"]) and not bound.outliers
    # five runs of which two show B: fewer than five estimates, no median to judge by
    few = [*base[:2], *(_nbk_row(f"b{i}", 3e-4, 0.0, flag=UPPER_BOUND) for i in range(3))]
    assert all(math.isnan(r.z["B"]) for r in flag_outliers(few))


def test_run_to_run_scatter_against_the_per_run_intervals():
    """Six runs of one device with +-1 % intervals (90 %): a 0.3 % scatter is within them; a 5 % scatter
    exceeds them (Cochran's Q), and the excess is close to the scatter the intervals do not explain."""
    from imustation.analysis.pipeline.scatter import EXCEEDS, WITHIN, run_scatter

    rng = np.random.default_rng(7)
    half = 0.01  # 90 % half-width in ln

    def runs(spread: float) -> list[FleetRow]:
        out = []
        for i, e in enumerate(rng.normal(0.0, spread, 6)):
            sw = 25.6 * math.exp(e)
            r = _row(f"r{i}", sw, 0.0)
            lo, hi = sw * math.exp(-half), sw * math.exp(half)
            out.append(replace(r, values={**r.values, "N": sw}, lo={**r.lo, "N": lo}, hi={**r.hi, "N": hi}))
        return out

    (small,) = [s for s in run_scatter(runs(0.003)) if s.quantity == "N"]
    assert small.runs == 6 and small.verdict == WITHIN and small.halfwidth == pytest.approx(half)
    spread = runs(0.05)
    (big,) = [s for s in run_scatter(spread) if s.quantity == "N"]
    assert big.verdict == EXCEEDS and big.p_value < 0.01 and 0.02 < big.excess < 0.1
    assert big.std == pytest.approx(np.std([r.values["N"] for r in spread], ddof=1), rel=1e-12)
    # a run left out (too short) is not counted
    short = replace(runs(0.003)[0], n=2400)
    (s,) = [s for s in run_scatter(flag_outliers([*runs(0.003), short])) if s.quantity == "N"]
    assert s.runs == 6


def test_a_row_whose_model_is_the_fleets_and_not_the_runs_own_says_so():
    """demo.toml 1.5 h alone: analyze and report give x gyro wn+gm, B 2.82 [1.94, 5.51]; in a fleet with three
    other runs the common model wn+rw gave that run B < 6.57 and K 22.5 with nothing saying why the numbers
    differ from analyze's (second newcomer run, issue 34)."""
    from imustation.analysis.reports.fleettable import fleet_markdown

    own = replace(_nbk_row("alone.h5", 1e-5, 0.3), model="wn+rw", own_model="wn+gm")
    same = replace(_nbk_row("same.h5", 1e-5, 0.3), model="wn+rw", own_model="wn+rw")
    md = fleet_markdown([own, same], [])
    line = next(ln for ln in md.splitlines() if ln.startswith("| alone.h5 "))
    assert "| wn+rw (fleet's; the run alone: wn+gm) |" in line
    line = next(ln for ln in md.splitlines() if ln.startswith("| same.h5 "))
    assert "| wn+rw |" in line and "the run alone" not in line


def test_a_short_run_of_many_devices_is_one_left_out_line():
    """A 12 s run of the whole lab in a fleet printed 31 'left out' lines on stderr; more than one device's
    six axes of one run and reason now share one line (fleet.md and the CSV list every axis)."""
    from imustation.analysis.reports.fleetreport import FleetReport

    why = "too short (12 s < 60 s)"
    many = [
        replace(_row("lab12.h5", 25.6, 0.01, key=f"dev{i // 3}"), axis="xyz"[i % 3], excluded=why) for i in range(9)
    ]
    few = [replace(_row("one.h5", 25.6, 0.01), axis=a, excluded=why) for a in "xyz"]
    rep = FleetReport("o", (*many, *few, _row("ok.h5", 25.6, 0.01)), (), "", ())
    assert rep.left_out_lines() == [
        f"left out: lab12.h5: 9 axes of 3 devices: {why}",
        *(f"left out: one.h5 k gyro/{a}: {why}" for a in "xyz"),
    ]
