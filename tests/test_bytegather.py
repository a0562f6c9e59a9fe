"""The unaligned gathers the bag readers locate records with (:mod:`imustation.acquisition.importers.bytegather`)."""

import numpy as np
import pytest

from imustation.acquisition.importers.bytegather import gather_u32, rows_match


def test_gather_u32_at_any_offset():
    rng = np.random.default_rng(1)
    b = rng.integers(0, 256, 1000, dtype=np.uint8)
    at = np.array([0, 1, 3, 7, 500, 996])
    want = [int.from_bytes(b[a : a + 4].tobytes(), "little") for a in at]
    assert gather_u32(b, at).tolist() == want
    assert gather_u32(b[5:], [0]).tolist() == [int.from_bytes(b[5:9].tobytes(), "little")]
    with pytest.raises(IndexError):
        gather_u32(b, [997])  # its last byte past the end


@pytest.mark.parametrize("k", [3, 8, 13, 41, 108])
def test_rows_match_compares_every_byte_but_the_free_ones(k):
    rng = np.random.default_rng(k)
    row = rng.integers(0, 256, k, dtype=np.uint8)
    free = np.zeros(k, bool)
    free[k // 3 : k // 3 + 2] = True
    stride = k + 5
    b = np.zeros(stride * 40, np.uint8)
    for i in range(40):
        b[i * stride : i * stride + k] = row
    b[2 * stride + k // 3] ^= 0xFF  # a free byte: still a match
    b[5 * stride + k - 1] ^= 0x01  # the last byte
    b[9 * stride] ^= 0x80  # the first byte
    b[11 * stride + (k // 3 + 3) % k] ^= 0x10
    starts = np.arange(40) * stride
    want = np.array([((b[s : s + k] == row) | free).all() for s in starts])
    assert not want[9] and want[2]
    assert (rows_match(b, starts, row.tobytes(), free) == want).all()
    assert (rows_match(b, range(0, 40 * stride, stride), row.tobytes(), free) == want).all()
    strict = rows_match(b, starts, row.tobytes())
    assert not strict[2] and strict[0]
