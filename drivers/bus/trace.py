"""Bus traces: record every transaction a driver makes, and replay them to the driver.

``capture --trace FILE`` wraps each device's transport (the I2C register
device, the SPI device or the serial port) in a :class:`TracingTransport` that
writes every call and its answer to a JSON-lines file. ``capture --replay
FILE`` gives each driver a :class:`ReplayTransport` instead, which answers
from the trace in order and checks that the driver asks exactly what it asked
when the trace was made. A capture from real hardware thereby becomes a
regression test of the driver code, with no hardware.

File format (one JSON object per line)::

    {"format": "imustation-trace", "version": 1}
    {"device": "bmx055", "kind": "i2c", "attrs": {"where": "i2c:1@0x68"}}
    {"d": "bmx055", "m": "read", "a": [8, 9], "r": {"b": "1b00..."}}
    {"d": "adis", "m": "transfer", "a": [{"b": "3e00"}], "e": ["BusTimeout", "..."]}

Bytes are written as ``{"b": hex}``; ``r`` is the answer, ``e`` a raised error
(class name in :mod:`imustation.errors` and message), re-raised on replay;
``dt`` the station-clock nanoseconds the call took (bus time, stall delays),
slept again on replay so that timestamps come out the same.
"""

from __future__ import annotations

import json
import os
import threading
from collections import defaultdict, deque
from collections.abc import Callable, Iterable
from typing import Any, ClassVar

from imustation import errors
from imustation.clock import Clock
from imustation.errors import BusClosed, BusError, InputError

TRACE_FORMAT = "imustation-trace"
TRACE_VERSION = 1

#: per bus kind: the traced methods, and the static attributes drivers read
METHODS: dict[str, tuple[str, ...]] = {
    "i2c": ("read", "write"),
    "spi": ("transfer", "transfer_frames", "ensure_open", "close"),
    "serial": ("read_available", "write", "ensure_open", "close"),
}
ATTRS: dict[str, tuple[str, ...]] = {"i2c": ("where",), "spi": ("where", "hz"), "serial": ("where", "baud")}


class TraceMismatch(BusError):
    """The driver asked something else than the trace holds at this point."""


class TraceEnded(BusClosed):
    """The driver asked for more than the trace holds."""


def _encode(value: Any) -> Any:
    if isinstance(value, (bytes, bytearray, memoryview)):
        return {"b": bytes(value).hex()}
    if isinstance(value, (list, tuple)):
        return [_encode(v) for v in value]
    return value


def _decode(value: Any) -> Any:
    if isinstance(value, dict) and set(value) == {"b"}:
        return bytes.fromhex(value["b"])
    if isinstance(value, list):
        return [_decode(v) for v in value]
    return value


class TraceWriter:
    """Append-only JSON-lines trace file shared by the traced transports (thread-safe)."""

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        try:
            self._fh = open(self.path, "x", encoding="utf-8")  # noqa: SIM115 - closed by close()
        except FileExistsError:
            raise InputError(f"{self.path}: trace file exists; choose another name") from None
        self._lock = threading.Lock()
        self.write({"format": TRACE_FORMAT, "version": TRACE_VERSION})

    def write(self, record: dict) -> None:
        line = json.dumps(record, separators=(",", ":"))
        with self._lock:
            self._fh.write(line + "\n")

    def close(self) -> None:
        with self._lock:
            self._fh.close()


class _RMW:
    """``update_bits`` for register transports, through their own read/write (so it is traced)."""

    def update_bits(self, reg: int, mask: int, value: int) -> None:
        old = self.read(reg, 1)[0]  # type: ignore[attr-defined]
        new = (old & ~mask) | (value & mask)
        if new != old:
            self.write(reg, bytes([new]))  # type: ignore[attr-defined]


