"""The compiled LZ4 frame decoder (acquisition/importers/lz4frames.py) against the lz4 package, the reference:
byte for byte on the frames lz4.frame writes in every combination of its options, and a status for every
frame that breaks the format (docs/reference/lz4-frame.md). The first test in a session compiles the kernels
when numba's cache has none (~5 s once); each test after takes well under a second."""

from __future__ import annotations

import itertools

import lz4.frame as F
import numpy as np
import pytest

from imustation.acquisition.importers.lz4frames import PROBLEMS, decode_frames, xxh32

BLOCKS = (F.BLOCKSIZE_MAX64KB, F.BLOCKSIZE_MAX256KB, F.BLOCKSIZE_MAX1MB, F.BLOCKSIZE_MAX4MB)


def _content(n: int, seed: int) -> bytes:
    """Messages of a recorder: repeated records with noise (compressible), with incompressible stretches."""
    rng = np.random.default_rng(seed)
    rec = rng.integers(0, 256, 400, dtype=np.uint8).tobytes()
    out = bytearray()
    while len(out) < n:
        noise = rng.integers(0, 256, int(rng.integers(0, 60)), dtype=np.uint8).tobytes()
        out += rec[: int(rng.integers(40, 400))] + noise
        if rng.random() < 0.05:
            out += b"\x07" * int(rng.integers(1, 3000))  # a long run: overlapping matches, length bytes of 255
    return bytes(out[:n])


def _decode(frames: list[bytes], sizes: list[int]):
    src = np.frombuffer(b"".join(frames), np.uint8)
    lens = np.array([len(f) for f in frames], np.int64)
    ends = np.cumsum(lens)
    return decode_frames(src, ends - lens, ends, np.array(sizes, np.int64))


def test_xxh32_known_values():
    # the reference values of xxHash32 with seed 0
    assert xxh32(b"") == 0x02CC5D05
    assert xxh32(b"abc") == 0x32D153FF
    assert xxh32(b"Nobody inspects the spammish repetition") == 0xE2293B2F


def test_frames_of_every_option_decode_as_lz4_frame_decompress_does():
    """Content checksum, block checksums, content size, block size 64 KB .. 4 MB, linked and independent
    blocks; empty, one-message, multi-block and incompressible (stored-block) contents; all in one call."""
    frames, want = [], []
    contents = [b"", b"x", _content(361, 1), _content(70_000, 2), _content(300_000, 3)]
    noise = np.random.default_rng(4).integers(0, 256, 100_000, dtype=np.uint8).tobytes()
    contents.append(noise)  # incompressible: stored blocks
    contents.append(noise[:3000] + bytes(20_000) + noise[3000:3700] + b"ab" * 5000)  # literal runs of > 255 bytes
    for data in contents:
        for bs, cc, bc, cs, linked in itertools.product(BLOCKS, *[(False, True)] * 4):
            frames.append(F.compress(data, block_size=bs, content_checksum=cc, block_checksum=bc, store_size=cs,
                                     block_linked=linked))  # fmt: skip
            want.append(data)
    big = _content(4_500_000, 5)  # more than one 1 MB block, and one 4 MB block and a rest
    for bs, linked in itertools.product(BLOCKS[2:], (False, True)):
        frames.append(F.compress(big, block_size=bs, content_checksum=True, block_checksum=True, block_linked=linked))
        want.append(big)
    out, status, got = _decode(frames, [len(w) for w in want])
    assert status.tolist() == [0] * len(frames)
    assert got.tolist() == [len(w) for w in want]
    for f, w in zip(frames, want, strict=True):
        assert F.decompress(f) == w  # the reference agrees with the content
    assert out.tobytes() == b"".join(want)


def _damaged(frame: bytes, at: int, xor: int = 0xFF) -> bytes:
    b = bytearray(frame)
    b[at] ^= xor
    return bytes(b)


def _literal_at(frame: bytes, marker: bytes) -> int:
    """Where a run of incompressible bytes of the content lies in the frame (a literal run)."""
    at = frame.index(marker)
    return at + len(marker) // 2


