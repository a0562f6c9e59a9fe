"""Field-recording import (docs/import.md): ROS 1/2 bags and MCAP written here with rosbags, text logs, .npy."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from bagmaker import write_imu_bag
from click.testing import CliRunner
from test_bad_input import assert_one_line_error

from imustation.acquisition.importers import check_stamps, import_recording, text_mapping
from imustation.analysis.pipeline.channel import analyze_channel
from imustation.analysis.pipeline.loaders import load_inputs
from imustation.analysis.pipeline.verdict import data_verdict
from imustation.cli import cli
from imustation.runfile import open_run

FS = 200.0
T0 = 1_700_000_000_000_000_000
PERIOD = 5_000_000


def record(n=3000, seed=1):
    rng = np.random.default_rng(seed)
    t = T0 + np.arange(n, dtype=np.int64) * PERIOD
    gyro = 1e-3 * rng.normal(size=(n, 3)) + np.cumsum(1e-5 * rng.normal(size=(n, 3)), axis=0)
    accel = rng.normal(size=(n, 3)) + [0, 0, 9.81]
    return t, gyro, accel


def run(*args):
    return CliRunner().invoke(cli, list(args))


def bag_path(tmp_path, fmt, t, g, a):
    if fmt == "ros1":
        return write_imu_bag(tmp_path / "rec.bag", t, g, a, fmt="ros1")
    folder = write_imu_bag(tmp_path / f"rec_{fmt}", t, g, a, fmt=fmt)
    if fmt == "mcap":
        return next(folder.glob("*.mcap"))  # a bare .mcap file
    return folder  # a ROS 2 bag folder (sqlite3)


@pytest.mark.parametrize("fmt", ["ros1", "mcap", "sqlite3"])
def test_bag_import_exact_samples(tmp_path, fmt):
    t, g, a = record()
    src = bag_path(tmp_path, fmt, t, g, a)
    out = tmp_path / "run.h5"
    calls = []
    res = import_recording(str(src), str(out), block=1000, progress=lambda d, n: calls.append((d, n)))
    assert calls[-1] == (len(t), len(t)) and len(calls) == 3  # streamed in blocks
    rep = res.reports["imu_data"]
    assert rep.n == len(t) and rep.gaps == 0 and rep.backwards == 0 and rep.duplicates == 0
    assert rep.true_rate_hz == pytest.approx(FS)
    with open_run(out) as run_:
        dev = run_.devices["imu_data"]
        assert dev.rate_hz == pytest.approx(FS) and dev.driver == "import"
        np.testing.assert_array_equal(run_.read("imu_data", "gyro"), g)
        np.testing.assert_array_equal(run_.read("imu_data", "accel"), a)
        np.testing.assert_array_equal(run_.read("imu_data", "t"), t - T0)
        assert run_.attrs["source"].endswith(src.name)
        assert run_.attrs["started_utc"].startswith("2023-11-14")


def test_roundtrip_bag_equals_npy(tmp_path):
    t, g, a = record(4000)
    src = bag_path(tmp_path, "ros1", t, g, a)
    res = run("import", str(src), "-o", str(tmp_path / "run.h5"), "--quiet")
    assert res.exit_code == 0, res.output
    ch_run = load_inputs([str(tmp_path / "run.h5")], ["*/gyro/y"])[0]
    np.save(tmp_path / "gyro.npy", g)
    ch_npy = load_inputs([str(tmp_path / "gyro.npy")], fs_hz=FS)[1]
    r1, r2 = analyze_channel(ch_run, m=200), analyze_channel(ch_npy, m=200)
    np.testing.assert_allclose(r1.allan.adev, r2.allan.adev, rtol=1e-12)
    assert r1.mli.sigma_w == pytest.approx(r2.mli.sigma_w, rel=1e-9)
    # and directly from the bag, through the CLI JSON
    doc1 = json.loads(run("analyze", str(src), "--channel", "*/gyro/y", "-m", "200", "--json").output)
    doc2 = json.loads(run("analyze", str(tmp_path / "gyro.npy"), "--rate", "200", "-m", "200", "--json").output)
    assert doc2["channels"][1]["id"] == "gyro/1"  # (globs select run-file channels only)
    assert doc1["channels"][0]["allan"]["adev"] == pytest.approx(doc2["channels"][1]["allan"]["adev"], rel=1e-12)
    assert doc1["channels"][0]["mli"]["sigma_w"] == pytest.approx(doc2["channels"][1]["mli"]["sigma_w"], rel=1e-9)
    assert doc1["channels"][0]["verdict"]["verdict"] in ("enough", "marginal", "not enough")
    assert doc1["channels"][0]["verdict"]["reasons"]


@pytest.mark.parametrize("block", [8192, 100])  # 100: the gap falls on a block boundary
def test_broken_stamps_are_reported_kept_and_logged(tmp_path, block):
    t, g, a = record(3000)
    t = t.copy()
    t[500] = t[499]  # duplicate
    t[1000], t[1001] = t[1001], t[1000]  # swapped: one backward step
    keep = np.r_[0:2000, 2050:3000]  # 50 samples missing
    t, g, a = t[keep], g[keep], a[keep]
    t[2500:] += 1234  # jitter-free offset, no gap
    src = bag_path(tmp_path, "mcap", t, g, a)
    out = tmp_path / "run.h5"
    rep = import_recording(str(src), str(out), block=block).reports["imu_data"]
    assert rep.duplicates == 1 and rep.backwards == 1
    assert rep.gaps == 1 and rep.missing == 50
    assert rep.n == len(t)  # nothing dropped
    with open_run(out) as run_:
        np.testing.assert_array_equal(run_.read("imu_data", "t"), t - T0)  # file order kept
        np.testing.assert_array_equal(run_.read("imu_data", "gyro"), g)
        ev = run_.events()
    gaps = [e for e in ev if e.kind == "gap"]
    assert len(gaps) == 1 and gaps[0].lost == 50 and gaps[0].t_ns == t[2000] - T0
    assert any("1 non-monotonic, 1 duplicated" in e.detail for e in ev)
    # the analysis splits the record at the gap
    ch = load_inputs([str(out)], ["*/gyro/x"])[0]
    assert ch.segments == [(0, 2000), (2000, len(t))]


def broken_record(n=3000):
    """A record with a duplicated stamp, a swapped pair and a gap of 50 samples."""
    t, g, a = record(n)
    t = t.copy()
    t[500] = t[499]
    t[1000], t[1001] = t[1001], t[1000]
    keep = np.r_[0:2000, 2050:n]
    return t[keep], g[keep], a[keep]


def text_log(tmp_path, t, g, a):
    p = tmp_path / "log.csv"
    header = "timestamp,acc_x [m/s^2],acc_y [m/s^2],acc_z [m/s^2],gyro_x [rad/s],gyro_y [rad/s],gyro_z [rad/s]"
    np.savetxt(p, np.column_stack([(t - T0) / 1e9 + 100.0, a, g]), delimiter=",", header=header, comments="",
               fmt="%.17g")  # fmt: skip
    return p


def test_stream_recording_keeps_every_sample_and_gap(tmp_path, monkeypatch):
    from imustation.acquisition.importers import stream

    monkeypatch.setattr(stream, "COLUMN_ROWS", 700)  # the arrays grow several times
    t, g, a = broken_record()
    rec = stream.stream_recording(str(bag_path(tmp_path, "ros1", t, g, a)), block=500)
    dev = rec.devices["imu_data"]
    np.testing.assert_array_equal(dev.t_ns, t - T0)  # file order, nothing dropped
    np.testing.assert_array_equal(np.column_stack(dev.columns["gyro"]), g)
    np.testing.assert_array_equal(np.column_stack(dev.columns["accel"]), a)
    assert [(e.t_ns, e.lost) for e in dev.events if e.kind == "gap"] == [(t[2000] - T0, 50)]
    assert rec.result.path == "" and rec.result.reports["imu_data"].n == len(t)


@pytest.mark.parametrize("fmt", ["ros1", "mcap", "sqlite3", "csv"])
def test_streamed_channels_equal_the_imported_run(tmp_path, fmt):
    """analyze's channels of a recording (streamed, no file) are those of the run file the import writes."""
    from imustation.cli._field import streamed_channels

    t, g, a = broken_record()
    src = text_log(tmp_path, t, g, a) if fmt == "csv" else bag_path(tmp_path, fmt, t, g, a)
    import_recording(str(src), str(tmp_path / "run.h5"))
    text = {"time_col": None, "gyro_cols": None, "accel_cols": None, "gyro_unit": None, "accel_unit": None}
    for globs in ([], ["*/gyro/y", "*/accel/*"]):
        ref = load_inputs([str(tmp_path / "run.h5")], globs)
        got = streamed_channels(str(src), globs, quiet=True, topic=None, time_unit=None, text=text)
        assert [c.id for c in got] == [c.id for c in ref] and len(ref) == (6 if not globs else 4)
        for c, r in zip(got, ref, strict=True):
            assert (c.fs_hz, c.units, c.scale, c.gaps, c.segments) == (r.fs_hz, r.units, r.scale, r.gaps, r.segments)
            assert c.meta == r.meta and c.source == str(src) and c.ref is None
            assert c.data.dtype == r.data.dtype and c.data.flags.c_contiguous
            np.testing.assert_array_equal(c.data, r.data)
        assert ref[0].gaps == 1 and len(ref[0].segments) == 2  # the gap splits the record


