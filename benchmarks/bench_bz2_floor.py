"""The floor of one-message bz2 chunks: libbz2's own time per stream, measured from C, against Python's.

Writes the same N Imu messages as two ROS 1 bz2 bags (one message per chunk, and large chunks), takes
every chunk's bz2 stream out of them, and decompresses all the streams of each bag:

* in C (a small program compiled here with gcc, ``BZ2_bzBuffToBuffDecompress`` per stream: libbz2 alone),
* in Python (``bz2.decompress`` per stream: what the importer calls per chunk),

printing CPU microseconds per stream and per message, so the per-stream set-up of libbz2 (its tables
built anew for every stream) is told apart from the importer's overhead:

    python benchmarks/bench_bz2_floor.py [-n 100000] [--repeat 3]

(docs/import.md, "Large bags", gives the figures.) Needs gcc and libbz2's header (``bzlib.h``).
"""

from __future__ import annotations

import argparse
import bz2
import os
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

C_SOURCE = r"""
#include <bzlib.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
/* streams file: repeated (u32 compressed length, u32 decompressed length, bytes); prints CPU seconds */
int main(int argc, char **argv) {
    FILE *f = fopen(argv[1], "rb");
    int repeat = atoi(argv[2]);
    fseek(f, 0, SEEK_END); long n = ftell(f); fseek(f, 0, SEEK_SET);
    char *buf = malloc(n); if (fread(buf, 1, n, f) != (size_t)n) return 3; fclose(f);
    char *out = malloc(64 << 20);
    double best = 1e9; long streams = 0;
    for (int r = 0; r < repeat; r++) {
        struct timespec a, b; clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &a);
        streams = 0;
        for (long p = 0; p < n;) {
            unsigned int cl = *(unsigned int *)(buf + p), dl = *(unsigned int *)(buf + p + 4);
            unsigned int got = 64 << 20;
            if (BZ2_bzBuffToBuffDecompress(out, &got, buf + p + 8, cl, 0, 0) != BZ_OK || got != dl) return 2;
            p += 8 + cl; streams++;
        }
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &b);
        double s = (b.tv_sec - a.tv_sec) + 1e-9 * (b.tv_nsec - a.tv_nsec);
        if (s < best) best = s;
    }
    printf("%ld %.6f\n", streams, best);
    return 0;
}
"""


def streams_of(bag: str) -> list[tuple[bytes, int]]:
    """Every chunk's compressed data and decompressed size, from the bag's index."""
    from rosbags.rosbag1 import Reader

    from imustation.acquisition.importers.ros1records import int_field, parse_fields

    with Reader(bag) as r:
        pos = [c.pos for c in r.chunk_infos]
    data = open(bag, "rb").read()  # noqa: SIM115 (a benchmark's one read)
    out = []
    for p in pos:
        hl = int.from_bytes(data[p : p + 4], "little")
        size = int_field(parse_fields(data, p + 4, p + 4 + hl), "size")
        dl = int.from_bytes(data[p + 4 + hl : p + 8 + hl], "little")
        out.append((data[p + 8 + hl : p + 8 + hl + dl], size))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=100_000, help="Imu messages in each bag")
    ap.add_argument("--repeat", type=int, default=3, help="passes over the streams (best taken)")
    args = ap.parse_args()
    from bagmaker import write_big_imu_bag

    tmp = tempfile.mkdtemp()
    try:
        exe = os.path.join(tmp, "bz2floor")
        src = os.path.join(tmp, "bz2floor.c")
        with open(src, "w") as f:
            f.write(C_SOURCE)
        subprocess.run(["gcc", "-O2", "-o", exe, src, "-lbz2"], check=True)
        for name, chunk in (("one message per chunk", 1), ("large chunks", None)):
            bag = os.path.join(tmp, "b.bag")
            write_big_imu_bag(bag, args.n, compression="bz2", chunk_bytes=chunk)
            streams = streams_of(bag)
            path = os.path.join(tmp, "streams")
            with open(path, "wb") as f:
                for raw, size in streams:
                    f.write(len(raw).to_bytes(4, "little") + size.to_bytes(4, "little") + raw)
            out = subprocess.run([exe, path, str(args.repeat)], check=True, capture_output=True, text=True).stdout
            k, c_s = out.split()
            py_s = 1e9
            raws = [raw for raw, _ in streams]
            for _ in range(args.repeat):
                t0 = time.process_time()
                for raw in raws:
                    bz2.decompress(raw)
                py_s = min(py_s, time.process_time() - t0)
            c_s = float(c_s)
            print(f"{name}: {k} streams, {args.n} messages, {sum(map(len, raws)) / 1e6:.1f} MB compressed")
            print(f"  libbz2 from C:           {c_s:.3f} s CPU, {1e6 * c_s / int(k):8.2f} us per stream, "
                  f"{1e6 * c_s / args.n:.2f} us per message")  # fmt: skip
            print(f"  bz2.decompress (Python): {py_s:.3f} s CPU, {1e6 * py_s / int(k):8.2f} us per stream, "
                  f"{1e6 * py_s / args.n:.2f} us per message")  # fmt: skip
            os.remove(bag)
    finally:
        shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
