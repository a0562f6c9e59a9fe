"""A seeded corpus of damaged and hostile inputs, and a runner with a time limit per run.

:func:`build_corpus` writes mutated run files (truncations, bit flips, attributes
absent / of the wrong type / zero / NaN / infinite / contradicting the
timestamps, unexpected group members, links out of the file, invalid UTF-8 in
events, datasets resized to billions of rows, corrupted compressed chunks,
NaN and impossible values), CSV logs, ``.npy`` arrays, ROS 1 bags and station
configs into a folder and returns one :class:`Case` per (input, reader command).
:func:`run_cases` runs them in a worker process (the CLI in-process, so the
imports are paid once) and restarts the worker when a case exceeds its time
limit. A case fails on a traceback, on a hang, and - for inputs that are
invalid - on anything but exit status 2 with one ``imustation: error:`` line.

The same seed gives the same corpus. Run it by hand::

    python tests/fuzz_corpus.py --seed 7 --size large
"""

from __future__ import annotations

import json
import os
import random
import select
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: virtual seconds of the base capture (100 Hz: two 8192-row chunks per dataset)
BASE_SECONDS = 100.0
BASE_CONFIG = """
[station]
name = "fuzz"
seed = 3
flush_interval_s = 1.0

[[device]]
name = "gyro"
driver = "bmx055"
bus = "i2c:1"
rate_hz = 100
bandwidth_hz = 32
  [device.sim]
  faults = [{kind = "disconnect", at_s = 40.0, duration_s = 2.0}]

[[thermometer]]
name = "ambient"
driver = "mcp9804"
bus = "i2c:2"
address = 0x18
"""

#: readers of run files and what they are given besides the path
RUN_READERS = {
    "inspect": ["inspect", "{path}"],
    "analyze": ["analyze", "{path}", "-m", "40", "--estimator", "gmwm"],
    "export": ["export", "{path}", "--format", "kalibr", "--gyro-only", "-o", "{out}.yaml"],
    "report": ["report", "{path}", "-o", "{out}.report", "--warmup", "0"],
    "monitor": ["{path}"],
}
ARRAY_READERS = {
    "analyze": ["analyze", "{path}", "--rate", "100", "-m", "40", "--estimator", "gmwm"],
    "import": ["import", "{path}", "-o", "{out}.h5", "--quiet"],
}


@dataclass(frozen=True)
class Case:
    """One reader run: ``argv`` of the CLI (or of the monitor's watcher when ``kind == "monitor"``).

    ``expect``: ``"invalid"`` (exit 2, one error line) or ``"any"`` (0 or 2; the input may be
    harmless, e.g. a flipped bit in space no reader uses). Never a traceback, never a hang.
    """

    name: str
    argv: tuple[str, ...]
    expect: str
    kind: str = "cli"


# --- the corpus --------------------------------------------------------------------------


def base_run(folder: Path) -> Path:
    """A 100 s simulated capture with a gap, a temperature channel and a thermometer (made once)."""
    from imustation.acquisition import capture, load_config

    path = folder / "base.h5"
    if not path.exists():
        cfg = folder / "base.toml"
        cfg.write_text(BASE_CONFIG)
        capture(load_config(cfg), path, BASE_SECONDS, simulate=True)
    return path


def _edit(base: Path, dst: Path, edit: Callable) -> Path:
    import h5py

    shutil.copyfile(base, dst)
    with h5py.File(dst, "r+") as f:
        edit(f)
    return dst


def _set(obj: str, key: str, value) -> Callable:
    def edit(f):
        f[obj].attrs[key] = value

    return edit


def _del(obj: str, key: str) -> Callable:
    def edit(f):
        del f[obj].attrs[key]

    return edit


def _resize(name: str, rows: int) -> Callable:
    def edit(f):
        f[name].resize(rows, axis=0)

    return edit


def _scale_rate(factor: float) -> Callable:
    def edit(f):
        g = f["devices/gyro"]
        g.attrs["rate_hz"] = float(g.attrs["rate_hz"]) * factor

    return edit


def _event(field: str, value) -> Callable:
    def edit(f):
        rows = f["events"][()]
        rows[-1][field] = value
        f["events"][-1] = rows[-1]

    return edit


def _replace_gyro(values: np.ndarray) -> Callable:
    """Float gyro data (as an import writes) holding ``values`` in its first rows."""

    def edit(f):
        g = f["devices/gyro"]
        old = g["gyro"]
        n, attrs = old.shape[0], dict(old.attrs)
        data = np.full((n, 3), 0.01)
        data[: len(values)] = values
        del g["gyro"]
        ds = g.create_dataset("gyro", data=data, maxshape=(None, 3), chunks=(8192, 3), compression="gzip")
        for k, v in attrs.items():
            ds.attrs[k] = v
        ds.attrs["scale"] = 1.0

    return edit