def test_streamed_channels_split_at_an_unlogged_hole(tmp_path):
    """A hole the stamps show but no event logs splits a streamed record, as load_run splits a run file."""
    from dataclasses import replace

    from imustation.acquisition.importers import stream_recording
    from imustation.analysis.pipeline.loaders import recording_channels

    t, g, a = broken_record()
    src = text_log(tmp_path, t, g, a)
    dev = stream_recording(str(src), text={"time_col": None, "gyro_cols": None, "accel_cols": None}).devices
    ((name, d),) = dev.items()
    period = int(round(1e9 / d.spec.rate_hz))
    t_ns = d.t_ns.copy()
    t_ns[2500:] += 20 * period  # 20 samples missing, no event says so
    got = recording_channels({name: replace(d, t_ns=t_ns)}, str(src), ["*/gyro/x"])
    assert got[0].gaps == 1 and got[0].segments == [(0, 2000), (2000, 2500), (2500, len(t_ns))]


@pytest.mark.parametrize("fmt", ["ros1", "csv"])
def test_analyze_streams_a_recording_without_a_run_file(tmp_path, monkeypatch, fmt):
    import tempfile

    from imustation.runfile import RunWriter

    t, g, a = broken_record()
    src = text_log(tmp_path, t, g, a) if fmt == "csv" else bag_path(tmp_path, fmt, t, g, a)
    assert run("import", str(src), "-o", str(tmp_path / "run.h5"), "--quiet").exit_code == 0
    args = ["--channel", "*/gyro/x", "-m", "100"]
    ref = run("analyze", str(tmp_path / "run.h5"), *args, "--json")
    table = run("analyze", str(tmp_path / "run.h5"), *args)

    def no_run_file(self, path, **kw):
        raise AssertionError(f"analyze wrote a run file: {path}")

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(RunWriter, "__init__", no_run_file)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    res = run("analyze", str(src), *args, "--json")
    assert res.exit_code == 0, res.output
    doc, want = json.loads(res.stdout), json.loads(ref.stdout)
    assert [c.pop("source") for c in doc["channels"]] == [str(src)]
    assert [c.pop("source") for c in want["channels"]] == [str(tmp_path / "run.h5")]
    assert doc == want and doc["channels"][0]["gaps"] == 1
    res = run("analyze", str(src), *args)
    assert res.exit_code == 0, res.output
    assert res.stdout == table.stdout  # the same table
    assert "1 gaps (50 samples missing), 1 duplicated, 1 non-monotonic" in res.stderr  # the import summary
    assert res.stderr.endswith(table.stderr)  # "analysing ..."
    assert list(tmp.iterdir()) == []