class TracingTransport(_RMW):
    """Forwards the transport's calls to ``inner`` and writes each call and answer to the trace."""

    def __init__(self, inner: Any, kind: str, device: str, writer: TraceWriter, clock: Clock):
        self._inner, self._kind, self._device, self._writer = inner, kind, device, writer
        self._clock = clock
        attrs = {a: getattr(inner, a) for a in ATTRS[kind] if hasattr(inner, a)}
        writer.write({"device": device, "kind": kind, "attrs": attrs})
        for method in METHODS[kind]:
            setattr(self, method, self._traced(method))

    def _traced(self, method: str) -> Callable:
        target = getattr(self._inner, method)

        def call(*args: Any) -> Any:
            record: dict[str, Any] = {"d": self._device, "m": method, "a": _encode(args)}
            t0 = self._clock.now_ns()
            try:
                result = target(*args)
            except errors.ImustationError as exc:
                record["e"] = [type(exc).__name__, str(exc)]
                raise
            else:
                record["r"] = _encode(result)
            finally:
                dt = self._clock.now_ns() - t0
                if dt:
                    record["dt"] = dt
                self._writer.write(record)
            return result

        return call

    def __getattr__(self, name: str) -> Any:  # static attributes (where, baud, hz, ...)
        return getattr(self._inner, name)


class ReplayTransport(_RMW):
    """Answers a driver from a trace, in order, checking every call against it."""

    ERRORS: ClassVar[dict[str, type]] = {
        name: cls
        for name, cls in vars(errors).items()
        if isinstance(cls, type) and issubclass(cls, errors.ImustationError)
    }

    def __init__(self, path: str, device: str, kind: str, attrs: dict, records: deque, clock: Clock):
        self._path, self._device, self._records = path, device, records
        self._clock = clock
        self._count = 0
        for key, value in attrs.items():
            setattr(self, key, value)
        for method in METHODS[kind]:
            setattr(self, method, self._replayed(method))

    def _replayed(self, method: str) -> Callable:
        def call(*args: Any) -> Any:
            self._count += 1
            asked = f"{method}{tuple(_encode(args))}"
            if not self._records:
                raise TraceEnded(f"{self._path}: trace of {self._device} ended after {self._count - 1} calls")
            rec = self._records.popleft()
            if rec["m"] != method or rec["a"] != _encode(list(args)):
                raise TraceMismatch(
                    f"{self._path}: {self._device} call {self._count}: trace has "
                    f"{rec['m']}{tuple(rec['a'])}, driver asked {asked}"
                )
            if rec.get("dt"):
                self._clock.sleep(rec["dt"] / 1e9)
            if "e" in rec:
                cls = self.ERRORS.get(rec["e"][0], BusError)
                raise cls(rec["e"][1])
            return _decode(rec["r"])

        return call


class Trace:
    """A trace file read into per-device record queues (for :class:`ReplayTransport`)."""

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        self.devices: dict[str, tuple[str, dict]] = {}
        self._records: dict[str, deque] = defaultdict(deque)
        try:
            with open(self.path, encoding="utf-8") as fh:
                lines: Iterable[str] = fh.readlines()
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read trace ({exc.strerror})") from None
        for i, line in enumerate(lines, 1):
            try:
                rec = json.loads(line)
            except ValueError:
                raise InputError(f"{self.path}: line {i} is not JSON") from None
            if i == 1:
                if rec.get("format") != TRACE_FORMAT or rec.get("version") != TRACE_VERSION:
                    raise InputError(f"{self.path}: not an imustation trace (v{TRACE_VERSION})")
            elif "device" in rec:
                self.devices[rec["device"]] = (rec["kind"], rec.get("attrs", {}))
            else:
                self._records[rec["d"]].append(rec)

    def transport(self, device: str, kind: str, clock: Clock) -> ReplayTransport:
        if device not in self.devices:
            known = ", ".join(sorted(self.devices)) or "none"
            raise InputError(f"{self.path}: no trace of device {device!r} (traced: {known})")
        traced_kind, attrs = self.devices[device]
        if traced_kind != kind:
            raise InputError(f"{self.path}: {device} was traced on a {traced_kind} bus, config says {kind}")
        return ReplayTransport(self.path, device, kind, attrs, self._records[device], clock)
