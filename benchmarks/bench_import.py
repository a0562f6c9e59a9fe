"""Time and peak memory of `imustation import` on a big bag: rosbags Reader (old) vs streaming reader (new).

Writes a bag of N sensor_msgs/Imu messages at 400 Hz (numpy-built payloads), then imports
it in a fresh process per reader and prints time, messages/s and peak RSS:

    python benchmarks/bench_import.py [-n 2000000] [--format ros1|mcap|sqlite3] [--compression lz4]
                                      [--reader old|new|both] [--keep BAG] [--chunk-bytes 1]
                                      [--versus-large [--topics 2] [--workers 1]] [--lz4-kernel auto|on|off]

``--chunk-bytes 1`` writes one message per chunk (a recorder flushing each message): the streaming
reader finds every chunk of a closed bag from its index and gathers them together (the rates reached
against large chunks: docs/import.md, "Large bags"). ``--versus-large`` writes both (the same N
messages) and prints the one-message-per-chunk rate as a ratio of the large-chunk rate measured in the
same run, with both rates, the load average and the ratio of messages per CPU second (steadier than
wall-clock time on a shared host) (streaming reader only; ``--topics 2``: two Imu topics
interleaved in both; ``--workers 1``: bz2 chunks decompressed in the reading thread, no pool).
``--lz4-kernel on|off``: lz4 chunks through the compiled decoder (:mod:`.lz4frames`) or lz4.frame,
whatever the bag's chunk count (auto: the reader's own choice, :data:`.ros1chunks.LZ4_KERNEL_CHUNKS`).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))


def measure(bag: str, reader: str, workers: str = "", kernel: str = "auto") -> float:
    from imustation.acquisition.importers import import_recording, loop, ros1chunks

    if workers:
        ros1chunks.WORKERS = int(workers)
    ros1chunks.LZ4_KERNEL = {"auto": None, "on": True, "off": False}[kernel]

    if reader == "old":  # the import as it was: rosbags Reader, message-by-message decoding, 2^20-row write buffer
        loop.WRITE_ROWS = 1 << 20

    out = os.path.join(tempfile.mkdtemp(), "bench.h5")
    t0, c0 = time.perf_counter(), time.process_time()
    res = import_recording(bag, out, overwrite=True, bag_reader=reader)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = sum(r.n for r in res.reports.values())
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rate = n / dt
    print(f"{reader:4s} {res.source_format}: {n} messages in {dt:.1f} s ({rate:,.0f} msg/s), "
          f"peak RSS {peak_mb:.0f} MB, CPU {cpu:.3f} s [{n / cpu:,.0f} msg per CPU s]")  # fmt: skip
    return rate
    shutil.rmtree(os.path.dirname(out))


def baseline() -> None:
    import rosbags.highlevel  # noqa: F401  (the imports the import process pays for)

    import imustation.acquisition.importers  # noqa: F401

    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"baseline (python, numpy, h5py, rosbags imported): {peak_mb:.0f} MB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=2_000_000, help="Imu messages (default 2M = 83 min at 400 Hz)")
    ap.add_argument("--format", default="ros1", choices=["ros1", "mcap", "sqlite3"])
    ap.add_argument("--compression", default=None, choices=["bz2", "lz4"], help="ROS1 chunk compression")
    ap.add_argument("--reader", default="both", choices=["old", "new", "both"])
    ap.add_argument("--keep", default=None, help="bag path: reuse it if it exists, else write and keep it")
    ap.add_argument("--chunk-bytes", type=int, default=None, help="ROS1 chunk threshold (1: a message per chunk)")
    ap.add_argument("--versus-large", action="store_true", help="ROS1: one message per chunk vs large chunks")
    ap.add_argument("--repeat", type=int, default=3, help="with --versus-large: imports of each (best taken)")
    ap.add_argument("--topics", type=int, default=1, help="with --versus-large: Imu topics interleaved in the bag")
    ap.add_argument(
        "--workers",
        type=int,
        default=None,
        help="with --versus-large: decompression threads of the ROS1 reader (1: none; default: its own)",
    )
    ap.add_argument(
        "--lz4-kernel",
        default="auto",
        choices=["auto", "on", "off"],
        help="ROS1 lz4 chunks: the compiled decoder (on), lz4.frame (off), or by the bag's chunk count (auto)",
    )
    ap.add_argument("--measure", nargs="+", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--baseline", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.baseline:
        baseline()
        return
    if args.measure:
        measure(*args.measure)
        return
    from bagmaker import write_big_imu_bag

    if args.versus_large:
        versus_large(args.n, args.compression, args.repeat, args.topics, args.workers, args.lz4_kernel)
        return
    tmp = None
    if args.keep:
        bag = args.keep
    else:
        tmp = tempfile.mkdtemp()
        bag = os.path.join(tmp, "big.bag" if args.format == "ros1" else "big")
    if not os.path.exists(bag):
        t0 = time.perf_counter()
        write_big_imu_bag(bag, args.n, fmt=args.format, compression=args.compression, chunk_bytes=args.chunk_bytes)
        print(f"wrote {args.n} Imu messages to {bag} in {time.perf_counter() - t0:.0f} s")
    src = bag
    if args.format == "mcap" and os.path.isdir(bag):
        src = next(os.path.join(bag, f) for f in os.listdir(bag) if f.endswith(".mcap"))
    size = sum(os.path.getsize(os.path.join(r, f)) for r, _, fs in os.walk(bag) for f in fs) if os.path.isdir(bag) \
        else os.path.getsize(bag)  # fmt: skip
    print(f"{src}: {size / 1e6:.0f} MB")
    subprocess.run([sys.executable, __file__, "--baseline"], check=True)
    for reader in ("old", "new") if args.reader == "both" else (args.reader,):
        subprocess.run([sys.executable, __file__, "--measure", src, reader, "", args.lz4_kernel], check=True)
    if tmp:
        shutil.rmtree(tmp)


def versus_large(
    n: int, compression: str | None, repeat: int, topics: int = 1, workers: int | None = None, kernel: str = "auto"
) -> None:
    """Import rate of a one-message-per-chunk bag as a ratio of a large-chunk bag's, interleaved runs.
    ``topics`` > 1: that many Imu topics interleaved (``n`` messages in all), in both bags; ``workers``:
    the reader's decompression threads (:data:`.ros1chunks.WORKERS`), the same for both."""
    from bagmaker import write_big_imu_bag

    tmp = tempfile.mkdtemp()
    bags = {}
    names = tuple(f"/imu/t{j}" for j in range(topics)) if topics > 1 else ("/imu/data",)
    for name, chunk in (("large", None), ("small", 1)):
        bags[name] = os.path.join(tmp, f"{name}.bag")
        write_big_imu_bag(bags[name], n // topics, compression=compression, chunk_bytes=chunk, topics=names)
        print(f"{name} chunks: {n} messages, {os.path.getsize(bags[name]) / 1e6:.0f} MB")
    best = dict.fromkeys(bags, 0.0)
    per_cpu = dict.fromkeys(bags, 0.0)
    for _ in range(repeat):  # interleaved, so a change in the machine's load touches both
        for name, bag in bags.items():
            cmd = [sys.executable, __file__, "--measure", bag, "new", str(workers or ""), kernel]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            rate = float(out.split("(")[1].split(" msg/s")[0].replace(",", ""))
            cpu_rate = float(out.split("[")[1].split(" msg")[0].replace(",", ""))
            best[name] = max(best[name], rate)
            per_cpu[name] = max(per_cpu[name], cpu_rate)
            print(f"  {name}: {rate:,.0f} msg/s, {cpu_rate:,.0f} msg per CPU s")
    # on a shared host the wall-clock rate follows the load; the CPU time spent per message much less
    # (it misses what threads gain in wall-clock time, and counts what they cost)
    print(f"per CPU second: {per_cpu['small'] / per_cpu['large']:.2f} "
          f"({per_cpu['small']:,.0f} / {per_cpu['large']:,.0f} msg per CPU s)")  # fmt: skip
    print(f"one message per chunk / large chunks: {best['small'] / best['large']:.2f} "
          f"({best['small']:,.0f} / {best['large']:,.0f} msg/s, best of {repeat}; load {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores)")  # fmt: skip
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