def test_check_stamps_jitter_and_rate():
    rng = np.random.default_rng(3)
    t = np.cumsum(np.full(10000, 2_500_000) + rng.integers(-1000, 1000, 10000)).astype(np.int64)
    rep = check_stamps(t)
    assert rep.true_rate_hz == pytest.approx(400.0, rel=1e-3)
    assert 400 < rep.jitter_ns < 1000
    assert rep.gaps == 0 and rep.monotonic
    # streaming in blocks gives the same counts
    from imustation.acquisition.importers import StampChecker

    t2 = np.delete(t, [100, 5000, 5001])
    c = StampChecker()
    for i in range(0, len(t2), 777):
        c.update(t2[i : i + 777])
    r = c.report()
    whole = check_stamps(t2)
    assert (r.gaps, r.missing, r.gap_list) == (whole.gaps, whole.missing, whole.gap_list) == (2, 3, r.gap_list)
    assert [g[0] for g in r.gap_list] == [100, 4999]


def test_csv_log_auto_detected(tmp_path):
    t, g, a = record(2000)
    ts = (t - T0) / 1e9 + 100.0
    p = tmp_path / "log.csv"
    header = "# units: rad/s, m/s^2\ntimestamp,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z"
    np.savetxt(p, np.column_stack([ts, a, g]), delimiter=",", header=header, comments="", fmt="%.17g")
    mp = text_mapping(str(p))
    assert (mp.time_col, mp.gyro_cols, mp.accel_cols, mp.time_unit) == (0, (4, 5, 6), (1, 2, 3), "s")
    res = run("import", str(p), "-o", str(tmp_path / "log.h5"))
    assert res.exit_code == 0, res.output
    assert "auto-detected" in res.output and "true rate 200 Hz" in res.output
    with open_run(tmp_path / "log.h5") as run_:
        np.testing.assert_array_equal(run_.read("imu", "gyro"), g)
        assert run_.devices["imu"].rate_hz == pytest.approx(FS, rel=1e-6)
    # direct analysis of the log (no --rate: a timed log)
    res = run("analyze", str(p), "--channel", "imu/gyro/z", "-m", "100", "--verbose")
    assert res.exit_code == 0, res.output
    assert "imu/gyro/z:\n" in res.output and "  enough data? " in res.output


def test_tsv_with_options_ms_and_degrees(tmp_path):
    t, g, _ = record(1500)
    p = tmp_path / "log.tsv"
    rows = np.column_stack([np.degrees(g), (t - T0) / 1e6])
    np.savetxt(p, rows, delimiter="\t", fmt="%.17g")
    res = run("import", str(p), "-o", str(tmp_path / "o.h5"), "--time-column", "3", "--gyro-columns", "0,1,2",
              "--time-unit", "ms", "--gyro-unit", "deg/s", "--quiet")  # fmt: skip
    assert res.exit_code == 0, res.output
    with open_run(tmp_path / "o.h5") as run_:
        np.testing.assert_allclose(run_.read("imu", "gyro"), g, rtol=1e-12)
        assert "accel" not in run_.devices["imu"].channels
        np.testing.assert_array_equal(run_.read("imu", "t"), t - T0)


def test_npy_with_time_column(tmp_path):
    t, g, a = record(1000)
    np.save(tmp_path / "rec.npy", np.column_stack([(t - T0) * 1e-9, g, a]))
    res = run("import", str(tmp_path / "rec.npy"), "-o", str(tmp_path / "o.h5"), "--quiet")
    assert res.exit_code == 0, res.output
    with open_run(tmp_path / "o.h5") as run_:
        np.testing.assert_array_equal(run_.read("imu", "accel"), a)


def test_bad_inputs(tmp_path):
    (tmp_path / "x.xyz").write_text("1 2 3\n")
    assert_one_line_error(run("import", str(tmp_path / "x.xyz"), "-o", str(tmp_path / "o.h5")), "x.xyz", "unknown")
    t, g, a = record(100)
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    String = store.types["std_msgs/msg/String"]
    with Writer(tmp_path / "noimu.bag") as w:
        c = w.add_connection("/chatter", String.__msgtype__, typestore=store)
        w.write(c, 1, store.serialize_ros1(String(data="x"), String.__msgtype__))
    assert_one_line_error(
        run("import", str(tmp_path / "noimu.bag"), "-o", str(tmp_path / "o.h5")), "noimu.bag", "no sensor_msgs/Imu"
    )
    src = bag_path(tmp_path, "ros1", t, g, a)
    assert_one_line_error(
        run("import", str(src), "-o", str(tmp_path / "o.h5"), "--topic", "/nope"), "rec.bag", "/nope", "/imu/data"
    )
    (tmp_path / "bad.csv").write_text("time,gx,gy,gz\n0.0,1,2,3\n0.005,1,x,3\n")
    bad = ("import", str(tmp_path / "bad.csv"), "-o", str(tmp_path / "o.h5"), "--gyro-unit", "rad/s")
    assert_one_line_error(
        run(*bad, "--gyro-columns", "gx,gy,gz"),
        "bad.csv",
        "line 3",
    )
    assert_one_line_error(
        run("import", str(tmp_path / "bad.csv"), "-o", str(tmp_path / "o.h5"), "--time-column", "when"),
        "bad.csv",
        "no column 'when'",
    )
    (tmp_path / "garbage.bag").write_bytes(b"not a bag at all")
    assert_one_line_error(run("analyze", str(tmp_path / "garbage.bag")), "garbage.bag", "not a readable")


