"""Where polled data go, and the one message form they travel in between threads and processes.

A :class:`Sink` takes what the station polls: samples, temperature readings, events.
The run file's writer (through the capture's recorder) is the final sink; a reader
thread of the real-clock scheduler and a worker process of a simulated capture
cannot write the file themselves (one writer owns the HDF5 file), so they hand
their calls over as *messages*: :class:`MessageSink` encodes every call as one
tuple and :func:`deliver` replays it on the final sink. The same encoding crosses
a thread queue and a process pipe (tuples of numpy arrays and plain values pickle
cheaply).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np

#: message tags, one per sink call (plus ERROR: a producer failed; the consumer re-raises)
APPEND, TEMPERATURE, EVENT, ERROR = "append", "temperature", "event", "error"


class Sink(Protocol):
    """Where polled data go: the run-file recorder, or a :class:`MessageSink` towards it.

    ``t_ns``: station time of every sample/reading (int64 ns since the start);
    ``channels``: raw counts per channel name; ``counter``: the device's sample
    counter or None; ``lost``: samples an event says were lost.
    """

    def append(
        self, device: str, t_ns: np.ndarray, channels: Mapping[str, np.ndarray], counter: np.ndarray | None
    ) -> None: ...

    def append_temperature(self, name: str, t_ns: np.ndarray, celsius: np.ndarray) -> None: ...

    def event(self, t_ns: int, source: str, kind: str, detail: str = "", lost: int = 0) -> None: ...


class MessageSink:
    """A sink that encodes every call as one message tuple and hands it to ``put``.

    ``put``: e.g. ``queue.SimpleQueue.put`` (a reader thread) or ``list.append``
    (a worker process batching for its pipe).
    """

    def __init__(self, put: Callable[[tuple], Any]):
        self._put = put

    def append(
        self, device: str, t_ns: np.ndarray, channels: Mapping[str, np.ndarray], counter: np.ndarray | None
    ) -> None:
        self._put((APPEND, device, t_ns, dict(channels), counter))

    def append_temperature(self, name: str, t_ns: np.ndarray, celsius: np.ndarray) -> None:
        self._put((TEMPERATURE, name, t_ns, celsius))

    def event(self, t_ns: int, source: str, kind: str, detail: str = "", lost: int = 0) -> None:
        self._put((EVENT, t_ns, source, kind, detail, lost))

    def error(self, exc: BaseException) -> None:
        """The producer failed: :func:`deliver` raises ``exc`` on the consumer's side."""
        self._put((ERROR, exc))


def deliver(sink: Sink, message: tuple) -> None:
    """Replay one :class:`MessageSink` message on ``sink`` (an ERROR message raises its exception)."""
    tag = message[0]
    if tag == APPEND:
        sink.append(*message[1:])
    elif tag == TEMPERATURE:
        sink.append_temperature(*message[1:])
    elif tag == EVENT:
        sink.event(*message[1:])
    elif tag == ERROR:
        raise message[1]
    else:
        raise ValueError(f"unknown sink message {tag!r}")


def shifted(message: tuple, offset_ns: int) -> tuple:
    """A sink message with its times moved by ``offset_ns`` (a reader's origin onto the run's)."""
    tag = message[0]
    if tag in (APPEND, TEMPERATURE):
        return (tag, message[1], message[2] + offset_ns, *message[3:])
    if tag == EVENT:
        return (tag, message[1] + offset_ns, *message[2:])
    return message


def tick_of(recorder: Any) -> Callable[[int], None] | None:
    """The recorder's between-polls hook: its ``tick(t_ns)``, or a plain run-file writer's ``flush_if_due``."""
    tick = getattr(recorder, "tick", None)
    if tick is None and hasattr(recorder, "flush_if_due"):
        return lambda t_ns: recorder.flush_if_due()
    return tick