def test_a_flipped_literal_byte_is_caught_by_the_content_checksum():
    marker = bytes(range(97, 123)) + bytes(range(200, 230))  # no repeats: stored as literals
    data = _content(3000, 6) + marker + _content(3000, 7)
    frame = F.compress(data, content_checksum=True)
    bad = _damaged(frame, _literal_at(frame, marker), 0x01)
    out, status, got = _decode([frame, bad], [len(data)] * 2)
    assert status.tolist() == [0, 12], PROBLEMS[int(status[1])]
    with pytest.raises(RuntimeError):
        F.decompress(bad)  # the reference finds it too
    # without a content checksum the same flip decodes to another content: only the chunk's size is checked
    plain = F.compress(data)
    out, status, got = _decode([_damaged(plain, _literal_at(plain, marker), 0x01)], [len(data)])
    assert status.tolist() == [0] and out.tobytes() != data


def test_a_flipped_byte_is_caught_by_the_block_checksum():
    marker = bytes(range(97, 123)) + bytes(range(200, 230))
    data = _content(3000, 6) + marker
    frame = F.compress(data, block_checksum=True)
    _, status, _ = _decode([_damaged(frame, _literal_at(frame, marker), 0x01)], [len(data)])
    assert status.tolist() == [8]


def test_every_damaged_frame_gets_its_status_never_a_result():
    data = _content(5000, 8)
    frame = F.compress(data, content_checksum=True, store_size=True)
    n = len(data)
    hdr_end = 4 + 2 + 8 + 1  # magic, FLG, BD, content size, header checksum
    block = int.from_bytes(frame[hdr_end : hdr_end + 4], "little")
    cases = {
        "magic": (_damaged(frame, 0), 2),
        "version": (_damaged(frame, 4, 0x80), 3),
        "reserved FLG bit": (_damaged(frame, 4, 0x02), 4),
        "reserved BD bits": (_damaged(frame, 5, 0x01), 4),
        "dictionary": (_damaged(frame, 4, 0x01), 5),
        "header checksum": (_damaged(frame, hdr_end - 1), 6),
        "content size": (_damaged(frame, 6, 0x01), 6),  # covered by the header checksum
        "block over the maximum": (
            frame[:hdr_end] + (block | 0x00100000).to_bytes(4, "little") + frame[hdr_end + 4 :],
            7,
        ),  # fmt: skip
        "block past the frame": (frame[:hdr_end] + (len(frame)).to_bytes(4, "little") + frame[hdr_end + 4 :], 1),
        "cut in the header": (frame[:9], 1),
        "cut in the block": (frame[: hdr_end + 40], 1),
        "no end mark": (frame[:-8], 1),
        "cut in the content checksum": (frame[:-2], 1),
        "content checksum": (_damaged(frame, len(frame) - 1), 12),
        "bytes after the frame": (frame + b"\0", 13),
        "empty": (b"", 1),
    }
    frames = [f for f, _ in cases.values()]
    _, status, _ = _decode(frames, [n] * len(frames))
    assert dict(zip(cases, status.tolist(), strict=True)) == {k: v for k, (_, v) in cases.items()}
    # a frame holding more than its chunk says stops at that size; one holding less says how much
    out, status, got = _decode([frame, frame], [n - 1, n + 1])
    assert status.tolist() == [10, 0] and got.tolist()[1] == n and len(out) == 2 * n


@pytest.mark.parametrize("seed", range(3))
def test_random_damage_never_reads_outside_or_hangs(seed):
    """Random bytes flipped in compressed frames (no checksums): each decodes to some status; the output
    never exceeds the sizes given."""
    rng = np.random.default_rng(seed)
    data = _content(20_000, seed)
    frame = F.compress(data, block_size=F.BLOCKSIZE_MAX64KB)
    frames = []
    for _ in range(300):
        b = bytearray(frame)
        for at in rng.integers(7, len(b), int(rng.integers(1, 4))).tolist():
            b[at] = int(rng.integers(0, 256))
        frames.append(bytes(b))
    out, status, got = _decode(frames, [len(data)] * len(frames))
    assert len(out) == len(data) * len(frames)
    assert set(status.tolist()) <= set(range(14))
    assert (got <= len(data)).all()