def test_verdict_rules():
    ok = data_verdict(36000.0, 300.0, 200.0, warmup_s=0.0, temp_span_c=0.5)
    assert ok.verdict == "enough" and ok.enough
    short = data_verdict(600.0, 300.0, 200.0)
    assert short.verdict == "not enough" and "2.0 x tau_b" in short.reasons[0]
    assert data_verdict(2000.0, 300.0, 100.0).verdict == "marginal"
    warm = data_verdict(36000.0, 300.0, 200.0, warmup_s=1800.0, temp_span_c=0.5)
    assert warm.verdict == "marginal" and any("warm-up" in r for r in warm.reasons)
    hot = data_verdict(36000.0, 300.0, 200.0, warmup_s=0.0, temp_span_c=5.0)
    assert hot.verdict == "marginal" and any("drift" in r for r in hot.reasons)
    # a Gauss-Markov bias's Allan deviation keeps falling beyond tau_b: reported, judged only when B is needed
    falling = data_verdict(36000.0, 300.0, 3600.0, allan_min_at_end=True, warmup_s=0.0, temp_span_c=0.5)
    assert falling.verdict == "enough" and any("still falls" in r for r in falling.reasons)
    assert data_verdict(36000.0, 300.0, 3600.0, allan_min_at_end=True, need=("B",)).verdict == "not enough"
    nofit = data_verdict(36000.0, math.nan, 200.0)
    assert nofit.verdict == "marginal"
    assert json.dumps(nofit.as_dict())
    # still warming at the end: nothing cut, said so; too short to tell: said so, not a warm-up 'until its end'
    warming = data_verdict(36000.0, 300.0, 200.0, warmup_s=0.0, warmup_state="unsettled", temp_span_c=0.5)
    assert warming.verdict == "marginal" and any("still warming up" in r for r in warming.reasons)
    assert warming.as_dict()["warmup_state"] == "unsettled"
    unknown = data_verdict(36000.0, 300.0, 200.0, warmup_s=0.0, warmup_state="unknown", temp_span_c=0.5)
    assert unknown.verdict == "enough" and any("too short to tell" in r for r in unknown.reasons)


# --- the streaming ROS 1 reader (acquisition/importers/rosbag1.py, ros1.py) -----


def _read_all(path, reader, topics):
    from imustation.acquisition.importers.bags import iter_bag

    got = {t: [] for t in topics}
    for t, blk in iter_bag(str(path), topics, block=1000, reader=reader):
        got[t].append(blk)
    return {t: tuple(np.concatenate(x) for x in zip(*v, strict=True)) for t, v in got.items()}


@pytest.mark.parametrize("compression", [None, "bz2", "lz4"])
def test_ros1_stream_equals_rosbags_reader(tmp_path, compression):
    from bagmaker import write_big_imu_bag
    from rosbags.rosbag1 import Reader

    from imustation.acquisition.importers.bags import bag_topics
    from imustation.acquisition.importers.rosbag1 import Ros1Bag

    topics = ["/imu/data", "/imu2/data_raw"]  # two Imu topics (frame_ids of two lengths) and a String topic
    src = write_big_imu_bag(tmp_path / "multi.bag", 1500, compression=compression, topics=topics, extra_every=7,
                            chunk_bytes=100_000, block=1000)  # fmt: skip
    assert bag_topics(str(src), reader="new") == bag_topics(str(src), reader="old") == [(t, 1500) for t in topics]
    new, old = _read_all(src, "new", topics), _read_all(src, "old", topics)
    for t in topics:
        assert len(new[t][0]) == 1500
        for a, b in zip(new[t], old[t], strict=True):
            np.testing.assert_array_equal(a, b)
    # raw messages, every topic (the String one too), same bytes and record times as rosbags
    with Reader(src) as r:
        ref = [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]
        nchunks = len(r.chunk_infos)
    with Ros1Bag(str(src)) as bag:
        mine = [(tp, t, bytes(raw)) for tp, _mt, t, raw in bag.messages()]
    assert nchunks > 5 and mine == ref