def _corrupt_chunk(name: str, index: int) -> Callable:
    def edit(f):
        ds = f[name]
        info = ds.id.get_chunk_info(index)
        ds.id.write_direct_chunk(info.chunk_offset, b"\x78\x01" + bytes(range(256)) * 8, info.filter_mask)

    return edit


def _member(where: str, make: Callable) -> Callable:
    def edit(f):
        make(f, where)

    return edit


def run_file_mutations(base: Path) -> list[tuple[str, Callable, str]]:
    """(name, h5py edit, which readers must refuse: "all" or "data" = those reading the samples)."""
    import h5py

    nan, inf = float("nan"), float("inf")
    m: list[tuple[str, Callable, str]] = []
    for key, values in {
        "format": [5, "other"],
        "format_version": ["1", 2, 1.0, True],
        "started_utc": [7, "yesterday"],
        "station": [np.array([1, 2])],
        "part": [0, "one"],
        "simulated": ["yes"],
    }.items():
        m += [(f"root.{key}={v!r}"[:60], _set("/", key, v), "all") for v in values]
    m += [(f"root.del.{k}", _del("/", k), "all") for k in ("format", "format_version", "started_utc")]
    for v in [0.0, nan, inf, -100.0, "fast", np.array([100.0, 100.0]), 1e300, 5e5]:
        m.append((f"rate_hz={v!r}"[:60], _set("devices/gyro", "rate_hz", v), "all"))
    m += [
        ("rate_hz.del", _del("devices/gyro", "rate_hz"), "all"),
        ("driver=3", _set("devices/gyro", "driver", 3), "all"),
    ]
    m += [(f"rate_hz*{k}", _scale_rate(k), "all") for k in (2.0, 0.5, 10.0)]
    for v in [0.0, nan, "fast", 50.0]:
        m.append((f"thermo.rate_hz={v!r}", _set("thermometers/ambient", "rate_hz", v), "all"))
    for v in [0.0, nan, inf, "x", np.array([1.0, 2.0, 3.0])]:
        m.append((f"scale={v!r}"[:60], _set("devices/gyro/gyro", "scale", v), "all"))
    m += [(f"gyro.del.{k}", _del("devices/gyro/gyro", k), "all") for k in ("scale", "offset", "units", "axes")]
    m += [
        ("offset=nan", _set("devices/gyro/gyro", "offset", nan), "all"),
        ("axes=x,y", _set("devices/gyro/gyro", "axes", "x,y"), "all"),
    ]
    m += [
        ("t.rows=0", _resize("devices/gyro/t", 0), "all"),
        ("gyro.rows=n-1", lambda f: f["devices/gyro/gyro"].resize(f["devices/gyro/gyro"].shape[0] - 1, axis=0), "all"),
        ("gyro.rows=2^31", _resize("devices/gyro/gyro", 2**31), "all"),
        ("t.rows=2^33", lambda f: [f[f"devices/gyro/{k}"].resize(2**33, axis=0) for k in f["devices/gyro"]], "all"),
        ("events.rows=2^31", _resize("events", 2**31), "all"),
        ("thermo.t.rows=2^31", _resize("thermometers/ambient/t", 2**31), "all"),
        ("t.del", lambda f: f["devices/gyro"].__delitem__("t"), "all"),
        ("devices.del", lambda f: f.__delitem__("devices"), "all"),
        ("events.del", lambda f: f.__delitem__("events"), "all"),
        ("events=ints", lambda f: (f.__delitem__("events"), f.create_dataset("events", data=np.arange(5))), "all"),
        ("extra.root", lambda f: f.create_dataset("extra", data=[1]), "all"),
        ("extra.group.in.device", lambda f: f["devices/gyro"].create_group("sub"), "all"),
        ("extra.dataset.in.devices", lambda f: f["devices"].create_dataset("stray", data=[1]), "all"),
        ("extra.in.thermometer", lambda f: f["thermometers/ambient"].create_dataset("x", data=[1.0]), "all"),
        ("external.link", lambda f: f["devices/gyro"].__setitem__("mag", h5py.ExternalLink("other.h5", "/x")), "all"),
        ("soft.link", lambda f: f["devices/gyro"].__setitem__("mag", h5py.SoftLink("/devices/gyro/gyro")), "all"),
        (
            "gyro=text",
            lambda f: (
                f["devices/gyro"].__delitem__("gyro"),
                f["devices/gyro"].create_dataset("gyro", data=np.array([b"a"] * 5)),
            ),
            "all",
        ),
        (
            "temp=3d",
            lambda f: (
                f["devices/gyro"].__delitem__("temp"),
                f["devices/gyro"].create_dataset("temp", data=np.zeros((5, 2, 2))),
            ),
            "all",
        ),
        ("event.lost<0", _event("lost", -5), "events"),
        ("event.kind=bogus", _event("kind", b"bogus"), "events"),
        ("event.source=badutf8", _event("source", b"\xff\xfe\xfa"), "events"),
        ("event.detail=badutf8", _event("detail", b"gap \xe2\x82"), "none"),
        ("gyro.chunk0=garbage", _corrupt_chunk("devices/gyro/gyro", 0), "data"),
        ("t.chunk1=garbage", _corrupt_chunk("devices/gyro/t", 1), "data"),
        ("gyro=nan", _replace_gyro(np.array([[np.nan, 0.0, 0.0]])), "data"),
        ("gyro=4.3e19", _replace_gyro(np.array([[4.3e19, 0.0, 0.0]])), "data"),
        # issue 33: values out of physical range, a rate its stamps contradict
        ("rate_hz*1.25", _scale_rate(1.25), "none"),  # read at the stamps' rate, with a warning
        ("offset=1e300", _set("devices/gyro/gyro", "offset", 1e300), "all"),
        ("scale=1e300", _set("devices/gyro/gyro", "scale", 1e300), "all"),
        ("ended<started", _set("/", "ended_utc", "2001-01-01T00:00:00.000+00:00"), "all"),
        ("event.lost=2^62", _event("lost", 2**62), "events"),
        ("t.steps.back", _step_back(10), "all"),
        ("t.steps.back.late", _step_back(7000), "data"),  # found when the record is read
    ]
    return m


