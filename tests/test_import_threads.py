"""ROS 1 chunks decompressed in threads ahead of the reading thread (acquisition/importers/ros1chunks.py):
the same messages in the same order as the serial path, bounded batches in flight, a damaged chunk named."""

from __future__ import annotations

import numpy as np
import pytest
from bagmaker import write_big_imu_bag
from click.testing import CliRunner
from rosbags.rosbag1 import Reader
from test_bad_input import assert_one_line_error

from imustation.acquisition.importers import ros1chunks
from imustation.acquisition.importers.bags import iter_bag
from imustation.acquisition.importers.rosbag1 import Ros1Bag
from imustation.cli import cli

TOPICS = ("/imu/data", "/imu/b")


def _read_all(path, topics):
    got = {t: [] for t in topics}
    for t, blk in iter_bag(str(path), list(topics), block=1000, reader="new"):
        got[t].append(blk)
    return {t: tuple(np.concatenate(x) for x in zip(*v, strict=True)) for t, v in got.items()}


def _chunk_starts(src) -> list[int]:
    with Reader(src) as r:
        return [c.pos for c in r.chunk_infos]


@pytest.mark.parametrize("compression", ["bz2", "lz4"])
@pytest.mark.parametrize("chunk_bytes", [1, 4000])
def test_threaded_chunks_equal_the_serial_path_in_order(tmp_path, monkeypatch, compression, chunk_bytes):
    """Many small batches decompressed by 3 threads, 2 batches ahead (lz4 threaded too, as bz2 is): every
    message of two interleaved topics, in the order the serial path and rosbags give."""
    src = write_big_imu_bag(tmp_path / "b.bag", 600, compression=compression, chunk_bytes=chunk_bytes,
                            topics=TOPICS, temp_every=7)  # fmt: skip
    monkeypatch.setattr(ros1chunks, "BATCH_BYTES", 3000)
    monkeypatch.setattr(ros1chunks, "WORKERS", 1)
    serial = _read_all(src, TOPICS)
    monkeypatch.setattr(ros1chunks, "WORKERS", 3)
    monkeypatch.setattr(ros1chunks, "THREADED", frozenset({"bz2", "lz4"}))
    threaded = _read_all(src, TOPICS)
    ref = {}
    for t in TOPICS:
        got = [blk for tp, blk in iter_bag(str(src), [t], block=1000, reader="old") if tp == t]
        ref[t] = tuple(np.concatenate(x) for x in zip(*got, strict=True))
    for t in TOPICS:
        assert len(threaded[t][0]) == 600
        for x, y, z in zip(threaded[t], serial[t], ref[t], strict=True):
            np.testing.assert_array_equal(x, y)
            np.testing.assert_array_equal(x, z)


def test_threaded_batches_in_flight_are_bounded_and_closing_early_stops(tmp_path, monkeypatch):
    """At most AHEAD + 1 batches are decompressed and not yet handed out; a reader closed after its first
    batch (an import with a message limit) returns at once."""
    src = write_big_imu_bag(tmp_path / "b.bag", 800, compression="bz2", chunk_bytes=1)
    monkeypatch.setattr(ros1chunks, "BATCH_BYTES", 2000)
    monkeypatch.setattr(ros1chunks, "WORKERS", 2)
    started = []
    real = ros1chunks._decompress_all

    def counted(*args):
        started.append(1)
        return real(*args)

    monkeypatch.setattr(ros1chunks, "_decompress_all", counted)
    with Ros1Bag(str(src)) as bag:
        bag.index()
        handed = 0
        for ch in bag.chunks({}):
            handed += 1
            assert len(started) - handed <= ros1chunks.AHEAD, (len(started), handed)
            assert len(ch.conn)
        assert handed > 50 and bag.messages_read == 800
        before = len(started)
        early = bag.chunks({})
        next(early)
        early.close()
        assert len(started) - before <= ros1chunks.AHEAD + 1  # nothing started after closing


@pytest.mark.parametrize("workers", [1, 2])
def test_a_damaged_bz2_chunk_in_a_threaded_batch_fails_in_one_line_naming_it(tmp_path, monkeypatch, workers):
    """A one-message bz2 chunk whose compressed data is damaged, in the middle of a batch decompressed in a
    thread: one line naming the chunk's offset in the file, exit 2, as in the serial path."""
    src = write_big_imu_bag(tmp_path / "b.bag", 600, compression="bz2", chunk_bytes=1)
    monkeypatch.setattr(ros1chunks, "BATCH_BYTES", 20_000)
    monkeypatch.setattr(ros1chunks, "WORKERS", workers)
    data = src.read_bytes()
    at = _chunk_starts(src)[400]
    hl = int.from_bytes(data[at : at + 4], "little")
    dmg = bytearray(data)
    dmg[at + 8 + hl + 30] ^= 0xFF  # inside the bz2 stream of that chunk
    bad = tmp_path / "damaged.bag"
    bad.write_bytes(bytes(dmg))
    res = CliRunner().invoke(cli, ["import", str(bad), "-o", str(tmp_path / "o.h5")])
    assert_one_line_error(res, "damaged.bag", f"chunk at byte {at}")


def test_an_uncompressed_chunk_of_another_size_is_named(tmp_path):
    """An uncompressed chunk whose header states a size other than its data's: one line naming it."""
    src = write_big_imu_bag(tmp_path / "b.bag", 300, chunk_bytes=1)
    data = src.read_bytes()
    at = _chunk_starts(src)[100]
    k = data.index(b"size=", at) + len(b"size=")
    big = bytearray(data)
    big[k : k + 4] = (int.from_bytes(data[k : k + 4], "little") + 3).to_bytes(4, "little")
    bad = tmp_path / "size.bag"
    bad.write_bytes(bytes(big))
    res = CliRunner().invoke(cli, ["import", str(bad), "-o", str(tmp_path / "o.h5")])
    assert_one_line_error(res, "size.bag", f"chunk at byte {at} holds")