def test_ros1_stream_keeps_file_order_and_reads_unindexed_bag(tmp_path):
    from bagmaker import imu_payloads
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    t, g, a = record(2000)
    t = t.copy()
    t[[1000, 1001]] = t[[1001, 1000]]  # a swapped pair, in the stamps and in the record (receive) times
    store = get_typestore(Stores.ROS1_NOETIC)
    src = tmp_path / "rec.bag"
    pay = imu_payloads("ros1", t, g, a)
    with Writer(src) as w:
        w.chunk_threshold = 100_000  # several chunks
        c = w.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=store)
        for i in range(len(t)):
            w.write(c, int(t[i]), pay[i].tobytes())
    out = tmp_path / "run.h5"
    rep = import_recording(str(src), str(out)).reports["imu_data"]
    assert rep.backwards == 1 and rep.n == 2000  # reported, not sorted away
    with open_run(out) as run_:
        np.testing.assert_array_equal(run_.read("imu_data", "t"), t - T0)
    old = import_recording(str(src), str(tmp_path / "old.h5"), bag_reader="old").reports["imu_data"]
    assert old.backwards == 0  # the rosbags Reader hands out messages sorted by record time
    raw = bytearray(src.read_bytes())
    # an unindexed bag (recording not closed): index_pos = 0; rosbags refuses it, the streaming reader scans it
    i = raw.index(b"index_pos=") + len(b"index_pos=")
    raw[i : i + 8] = bytes(8)
    (tmp_path / "open.bag").write_bytes(bytes(raw))
    with pytest.raises(Exception, match="not indexed"):
        Reader(tmp_path / "open.bag").open()
    rep2 = import_recording(str(tmp_path / "open.bag"), str(tmp_path / "open.h5")).reports["imu_data"]
    assert rep2.n == 2000 and rep2.backwards == 1
    with open_run(tmp_path / "open.h5") as run_:
        np.testing.assert_array_equal(run_.read("imu_data", "gyro"), g)
    # ... cut in the middle of a chunk (the recorder was killed): what precedes the cut is imported, the rest noted
    (tmp_path / "cut.bag").write_bytes(bytes(raw[: len(raw) // 2]))
    res = run("import", str(tmp_path / "cut.bag"), "-o", str(tmp_path / "cut.h5"))
    assert res.exit_code == 0 and "unreadable, not imported" in res.output, res.output
    with open_run(tmp_path / "cut.h5") as run_:
        k = len(run_.read("imu_data", "t"))
        assert 500 < k < 2000  # the complete messages of the chunk cut short are imported too
        assert f"({k} messages before them imported)" in res.output
        np.testing.assert_array_equal(run_.read("imu_data", "gyro"), g[:k])
        assert any("recording not closed" in e.detail for e in run_.events())


def _traced_peak(path, reader):
    import tracemalloc

    from imustation.acquisition.importers.bags import bag_topics, iter_bag

    tracemalloc.start()
    try:
        topics = [t for t, _ in bag_topics(path, reader=reader)]
        n = sum(len(blk[0]) for _, blk in iter_bag(path, topics, reader=reader))
        return n, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.fixture(scope="module")
def bag200k(tmp_path_factory):
    from bagmaker import write_big_imu_bag

    p = write_big_imu_bag(tmp_path_factory.mktemp("big") / "200k.bag", 200_000)
    yield str(p)
    p.unlink()


# bytes; measured on this bag: streaming reader 4 MiB, rosbags Reader 37 MiB (its per-message index)
MEM_BOUND = 16 * 2**20


def test_ros1_stream_memory_is_per_chunk_not_per_message(bag200k):
    n, peak = _traced_peak(bag200k, "new")
    assert n == 200_000
    assert peak < MEM_BOUND, f"peak {peak / 2**20:.1f} MiB"


@pytest.mark.slow
def test_rosbags_reader_exceeds_the_memory_bound(bag200k):
    """The memory test can fail: the old (rosbags Reader) path goes over the bound on the same bag."""
    n, peak = _traced_peak(bag200k, "old")
    assert n == 200_000 and peak > MEM_BOUND


@pytest.mark.parametrize("fmt", ["ros1", "cdr"])
def test_numpy_imu_decoders_equal_rosbags(fmt):
    from bagmaker import _one
    from rosbags.typesys import Stores, get_typestore

    from imustation.acquisition.importers.messages import decode_imu_cdr, decode_imu_ros1

    store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    de = store.deserialize_ros1 if fmt == "ros1" else store.deserialize_cdr
    rng = np.random.default_rng(5)
    raws = []
    for n in range(12):  # frame_ids of 0..11 characters: every CDR padding
        raw = bytearray(_one(store, "ros1" if fmt == "ros1" else "cdr", "f" * n))
        tail = len(raw) - 37 * 8
        raw[tail:] = rng.normal(size=37).tobytes()
        raw[4:12] = np.array([1_700_000_000 + n, 999_999_999 - n], "<u4").tobytes()
        raws.append(bytes(raw))
    if fmt == "ros1":
        lens = np.array([len(r) for r in raws])
        t, g, a = decode_imu_ros1(b"".join(raws), np.r_[0, np.cumsum(lens)[:-1]], lens)
    else:
        t, g, a = decode_imu_cdr(raws)
    for i, raw in enumerate(raws):
        m = de(raw, "sensor_msgs/msg/Imu")
        assert t[i] == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        w, acc = m.angular_velocity, m.linear_acceleration
        assert tuple(g[i]) == (w.x, w.y, w.z) and tuple(a[i]) == (acc.x, acc.y, acc.z)
    longer = raws[0] + b"\0" * 8  # not the Imu layout
    with pytest.raises(ValueError):
        decode_imu_cdr([longer]) if fmt == "cdr" else decode_imu_ros1(longer, [0], [len(longer)])


@pytest.mark.parametrize("fmt", ["mcap", "sqlite3"])
def test_ros2_numpy_path_equals_rosbags_deserialiser(tmp_path, fmt, monkeypatch):
    from bagmaker import write_big_imu_bag

    from imustation.acquisition.importers import ros2
    from imustation.acquisition.importers.messages import decode_imu_cdr

    decoded = []
    monkeypatch.setattr(ros2, "decode_imu_cdr", lambda raws: decoded.append(len(raws)) or decode_imu_cdr(raws))

    topics = ["/imu/data", "/imu2/data_raw"]
    src = write_big_imu_bag(tmp_path / "r2", 1500, fmt=fmt, topics=topics, extra_every=5, block=1000)
    if fmt == "mcap":
        src = next(src.glob("*.mcap"))
    new, old = _read_all(src, "new", topics), _read_all(src, "old", topics)
    assert sum(decoded) == 3000  # the numpy decoder, not the fallback
    for t in topics:
        assert len(new[t][0]) == 1500
        for x, y in zip(new[t], old[t], strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("fmt,reader", [("ros1", "new"), ("ros1", "old"), ("mcap", "new")])
def test_temperature_topics_become_thermometers(tmp_path, fmt, reader):
    from bagmaker import write_big_imu_bag

    src = write_big_imu_bag(tmp_path / ("t.bag" if fmt == "ros1" else "t"), 1500, fmt=fmt, temp_every=50,
                            extra_every=7, chunk_bytes=100_000)  # fmt: skip
    if fmt == "mcap":
        src = next(src.glob("*.mcap"))
    out = tmp_path / "run.h5"
    res = import_recording(str(src), str(out), block=1000, bag_reader=reader)
    assert res.thermometers == {"imu_temperature": ("/imu/temperature", 30)}
    assert list(res.devices) == ["imu_data"]  # not a device
    i = np.arange(0, 1500, 50)
    with open_run(out) as run_:
        assert run_.thermometers == ["imu_temperature"]
        t, c = run_.temperatures("imu_temperature")
        t_imu = run_.read("imu_data", "t")
        np.testing.assert_array_equal(t, t_imu[i] + 200_000)
        np.testing.assert_allclose(c, 20 + i * 1e-4, rtol=0, atol=1e-12)
    res = run("import", str(src), "-o", str(tmp_path / "cli.h5"))
    assert res.exit_code == 0 and "imu_temperature (30 readings)" in res.output, res.output


@pytest.fixture(scope="module", params=[None, "bz2", "lz4"])
def chunked_bag(request, tmp_path_factory):
    """A closed (indexed) ROS 1 bag of 6000 Imu messages in 22 chunks, its chunk positions and counts,
    and every message's gyro as rosbags reads it."""
    from bagmaker import write_big_imu_bag
    from rosbags.rosbag1 import Reader

    src = write_big_imu_bag(tmp_path_factory.mktemp("cut") / "full.bag", 6000, compression=request.param,
                            chunk_bytes=100_000)  # fmt: skip
    ref = _read_all(src, "old", ["/imu/data"])["/imu/data"]
    with Reader(src) as r:
        chunks = [(c.pos, sum(c.connection_counts.values())) for c in r.chunk_infos]
    return src, request.param, chunks, ref


@pytest.mark.parametrize("where", [0.25, 0.5, 0.8, "index"])
def test_a_truncated_ros1_bag_imports_every_message_before_the_cut(chunked_bag, tmp_path, where):
    """A closed bag cut short (its index at the end gone) used to import nothing ('no Imu topic'):
    the chunks are read one after the other up to the cut, the complete messages of the chunk cut
    short too where its compression allows, and the cut is stated on stderr and in the file."""
    src, compression, chunks, (t_ref, g_ref, _a) = chunked_bag
    data = src.read_bytes()
    index_pos = int.from_bytes(data[data.index(b"index_pos=") + 10 :][:8], "little")
    cut = index_pos + 40 if where == "index" else int(len(data) * where)
    p = tmp_path / "cut.bag"
    p.write_bytes(data[:cut])
    res = run("import", str(p), "-o", str(tmp_path / "cut.h5"))
    assert res.exit_code == 0, res.output
    with open_run(tmp_path / "cut.h5") as run_:
        k = run_.rows("imu_data")
        t, g = run_.read("imu_data", "t"), run_.read("imu_data", "gyro")
        notes = [e.detail for e in run_.events() if e.kind == "note" and "truncated bag" in e.detail]
    # a prefix of the bag, at least every chunk that ends before the cut, at most those that start before it
    ends = [pos for pos, _ in chunks[1:]] + [index_pos]
    complete = sum(n for (pos, n), end in zip(chunks, ends, strict=True) if end <= cut)
    started = sum(n for pos, n in chunks if pos < cut)
    assert complete <= k <= started and k > 0
    np.testing.assert_array_equal(g, g_ref[:k])
    np.testing.assert_array_equal(t, t_ref[:k] - t_ref[0])
    if compression is None and where != "index":
        assert k > complete  # the complete messages of the chunk cut short
    lines = [ln for ln in res.output.splitlines() if "truncated bag" in ln]
    assert len(lines) == 1 and len(notes) == 1, res.output
    assert f"{k} messages before the cut imported" in lines[0] and lines[0].endswith(notes[0])
    if where == "index":
        assert k == 6000 and "inside its index" in lines[0] and "no message lost" in lines[0]
    else:
        assert f"file ends at byte {cut}" in lines[0] and "not imported" in lines[0]
        import re

        about = int(re.search(r"~(\d+) messages \(estimated\)", lines[0]).group(1))
        assert abs(about - (6000 - k)) <= 0.05 * (6000 - k)  # what the cut lost, estimated


def test_a_ros1_bag_cut_at_a_chunk_boundary_says_what_was_lost(chunked_bag, tmp_path):
    """A bag cut exactly between two chunks read to its end without an error, and was reported
    'cut inside its index ... no message lost' although most chunks were gone."""
    import re

    src, _compression, chunks, _ref = chunked_bag
    data = src.read_bytes()
    cut = chunks[3][0]  # the first byte of the fourth chunk
    p = tmp_path / "cut.bag"
    p.write_bytes(data[:cut])
    res = run("import", str(p), "-o", str(tmp_path / "cut.h5"))
    assert res.exit_code == 0, res.output
    k = sum(n for _pos, n in chunks[:3])
    line = next(ln for ln in res.output.splitlines() if "truncated bag" in ln)
    assert "no message lost" not in line and f"{k} messages before the cut imported (3 of {len(chunks)} chunks)" in line
    assert f"{len(chunks) - 3} chunks" in line and "cut between records" in line
    about = int(re.search(r"~(\d+) messages", line).group(1))
    assert abs(about - (6000 - k)) < 0.05 * (6000 - k)  # estimated from the bytes per message read


@pytest.mark.parametrize("fmt", ["ros1", "mcap"])
def test_an_empty_imu_topic_beside_a_good_one_is_skipped_and_named(tmp_path, fmt):
    """Before: 'fewer than two increasing stamps; cannot tell the sample rate' for the whole bag."""
    from bagmaker import _imu_msg
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    imu = store.types["sensor_msgs/msg/Imu"].__msgtype__
    ser = store.serialize_ros1 if fmt == "ros1" else store.serialize_cdr
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer

        path, w = tmp_path / "two.bag", Writer(tmp_path / "two.bag")
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        path, w = tmp_path / "two", Writer(tmp_path / "two", version=9, storage_plugin=StoragePlugin.MCAP)
    with w:
        good = w.add_connection("/imu/data", imu, typestore=store)
        one = w.add_connection("/imu/spare", imu, typestore=store)
        w.add_connection("/imu/unused", imu, typestore=store)
        for i in range(500):
            t = T0 + i * PERIOD
            w.write(good, t, bytes(ser(_imu_msg(store, fmt, i, t, (0.01, 0.0, 0.0), (0, 0, 9.8)), imu)))
        w.write(one, T0, bytes(ser(_imu_msg(store, fmt, 0, T0, (0.01, 0.0, 0.0), (0, 0, 9.8)), imu)))
    src = path if fmt == "ros1" else next(path.glob("*.mcap"))
    res = run("import", str(src), "-o", str(tmp_path / "o.h5"))
    assert res.exit_code == 0, res.output
    assert "Imu topic /imu/spare skipped: 1 message" in res.output
    assert "Imu topic /imu/unused skipped: 0 messages" in res.output
    with open_run(tmp_path / "o.h5") as r:
        assert list(r.devices) == ["imu_data"] and r.rows("imu_data") == 500


@pytest.mark.parametrize("compression", [None, "lz4"])
def test_a_bag_of_one_message_per_chunk_is_read_whole_and_in_order(tmp_path, compression, monkeypatch):
    """Small chunks are split and decoded in batches (their speed: benchmarks/bench_import.py --chunk-bytes 1);
    every message comes out as rosbags reads it, and a cut inside a batch still keeps what precedes it."""
    from bagmaker import write_big_imu_bag

    from imustation.acquisition.importers import rosbag1

    monkeypatch.setattr(rosbag1, "BATCH_BYTES", 40_000)  # several batches in a small bag
    monkeypatch.setattr(rosbag1, "WALK_BYTES", 50_000)  # and several reads of the record walk
    src = write_big_imu_bag(tmp_path / "tiny.bag", 3000, compression=compression, chunk_bytes=1,
                            extra_every=7, temp_every=50)  # fmt: skip
    t_ref, g_ref, a_ref = _read_all(src, "old", ["/imu/data"])["/imu/data"]
    t, g, a = _read_all(src, "new", ["/imu/data"])["/imu/data"]
    np.testing.assert_array_equal(t, t_ref)
    np.testing.assert_array_equal(g, g_ref)
    np.testing.assert_array_equal(a, a_ref)
    res = import_recording(str(src), str(tmp_path / "o.h5"))
    assert res.reports["imu_data"].n == 3000 and res.thermometers["imu_temperature"][1] == 60
    data = src.read_bytes()
    (tmp_path / "cut.bag").write_bytes(data[: len(data) // 2 + 7])
    res = import_recording(str(tmp_path / "cut.bag"), str(tmp_path / "cut.h5"))
    k = res.reports["imu_data"].n
    assert 1000 < k < 3000 and any("truncated bag" in n for n in res.notes)
    with open_run(tmp_path / "cut.h5") as r:
        np.testing.assert_array_equal(r.read("imu_data", "gyro"), g_ref[:k])


def test_one_message_chunks_are_walked_in_runs(tmp_path, monkeypatch):
    """A chunk per message of one topic repeats two records at a constant stride: the walk takes
    them in runs (before: one Python step per record, 126k msg/s against 290-360k for large chunks;
    benchmarks/bench_import.py --chunk-bytes 1). Every message as rosbags reads it; a cut inside a
    run keeps what precedes it; a record whose length breaks the run stops the import as before."""
    from bagmaker import write_big_imu_bag

    from imustation.acquisition.importers import ros1records, rosbag1

    found = []
    real = rosbag1.periodic_run

    def counted(*args):
        k, run = real(*args)
        found.append(k)
        return k, run

    monkeypatch.setattr(rosbag1, "periodic_run", counted)
    monkeypatch.setattr(rosbag1, "BATCH_BYTES", 40_000)
    monkeypatch.setattr(rosbag1, "WALK_BYTES", 50_000)
    src = write_big_imu_bag(tmp_path / "one.bag", 3000, chunk_bytes=1)
    t_ref, g_ref, a_ref = _read_all(src, "old", ["/imu/data"])["/imu/data"]
    found.clear()
    t, g, a = _read_all(src, "new", ["/imu/data"])["/imu/data"]
    np.testing.assert_array_equal(t, t_ref)
    np.testing.assert_array_equal(g, g_ref)
    np.testing.assert_array_equal(a, a_ref)
    assert sum(found) > 2900  # chunk infos in runs (the closed bag's chunks come from its index: below)
    data = src.read_bytes()
    (tmp_path / "cut.bag").write_bytes(data[: len(data) // 2 + 7])
    found.clear()
    res = import_recording(str(tmp_path / "cut.bag"), str(tmp_path / "cut.h5"))
    assert sum(found) > 2 * 1400  # no index: the chunks walked in runs, twice (topics, then messages)
    k = res.reports["imu_data"].n
    assert 1000 < k < 3000 and any("truncated bag" in n for n in res.notes)
    with open_run(tmp_path / "cut.h5") as r:
        np.testing.assert_array_equal(r.read("imu_data", "gyro"), g_ref[:k])
    monkeypatch.setattr(ros1records, "MIN_RUN", 1 << 40)  # no runs: record by record, as before
    one_by_one = import_recording(str(tmp_path / "cut.bag"), str(tmp_path / "cut1.h5"))
    assert one_by_one.reports["imu_data"].n == k and one_by_one.notes == res.notes
    # the header length of a chunk in the middle of a run made absurd: one line, as one by one
    at = data.index(b"op=\x05", len(data) // 3) - 8  # the length of the chunk header's op field, minus 4
    bad = bytearray(data)
    bad[at : at + 4] = (1 << 21).to_bytes(4, "little")
    (tmp_path / "bad.bag").write_bytes(bytes(bad))
    assert_one_line_error(run("import", str(tmp_path / "bad.bag"), "-o", str(tmp_path / "bad.h5")), "bad.bag")


@pytest.mark.parametrize("compression", [None, "lz4", "bz2"])
@pytest.mark.parametrize("topics", [("/imu/data",), ("/imu/data", "/imu/b")])
def test_small_chunk_bags_are_read_from_their_index(tmp_path, monkeypatch, compression, topics):
    """A closed bag of a chunk per message (compressed, or two topics interleaved) is read from its index's
    chunk table, every chunk gathered at once (before: lz4/bz2 and interleaved ones were walked record by
    record, ~0.3 of the large-chunk rate): every message as rosbags reads it."""
    from bagmaker import write_big_imu_bag

    from imustation.acquisition.importers import ros1chunks

    used = []
    real = ros1chunks.layout

    def counted(*args):
        lay = real(*args)
        used.append(lay is not None)
        return lay

    monkeypatch.setattr(ros1chunks, "layout", counted)
    monkeypatch.setattr(ros1chunks, "BATCH_BYTES", 20_000)
    src = write_big_imu_bag(tmp_path / "one.bag", 700, chunk_bytes=1, compression=compression, topics=topics,
                            temp_every=7)  # fmt: skip
    ref = _read_all(src, "old", list(topics))
    got = _read_all(src, "new", list(topics))
    assert used and all(used)
    for tp in topics:
        for x, y in zip(got[tp], ref[tp], strict=True):
            np.testing.assert_array_equal(x, y)
    res = import_recording(str(src), str(tmp_path / "o.h5"))
    assert res.thermometers["imu_temperature"][1] == 100 and not any("truncated" in n for n in res.notes)


def test_a_chunk_table_that_does_not_tile_the_bag_is_not_used(tmp_path, monkeypatch):
    """A chunk info pointing one byte off, or counting another number of messages: reading from the table
    stops at the block it is in, and the bag is walked from there (every message still read), never read
    from a table that does not match its data."""
    from bagmaker import write_big_imu_bag

    from imustation.acquisition.importers import ros1chunks
    from imustation.acquisition.importers.rosbag1 import Ros1Bag

    monkeypatch.setattr(ros1chunks, "BLOCK_BYTES", 20_000)
    src = write_big_imu_bag(tmp_path / "one.bag", 300, chunk_bytes=1)
    with Ros1Bag(str(src)) as bag:
        bag.index()
        counts = [0, 0, 0]
        list(ros1chunks.read_chunks(bag.fh, bag.table, bag.first_record, bag.index_pos, {}, counts))
        assert counts[2] is None and counts[1] == 300
        for edit in ("pos", "messages"):
            pos, msgs = bag.table.pos.copy(), bag.table.messages.copy()
            if edit == "pos":
                pos[100] += 1
            else:
                msgs[100] = 2
            counts = [0, 0, 0]
            table = ros1chunks.ChunkTable(pos, bag.table.conns, msgs)
            list(ros1chunks.read_chunks(bag.fh, table, bag.first_record, bag.index_pos, {}, counts))
            assert 0 < counts[1] <= 100 and counts[2] == pos[counts[0]]  # walked on from the block's start
            bag.table = table
            t = np.concatenate([c.time for c in bag.chunks({})])
            np.testing.assert_array_equal(np.diff(t), 2_500_000)
            assert len(t) == 300
            bag.index()  # the table as the index says


@pytest.mark.parametrize("kernel", [False, True])
def test_damaged_small_chunk_bags_read_or_fail_in_one_line(tmp_path, monkeypatch, kernel):
    """The fuzz corpus's small-chunk bags (tests/fuzz_corpus.py): every one imports, or fails with one
    line, exit 2 (a damaged lz4 chunk, a chunk whose header says another size, lz4 frames whose content
    checksum, header checksum or block size is wrong); lz4 chunks through lz4.frame and through the
    compiled decoder (acquisition/importers/lz4frames.py)."""
    from fuzz_corpus import small_chunk_bags

    from imustation.acquisition.importers import ros1chunks

    monkeypatch.setattr(ros1chunks, "LZ4_KERNEL", kernel)
    cases = small_chunk_bags(tmp_path)
    assert len(cases) == 20
    why = {"one-lz4sum-content-sum.bag": "content checksum", "one-lz4sum-header-sum.bag": "header checksum",
           "one-lz4sum-block-size.bag": "cut short"}  # fmt: skip
    for name, path, expect in cases:
        res = run("import", str(path), "-o", str(tmp_path / f"{name}.h5"))
        if expect["import"] == "invalid":
            assert_one_line_error(res, name, *([why[name]] if kernel and name in why else []))
        else:
            assert res.exit_code == 0, (name, res.output)
            if "cut" in name:
                assert "truncated bag" in res.output, (name, res.output)