def _step_back(row: int) -> Callable:
    def edit(f):
        t = f["devices/gyro/t"]
        t[row] = t[row - 10]

    return edit


def _refused_by(scope: str, command: str) -> bool:
    if scope == "all":
        return True
    if scope == "events":
        return command in ("inspect", "analyze", "export", "report", "monitor")
    if scope == "data":
        return command in ("analyze", "export", "report")
    return False


def _npy_header_claiming(rows: int) -> bytes:
    header = repr({"descr": "<f8", "fortran_order": False, "shape": (rows,)}).encode()
    header += b" " * (63 - (len(header) + 10) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + b"\x00" * 64


def array_inputs(folder: Path, rng: random.Random) -> list[tuple[str, Path, dict[str, str]]]:
    """(name, file, expectation per reader) of CSV logs and .npy arrays."""
    t = np.arange(2000) / 100.0
    g = np.random.default_rng(rng.randrange(2**32)).normal(0, 0.01, (2000, 3))
    good_csv = "t,gx [rad/s],gy [rad/s],gz [rad/s]\n" + "\n".join(
        f"{a:.3f},{b:.6f},{c:.6f},{d:.6f}" for a, (b, c, d) in zip(t, g, strict=True)
    )
    lines = good_csv.split("\n")
    out = []

    def text(name: str, data: bytes | str, expect: dict[str, str]) -> None:
        p = folder / name
        p.write_bytes(data.encode() if isinstance(data, str) else data)
        out.append((name, p, expect))

    bad = {"analyze": "invalid", "import": "invalid"}
    text("bad-utf8.csv", good_csv.encode().replace(b"\n1.000,", b"\n1.0\xff\xfe,", 1), bad)
    text("bad-utf8-header.csv", b"t,g\xffx,gy,gz\n" + "\n".join(lines[1:]).encode(), bad)
    text("nan.csv", "\n".join([*lines[:100], "1.00,nan,0,0", *lines[101:]]), bad)
    text("inf.csv", "\n".join([*lines[:100], "1.00,1e400,0,0", *lines[101:]]), bad)
    text("header-only.csv", lines[0] + "\n", bad)
    text("empty.csv", "", bad)
    text("ragged.csv", "\n".join([*lines[:50], "0.5,1", *lines[51:]]), bad)
    text("garbage.csv", bytes(rng.randrange(256) for _ in range(3000)), bad)
    # issue 33: no unit stated (refused by the import; plain columns with --rate), units in the names,
    # integer-ms stamps, a byte that is not UTF-8 far into the file
    plain = "t,gx,gy,gz\n" + "\n".join(lines[1:])
    text("no-unit.csv", plain, {"analyze": "any", "import": "invalid"})
    text("dps.csv", plain.replace("t,gx,gy,gz", "t,gx_dps,gy_dps,gz_dps", 1), {"analyze": "any", "import": "any"})
    ms = "time_ms,gx_rads,gy_rads,gz_rads\n" + "\n".join(
        f"{int(k * 2.5)},{b:.6f},{c:.6f},{d:.6f}" for k, (b, c, d) in enumerate(g)
    )
    text("int-ms.csv", ms, {"analyze": "any", "import": "any"})
    late = good_csv.encode()
    cut = late.index(b"\n", len(late) * 3 // 4) + 1
    text("latin1-late.csv", late[:cut] + b"\xe9" + late[cut:], bad)

    def npy(name: str, arr, expect: dict[str, str], raw: bytes | None = None) -> None:
        p = folder / name
        if raw is not None:
            p.write_bytes(raw)
        else:
            with open(p, "wb") as fh:
                np.save(fh, arr, allow_pickle=True)
        out.append((name, p, expect))

    log = np.column_stack([t, g])
    npy("ramp.npy", np.arange(20000.0), {"analyze": "any", "import": "invalid"})
    npy("ramp4.npy", np.column_stack([t, t, t, t]), {"analyze": "any", "import": "any"})
    npy("claims-1e11-rows.npy", None, bad, raw=_npy_header_claiming(10**11))
    npz = folder / "tmp.npz"
    np.savez(npz, a=log)
    npy("renamed-npz.npy", None, bad, raw=npz.read_bytes())
    npy("object.npy", np.array([{"a": 1}, None], dtype=object), bad)
    npy("3d.npy", np.zeros((10, 2, 2)), bad)
    npy("empty.npy", np.zeros(0), bad)
    npy("nan.npy", np.where(np.arange(2000) == 7, np.nan, 0.01), bad)
    npy("nan-log.npy", np.where(np.arange(8000).reshape(2000, 4) == 9, np.nan, log), bad)
    npy("bool.npy", np.ones(100, dtype=bool), bad)
    npy("complex.npy", np.ones(100, dtype=complex), bad)
    npy("bad-header.npy", None, bad, raw=b"\x93NUMPY\x01\x00\x10\x00{'descr': 7}    \n")
    return out


CONFIG_HEAD = '[station]\nname = "f"\n[[device]]\nname = "g"\ndriver = "bmx055"\nbus = "i2c:1"\n'
CONFIG_THERMO = '[[thermometer]]\nname = "t1"\ndriver = "mcp9804"\nbus = "i2c:2"\naddress = 0x18\n'


def config_inputs(folder: Path) -> list[tuple[str, Path, str]]:
    """(name, config file, expectation) of station configs that capture --simulate must check."""
    deep = "x = " + "[" * 500 + "]" * 500 + "\n"
    bodies = {
        "sim-int": ("[station]\n[[device]]\nname='g'\ndriver='bmx055'\nbus='i2c:1'\nsim = 3\n", "invalid"),
        "faults-str": (CONFIG_HEAD + "  [device.sim]\n  faults = 'x'\n", "invalid"),
        "fault-every-0": (CONFIG_HEAD + "  [device.sim]\n  faults = [{kind='nack', every_s=0}]\n", "invalid"),
        "fault-every-tiny": (CONFIG_HEAD + "  [device.sim]\n  faults = [{kind='nack', every_s=1e-300}]\n", "invalid"),
        "fault-at-inf": (CONFIG_HEAD + "  [device.sim]\n  faults = [{kind='nack', at_s=inf}]\n", "invalid"),
        "fault-every-nan": (CONFIG_HEAD + "  [device.sim]\n  faults = [{kind='nack', every_s=nan}]\n", "invalid"),
        "deep-array-station": (deep + CONFIG_HEAD, "invalid"),
        "deep-array-device": (CONFIG_HEAD + deep, "invalid"),
        "deep-array-sim": (CONFIG_HEAD + "  [device.sim]\n  " + deep, "invalid"),
        "sigma-text": (CONFIG_HEAD + "  [device.sim]\n  sigma_w = 'abc'\n", "invalid"),
        "sigma-nan": (CONFIG_HEAD + "  [device.sim]\n  sigma_w = nan\n", "invalid"),
        "sigma-neg": (CONFIG_HEAD + "  [device.sim]\n  sigma_w = -1.0\n", "invalid"),
        "sigma-2": (CONFIG_HEAD + "  [device.sim]\n  sigma_w = [1e-3, 1e-3]\n", "invalid"),
        "tau-0": (CONFIG_HEAD + "  [device.sim]\n  tau_b = 0.0\n", "invalid"),
        "temp-period-0": (CONFIG_HEAD + "  [device.sim]\n  temp_period_s = 0.0\n", "invalid"),
        "temp-inf": (CONFIG_HEAD + "  [device.sim]\n  temp_c = inf\n", "invalid"),
        "gravity-nested": (CONFIG_HEAD + "  [device.sim]\n  gravity_g = [[1.0]]\n", "invalid"),
        "seed-neg": (CONFIG_HEAD + "  [device.sim]\n  seed = -1\n", "invalid"),
        "seed-huge": ("[station]\nseed = 9223372036854775807\n" + CONFIG_HEAD.split("\n", 2)[2], "any"),
        "station-seed-neg": ("[station]\nseed = -5\n" + CONFIG_HEAD.split("\n", 2)[2], "invalid"),
        "rate-nan": (CONFIG_HEAD + "rate_hz = nan\n", "invalid"),
        "rate-text": (CONFIG_HEAD + "rate_hz = '400'\n", "invalid"),
        "address-huge": (CONFIG_HEAD + "address = 100000000000000000\n", "invalid"),
        "thermo-sim-int": (CONFIG_HEAD + CONFIG_THERMO + "sim = 3\n", "invalid"),
        "thermo-rate-0": (CONFIG_HEAD + CONFIG_THERMO + "rate_hz = 0\n", "invalid"),
        "thermo-period-0": (CONFIG_HEAD + CONFIG_THERMO + "  [thermometer.sim]\n  temp_period_s = 0.0\n", "invalid"),
        "thermo-sim-unknown": (CONFIG_HEAD + CONFIG_THERMO + "  [thermometer.sim]\n  bogus = 1\n", "invalid"),
        "replay-missing": (CONFIG_HEAD + "  [device.sim]\n  replay = 'nope.h5#g/gyro'\n", "invalid"),
        "device-array-of-ints": ("device = [1, 2]\n", "invalid"),
        "bad-utf8": (b"[station]\nname = '\xff'\n", "invalid"),
    }
    out = []
    for name, (body, expect) in bodies.items():
        p = folder / f"{name}.toml"
        p.write_bytes(body if isinstance(body, bytes) else body.encode())
        out.append((name, p, expect))
    return out


def bag_inputs(folder: Path) -> list[tuple[str, Path, dict[str, str]]]:
    """ROS 1 bags: truncated, two topics mapping to one device name, NaN and impossible values."""
    from bagmaker import write_imu_bag

    n = 600
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000
    g = np.full((n, 3), 0.01)
    a = np.tile([0.0, 0.0, 9.81], (n, 1))
    out = []
    good = write_imu_bag(folder / "good.bag", t, g, a)
    data = good.read_bytes()
    for frac in (0.3, 0.7, 0.95):
        p = folder / f"cut{int(frac * 100)}.bag"
        p.write_bytes(data[: int(len(data) * frac)])
        out.append((p.name, p, {"import": "any", "analyze": "any"}))
    bad = g.copy()
    bad[100, 0] = np.nan
    out.append(("nan.bag", write_imu_bag(folder / "nan.bag", t, bad, a), {"import": "any", "analyze": "invalid"}))
    huge = g.copy()
    huge[200, 1] = 4.3e19
    out.append(("huge.bag", write_imu_bag(folder / "huge.bag", t, huge, a), {"import": "any", "analyze": "invalid"}))
    out += _issue33_bags(folder, t, g, a)
    out += small_chunk_bags(folder)
    return out


def small_chunk_bags(folder: Path) -> list[tuple[str, Path, dict[str, str]]]:
    """Bags of a chunk per message (read from their index's chunk table): lz4, bz2, two topics
    interleaved; each cut inside a chunk and exactly between two; a chunk info pointing one byte off
    (the table is not used: walked), an lz4 chunk whose data is damaged, a chunk header's size wrong."""
    from bagmaker import write_big_imu_bag
    from rosbags.rosbag1 import Reader

    ok, bad = {"import": "any", "analyze": "any"}, {"import": "invalid", "analyze": "invalid"}
    out = []
    one, two = ("/imu/data",), ("/imu/data", "/imu/b")
    for name, comp, topics in (("lz4", "lz4", one), ("bz2", "bz2", one), ("two", None, two), ("two-lz4", "lz4", two)):
        src = write_big_imu_bag(folder / f"one-{name}.bag", 500, compression=comp, chunk_bytes=1, topics=topics)
        out.append((src.name, src, ok))
        data = src.read_bytes()
        with Reader(src) as r:
            infos = [c.pos for c in r.chunk_infos]  # the reader empties its list when closed
        cut = folder / f"one-{name}-cut.bag"
        cut.write_bytes(data[: len(data) * 2 // 5])
        edge = folder / f"one-{name}-cut-at-chunk.bag"
        edge.write_bytes(data[: infos[len(infos) // 2]])
        out += [(cut.name, cut, ok), (edge.name, edge, ok)]
        if name in ("lz4", "two"):
            # the chunk_pos of one chunk info one byte off: the table does not tile the bag, it is walked
            at = data.index(b"chunk_pos=", infos[-1]) + len(b"chunk_pos=")
            off = bytearray(data)
            off[at : at + 8] = (int.from_bytes(data[at : at + 8], "little") + 1).to_bytes(8, "little")
            p = folder / f"one-{name}-pos-off.bag"
            p.write_bytes(bytes(off))
            out.append((p.name, p, ok))
        if name == "lz4":
            mid = infos[len(infos) // 3]
            hl = int.from_bytes(data[mid : mid + 4], "little")
            dmg = bytearray(data)
            dmg[mid + 8 + hl + 12] ^= 0xFF  # inside the lz4 block of a chunk
            p = folder / "one-lz4-damaged.bag"
            p.write_bytes(bytes(dmg))
            out.append((p.name, p, bad))
        if name == "two":
            mid = infos[len(infos) // 3]
            at = data.index(b"size=", mid) + len(b"size=")
            big = bytearray(data)
            big[at : at + 4] = (int.from_bytes(data[at : at + 4], "little") + 7).to_bytes(4, "little")
            p = folder / "one-two-size.bag"
            p.write_bytes(bytes(big))
            out.append((p.name, p, bad))
    out += _lz4_checksum_bags(folder)
    return out


def _lz4_checksum_bags(folder: Path) -> list[tuple[str, Path, dict[str, str]]]:
    """A one-message-per-chunk lz4 bag whose frames carry a content checksum and no content size (as ROS's
    roslz4 writes them), good, and with one chunk's frame damaged: its content checksum, its header checksum,
    its block size beyond the chunk."""
    from bagmaker import roslz4_bag

    ok, bad = {"import": "any", "analyze": "any"}, {"import": "invalid", "analyze": "invalid"}
    # the frame: magic, FLG, BD, header checksum (no content size), first block's size, ...
    src, data, _, frame, dl = roslz4_bag(folder / "one-lz4sum.bag", 500, 300)
    out = [(src.name, src, ok)]
    for name, where, value in (
        ("content-sum", frame + dl - 1, data[frame + dl - 1] ^ 0x5A),
        ("header-sum", frame + 6, data[frame + 6] ^ 0x5A),
        ("block-size", frame + 7, None),
    ):
        dmg = bytearray(data)
        if value is None:  # the first block's size word: more than the chunk holds (below the 64 KB maximum)
            dmg[where : where + 4] = (dl + 100).to_bytes(4, "little")
        else:
            dmg[where] = value
        p = folder / f"one-lz4sum-{name}.bag"
        p.write_bytes(bytes(dmg))
        out.append((p.name, p, bad))
    return out


def _issue33_bags(folder: Path, t, g, a) -> list[tuple[str, Path, dict[str, str]]]:
    """A bag cut between two chunks, MCAP of ROS 1 messages (good, chunk CRC failing, record length
    corrupted, cut short) and a ROS 2 MCAP whose chunk fails its CRC."""
    import struct

    from bagmaker import write_big_imu_bag, write_imu_bag, write_ros1_mcap
    from rosbags.rosbag1 import Reader

    ok, bad = {"import": "any", "analyze": "any"}, {"import": "invalid", "analyze": "invalid"}
    out = []
    chunky = write_big_imu_bag(folder / "chunky.bag", 3000, chunk_bytes=100_000)
    with Reader(chunky) as r:
        at = r.chunk_infos[2].pos
    p = folder / "cut-at-chunk.bag"
    p.write_bytes(chunky.read_bytes()[:at])
    out.append((p.name, p, ok))
    good = write_ros1_mcap(folder / "ros1.mcap", t, g, a, chunk_msgs=200, compression="lz4")
    out.append((good.name, good, ok))
    data = good.read_bytes()
    pos = 8
    while data[pos] != 0x06:  # the first chunk record
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    n = struct.unpack_from("<Q", data, pos + 1)[0]
    flip = bytearray(data)
    flip[pos + 9 + n - 20] ^= 0x01
    (folder / "ros1-crc.mcap").write_bytes(bytes(flip))
    length = bytearray(data)
    length[pos + 1 : pos + 9] = struct.pack("<Q", 2**40)
    (folder / "ros1-length.mcap").write_bytes(bytes(length))
    (folder / "ros1-cut.mcap").write_bytes(data[: len(data) // 2])
    out += [("ros1-crc.mcap", folder / "ros1-crc.mcap", bad), ("ros1-length.mcap", folder / "ros1-length.mcap", bad)]
    out.append(("ros1-cut.mcap", folder / "ros1-cut.mcap", ok))
    r2 = next(write_imu_bag(folder / "r2", t, g, a, fmt="mcap").glob("*.mcap"))
    data = r2.read_bytes()
    pos = 8
    while data[pos] != 0x06:
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    flip = bytearray(data)  # rosbags writes no chunk CRC (0): one that does not match its records
    flip[pos + 9 + 24 : pos + 9 + 28] = struct.pack("<I", 0xDEADBEEF)
    (folder / "ros2-crc.mcap").write_bytes(bytes(flip))
    out.append(("ros2-crc.mcap", folder / "ros2-crc.mcap", bad))
    return out


def _two_topics_bag(folder: Path) -> Path:
    from bagmaker import _imu_msg
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    imu = store.types["sensor_msgs/msg/Imu"].__msgtype__
    path = folder / "two-topics.bag"
    with Writer(path) as w:
        conns = [w.add_connection(tp, imu, typestore=store) for tp in ("/imu/a", "/imu_a")]
        for i in range(300):
            t = 1_700_000_000_000_000_000 + i * 10_000_000
            for c in conns:
                w.write(c, t, store.serialize_ros1(_imu_msg(store, "ros1", i, t, (0.01, 0.0, 0.0), (0, 0, 9.8)), imu))
    return path


def build_corpus(folder: Path, seed: int = 1, size: str = "small") -> list[Case]:
    """Every case of the corpus for ``seed``; ``size`` "small" (the default suite) or "large"."""
    rng = random.Random(seed)
    folder.mkdir(parents=True, exist_ok=True)
    base = base_run(folder)
    raw = base.read_bytes()
    cases: list[Case] = []
    readers = RUN_READERS if size == "large" else {k: RUN_READERS[k] for k in ("inspect", "analyze", "monitor")}

    quick = {k: RUN_READERS[k] for k in ("inspect", "analyze", "monitor")}

    def add_run(name: str, path: Path, refuse: Callable[[str], bool], readers: dict = readers) -> None:
        for cmd, argv in readers.items():
            args = tuple(a.format(path=path, out=folder / f"{name}.{cmd}") for a in argv)
            cases.append(
                Case(
                    f"run:{name}:{cmd}",
                    args,
                    "invalid" if refuse(cmd) else "any",
                    "monitor" if cmd == "monitor" else "cli",
                )
            )

    mutations = run_file_mutations(base)
    if size != "large":
        mutations = rng.sample(mutations, 24)
    for name, edit, scope in mutations:
        safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in name)
        add_run(name, _edit(base, folder / f"m-{safe}.h5", edit), lambda cmd, s=scope: _refused_by(s, cmd))
    for i in range(4 if size != "large" else 20):
        cut = rng.randrange(0, len(raw))
        p = folder / f"cut{i}.h5"
        p.write_bytes(raw[:cut])
        add_run(f"cut{cut}", p, lambda cmd: True, quick)
    for i in range(4 if size != "large" else 40):
        data = bytearray(raw)
        pos = rng.randrange(len(data))
        data[pos] ^= 1 << rng.randrange(8)
        p = folder / f"flip{i}.h5"
        p.write_bytes(bytes(data))
        add_run(f"flip{pos}", p, lambda cmd: False, quick)
    arrays = array_inputs(folder, rng)
    for name, path, expect in arrays:
        for cmd, argv in ARRAY_READERS.items():
            args = tuple(a.format(path=path, out=folder / f"{name}.{cmd}") for a in argv)
            cases.append(Case(f"array:{name}:{cmd}", args, expect[cmd]))
    for name, path, expect in config_inputs(folder):
        out = folder / f"{name}.h5"
        cases.append(
            Case(
                f"config:{name}",
                ("capture", str(path), "--simulate", "--duration", "2s", "-o", str(out), "--quiet", "--overwrite"),
                expect,
            )
        )
    if size == "large":
        bags = bag_inputs(folder)
        bags.append(("two-topics.bag", _two_topics_bag(folder), {"import": "invalid", "analyze": "invalid"}))
        for name, path, expect in bags:
            for cmd, argv in ARRAY_READERS.items():
                args = [a.format(path=path, out=folder / f"{name}.{cmd}") for a in argv]
                if cmd == "analyze":
                    args = ["analyze", str(path), "-m", "40", "--estimator", "gmwm"]
                cases.append(Case(f"bag:{name}:{cmd}", tuple(args), expect[cmd]))
    return cases


# --- running it ---------------------------------------------------------------------------


def _worker() -> None:
    """Read one JSON case per line on stdin, run it in-process, answer one JSON line on stdout."""
    import traceback

    from click.testing import CliRunner

    from imustation.cli import cli
    from imustation.errors import ImustationError

    out = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)  # nothing but answers on the pipe, whatever a library prints
    sys.stdout = sys.stderr
    for line in sys.stdin:
        case = json.loads(line)
        tb = None
        if case["kind"] == "monitor":
            code, err = _monitor_case(case["argv"][0], ImustationError)
            if isinstance(code, BaseException):
                tb, code = "".join(traceback.format_exception(code)), 1
        else:
            res = CliRunner().invoke(cli, case["argv"])
            code, err = res.exit_code, res.stderr
            if res.exception is not None and not isinstance(res.exception, SystemExit):
                tb = "".join(traceback.format_exception(res.exception))
        out.write(json.dumps({"code": code, "stderr": err[-4000:], "traceback": tb}) + "\n")
        out.flush()


def _monitor_case(path: str, expected: type) -> tuple:
    """The monitor's file side: start on the file, poll it, compute the curves (no server)."""
    from imustation.monitor.watcher import Monitor

    try:
        mon = Monitor(path, poll_s=0.1, allan_every_s=0.1, model_after_s=1e9)
        mon.poll()
        mon.analyse(fit=False)
    except expected as exc:
        return 2, f"imustation: error: {exc}\n"
    except Exception as exc:  # noqa: BLE001 - reported as the traceback it is
        return exc, ""
    return 0, ""


class _Worker:
    def __init__(self) -> None:
        env = {**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONFAULTHANDLER": "1"}
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--worker"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL, text=True, env=env, start_new_session=True,
        )  # fmt: skip

    def run(self, case: Case, limit_s: float) -> dict | None:
        """The worker's answer, or None when it gave none within ``limit_s`` (then it is killed)."""
        self.proc.stdin.write(json.dumps({"argv": list(case.argv), "kind": case.kind}) + "\n")
        self.proc.stdin.flush()
        ready, _, _ = select.select([self.proc.stdout], [], [], limit_s)
        line = self.proc.stdout.readline() if ready else ""
        if not line:
            self.kill()
            return None
        return json.loads(line)

    def kill(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()


def verdict(case: Case, answer: dict | None, limit_s: float) -> str | None:
    """Why ``case`` failed, or None."""
    if answer is None:
        return f"no answer within {limit_s:g} s (hang or crash)"
    if answer["traceback"]:
        return "traceback: " + answer["traceback"].strip().splitlines()[-1][:300]
    errors = [ln for ln in answer["stderr"].splitlines() if ln.startswith("imustation: error: ")]
    if answer["code"] not in (0, 2) or (answer["code"] == 2 and len(errors) != 1):
        return f"exit {answer['code']} with {len(errors)} error lines: {answer['stderr'][-300:]!r}"
    if case.expect == "invalid" and answer["code"] != 2:
        return "exit 0 on an invalid input"
    return None


def run_cases(cases: list[Case], limit_s: float = 120.0, log=None, workers: int = 2) -> list[tuple[Case, str]]:
    """Run every case on ``workers`` worker processes side by side (each case is independent; the default
    suite runs this on a 2-CPU machine); returns (case, reason) of those that failed, in corpus order (also
    written to ``log`` as they come)."""
    todo = list(enumerate(cases))
    failures: list[tuple[int, Case, str]] = []
    lock = threading.Lock()

    def serve() -> None:
        worker = _Worker()
        try:
            while True:
                with lock:
                    if not todo:
                        return
                    k, case = todo.pop(0)
                answer = worker.run(case, limit_s)
                why = verdict(case, answer, limit_s)
                if why:
                    with lock:
                        failures.append((k, case, why))
                        if log is not None:
                            print(f"FAIL {case.name}: {why}", file=log, flush=True)
                if answer is None:
                    worker = _Worker()
        finally:
            worker.kill()

    threads = [threading.Thread(target=serve) for _ in range(max(1, workers))]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return [(case, why) for _, case, why in sorted(failures, key=lambda f: f[0])]


def main() -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--size", choices=("small", "large"), default="small")
    ap.add_argument("--dir", default=None)
    ap.add_argument("--limit", type=float, default=120.0)
    ap.add_argument("--worker", action="store_true")
    args = ap.parse_args()
    if args.worker:
        _worker()
        return
    import tempfile

    folder = Path(args.dir or tempfile.mkdtemp(prefix="fuzz-"))
    cases = build_corpus(folder, args.seed, args.size)
    t0 = time.monotonic()
    failures = run_cases(cases, args.limit, log=sys.stdout)
    print(f"{len(cases)} cases, {len(failures)} failures, {time.monotonic() - t0:.0f} s, corpus in {folder}")


if __name__ == "__main__":
    main()
