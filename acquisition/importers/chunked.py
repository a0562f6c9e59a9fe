"""What the streaming readers of ROS 1 messages (:class:`.rosbag1.Ros1Bag`, :class:`.mcap1.Mcap1`) share.

Both open one file, check how it starts, and hand out its messages a chunk at a time in file order
(:class:`.ros1records.ChunkMessages`); topics and counts come from an index when the file has a usable
one, else from a scan of every chunk (:meth:`ChunkedFile.scan`).
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import numpy as np

from imustation.acquisition.importers.ros1records import ChunkMessages, Connection


def file_span(fh, start: int, stop: int) -> tuple[bytes, int]:
    """The bytes of the open file ``fh`` from ``start`` to ``stop`` (or to the file's end, if that comes
    first), and the file offset where they start.

    Read, not memory-mapped: a map is a little faster (100k one-message chunks, 59 MB, in a fresh process:
    7-8 ms against 13-18 ms read) but a file cut short by another process while it is mapped kills this
    one with SIGBUS at the next touch of a page past the new end - no message, no file closed - where a
    read only returns fewer bytes, which the readers report in one line."""
    stop = min(stop, os.fstat(fh.fileno()).st_size)
    if stop <= start:
        return b"", start
    fh.seek(start)
    return fh.read(stop - start), start


class ChunkedFile:
    """A file of chunks of ROS 1 messages, open for reading in order; a context manager.

    Subclasses check the file's start in :meth:`_start` (the file open, :attr:`size` known; a failure
    closes it) and hand out its messages in :meth:`chunks`.
    """

    def __init__(self, path: str):
        self.path = str(path)
        self.fh = open(self.path, "rb")  # noqa: SIM115 (closed by close / the context manager)
        try:
            self.size = os.fstat(self.fh.fileno()).st_size
            #: where reading stopped in a file cut short (None: read to its end)
            self.unread_from: int | None = None
            #: chunks and messages read by the last :meth:`chunks`
            self.chunks_read = self.messages_read = 0
            self._start()
        except BaseException:
            self.fh.close()
            raise

    def _start(self) -> None:
        raise NotImplementedError

    def chunks(self, conns: dict[int, Connection] | None = None) -> Iterator[ChunkMessages]:
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.fh.close()

    def scan(self) -> tuple[dict[int, Connection], dict[int, int]]:
        """Connections and message counts per connection id, from every chunk (a file without a usable index)."""
        conns: dict[int, Connection] = {}
        counts: dict[int, int] = {}
        for ch in self.chunks(conns):
            ids, n = np.unique(ch.conn, return_counts=True)
            for i, k in zip(ids.tolist(), n.tolist(), strict=True):
                counts[i] = counts.get(i, 0) + k
        return conns, counts
