"""Serial ports (``serial:/dev/ttyUSB0?baud=38400``) through pyserial, and a framed-stream reader.

:class:`SerialPort` opens the device with ``serial.serial_for_url`` - the
same call whether the target is a real tty or the simulated
``imusim://<name>`` port (a pyserial URL handler in
``imustation.drivers.sim.serial_handlers``), so simulation runs this code
unchanged. Reads never block: each poll takes what the port holds. pyserial
errors become :class:`~imustation.errors.BusClosed` (the adapter vanished) or
:class:`~imustation.errors.BusError` with one-line messages; after a loss the
port is reopened by :meth:`SerialPort.ensure_open`.

:class:`FramedStreamReader` keeps the bytes between polls and lets a protocol
split them into frames, counting the bytes it had to skip to resynchronise
(garbage, partial frames, dropped bytes).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from imustation.drivers.bus.url import BusURL, parse_bus_url
from imustation.errors import BusClosed, BusError

#: pyserial read size cap per poll (a poll never needs more)
MAX_READ = 1 << 20
#: unread input a Linux tty keeps without flow control (n_tty's N_TTY_BUF_SIZE); what arrives beyond it is
#: dropped without a word (a USB-serial adapter adds a few hundred bytes of its own FIFO, not counted)
TTY_INPUT_BYTES = 4096
BAUD_RATES = (
    1200, 2400, 4800, 9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200,
    230400, 460800, 921600, 2000000, 3686400, 4000000,
)  # fmt: skip


class SerialPort:
    """One serial device.

    Parameters
    ----------
    url : ``serial:DEVICE?baud=N`` (``DEVICE`` a tty path or any pyserial URL).
    baud_default : used when the URL has no ``baud``.
    sim_url : open this pyserial URL instead of ``DEVICE`` (simulation), keeping ``where``.
    """

    def __init__(self, url: str | BusURL, *, baud_default: int, sim_url: str | None = None):
        parsed = url if isinstance(url, BusURL) else parse_bus_url(url, ("serial",))
        parsed.check_params(("baud",))
        if not parsed.target:
            raise BusError(f"bus {parsed.text!r}: expected serial:/dev/ttyUSB0?baud=N")
        self.url = parsed
        self.device = parsed.target
        self.baud = parsed.int_param("baud", baud_default, 1, 100_000_000)
        if self.baud not in BAUD_RATES:
            raise BusError(
                f"bus {parsed.text!r}: baud={self.baud} not a standard rate ({', '.join(map(str, BAUD_RATES))})"
            )
        self.where = f"serial:{self.device}"
        self._open_url = sim_url or self.device
        self._port: Any = None

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def ensure_open(self) -> None:
        """Open the port (8N1, no flow control, non-blocking reads) if it is not open."""
        if self._port is not None:
            return
        import serial

        try:
            self._port = serial.serial_for_url(
                self._open_url, baudrate=self.baud, bytesize=8, parity="N", stopbits=1, timeout=0, write_timeout=1.0
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise BusClosed(f"{self.where}: cannot open at {self.baud} baud: {exc}") from exc

    def _lost(self, what: str, exc: Exception) -> BusClosed:
        self.close()
        return BusClosed(f"{self.where}: port lost during {what}: {exc}")

    def read_available(self) -> bytes:
        """Every byte received since the last call (possibly none)."""
        import serial

        self.ensure_open()
        try:
            n = self._port.in_waiting
            return bytes(self._port.read(min(n, MAX_READ))) if n else b""
        except (serial.SerialException, OSError) as exc:
            raise self._lost("read", exc) from exc

    def write(self, data: bytes) -> None:
        import serial

        self.ensure_open()
        try:
            self._port.write(data)
        except serial.SerialTimeoutException as exc:
            raise BusError(f"{self.where}: write of {len(data)} bytes timed out") from exc
        except (serial.SerialException, OSError) as exc:
            raise self._lost("write", exc) from exc

    def close(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except Exception:  # noqa: BLE001 - the port may already be gone
                pass
            self._port = None


@dataclass
class Scan:
    """What one pass over the buffered bytes found."""

    frames: Any
    #: bytes skipped to resynchronise (garbage, partial or damaged frames)
    garbage: int = 0
    #: frames whose framing was right but whose checksum was wrong
    bad_checksums: int = 0
    extra: dict[str, Any] = field(default_factory=dict)


class FramedStreamReader:
    """Bytes in, frames out, across polls.

    Subclasses implement :meth:`scan`: given the buffered bytes, return the
    frames found, and how many leading bytes are done with (frames and the
    garbage between them); the rest - a frame still arriving - is kept for the
    next call. ``max_pending`` bounds the kept bytes so a stream of garbage
    cannot grow the buffer.
    """

    def __init__(self, max_pending: int = 4096):
        self._buf = b""
        self.max_pending = max_pending
        #: totals since creation (health figures)
        self.garbage_bytes = 0
        self.bad_checksums = 0

    def scan(self, buf: bytes) -> tuple[Scan, int]:
        """Return ``(scan, consumed)`` for ``buf``."""
        raise NotImplementedError

    def feed(self, data: bytes) -> Scan:
        buf = self._buf + data if self._buf else data
        result, consumed = self.scan(buf)
        rest = buf[consumed:]
        if len(rest) > self.max_pending:
            result.garbage += len(rest) - self.max_pending
            rest = rest[-self.max_pending :]
        self._buf = rest
        self.garbage_bytes += result.garbage
        self.bad_checksums += result.bad_checksums
        return result

    def reset(self) -> None:
        self._buf = b""