@pytest.mark.slow
def test_random_damage_with_numba_bounds_checks(tmp_path):
    """The random-damage and damaged-frame tests again with numba's bounds checks on (a read or write
    outside an array raises IndexError instead of going unseen), compiled afresh in a subprocess."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, NUMBA_BOUNDSCHECK="1", NUMBA_CACHE_DIR=str(tmp_path))
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", __file__, "-k",
                          "random_damage_never or every_damaged or every_option"],
                         env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert res.returncode == 0, res.stdout[-3000:]


def _read(path, topics):
    from imustation.acquisition.importers.bags import iter_bag

    got = {t: [] for t in topics}
    for t, blk in iter_bag(str(path), list(topics), block=1000, reader="new"):
        got[t].append(blk)
    return {t: tuple(np.concatenate(x) for x in zip(*v, strict=True)) for t, v in got.items()}


@pytest.mark.parametrize(
    "chunk_bytes, options",
    [(1, None), (1, {"content_checksum": True, "store_size": False}), (5000, {"block_checksum": True})],
)
def test_lz4_bags_read_the_same_through_the_decoder_and_lz4_frame(tmp_path, monkeypatch, chunk_bytes, options):
    """One message per chunk (rosbags' frames; roslz4's, with a content checksum) and larger chunks, two
    topics interleaved: the same messages in the same order either way, and auto picks the decoder from
    LZ4_KERNEL_CHUNKS chunks on."""
    from bagmaker import write_big_imu_bag

    from imustation.acquisition.importers import lz4frames, ros1chunks

    topics = ("/imu/data", "/imu/b")
    src = write_big_imu_bag(tmp_path / "b.bag", 400, compression="lz4", chunk_bytes=chunk_bytes, topics=topics,
                            lz4_options=options)  # fmt: skip
    monkeypatch.setattr(ros1chunks, "LZ4_KERNEL", False)
    ref = _read(src, topics)
    calls = []
    real = lz4frames.decode_frames
    monkeypatch.setattr(lz4frames, "decode_frames", lambda *a: calls.append(len(a[1])) or real(*a))
    monkeypatch.setattr(ros1chunks, "LZ4_KERNEL", None)
    monkeypatch.setattr(ros1chunks, "LZ4_KERNEL_CHUNKS", 10)
    got = _read(src, topics)
    assert calls and (chunk_bytes != 1 or sum(calls) == 800)  # every one-message chunk through it
    for t in topics:
        assert len(got[t][0]) == 400
        for x, y in zip(got[t], ref[t], strict=True):
            np.testing.assert_array_equal(x, y)
    calls.clear()
    monkeypatch.setattr(ros1chunks, "LZ4_KERNEL_CHUNKS", 10**9)
    _read(src, topics)
    assert not calls  # below the count: lz4.frame


def test_a_flipped_payload_byte_in_a_bag_is_caught_by_the_content_checksum(tmp_path, monkeypatch):
    """A byte of an Imu message's payload flipped inside a one-message lz4 chunk whose frame has a content
    checksum (roslz4's): the frame still parses, its checksum does not match; one line naming the chunk."""
    from bagmaker import roslz4_bag
    from click.testing import CliRunner
    from test_bad_input import assert_one_line_error

    from imustation.acquisition.importers import ros1chunks
    from imustation.cli import cli

    _, data, at, start, dl = roslz4_bag(tmp_path / "b.bag", 300, 200)
    frame = data[start : start + dl]
    size = len(F.decompress(frame))
    # the first byte from the frame's middle whose flip leaves the frame parsing: a literal of the payload
    for k in range(dl // 2, dl - 8):
        _, status, _ = _decode([_damaged(frame, k, 0x01)], [size])
        if status[0] == 12:
            break
    else:
        raise AssertionError("no literal byte found")
    dmg = bytearray(data)
    dmg[start + k] ^= 0x01
    bad = tmp_path / "flipped.bag"
    bad.write_bytes(bytes(dmg))
    monkeypatch.setattr(ros1chunks, "LZ4_KERNEL", True)
    res = CliRunner().invoke(cli, ["import", str(bad), "-o", str(tmp_path / "o.h5")])
    assert_one_line_error(res, "flipped.bag", f"chunk at byte {at}", "content checksum does not match")
