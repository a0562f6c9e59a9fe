"""pyserial handler of ``imusim://<name>``: a port whose far end is a device simulator.

Bytes reach the host no faster than the line carries them (baud / 10 bytes
per second on the station clock, 8N1); a device simulator with a fixed baud
rate gives unusable bytes to a port opened at another rate. While the device's
``disconnect`` fault is active the port behaves as an unplugged USB-serial
adapter: reads and writes fail, and reopening fails until it returns.

The host side is modelled too: the kernel keeps at most ``TTY_BUFFER_BYTES`` of
unread input (no flow control: what arrives beyond is dropped), and the device's
``stall`` / ``slow`` faults make the host's read late (a busy or stalled host), so
a long stall loses bytes as it does on a real tty.
"""

from __future__ import annotations

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from imustation.drivers.bus.serial_port import TTY_INPUT_BYTES
from imustation.drivers.sim.serial_handlers import DEVICES, SCHEME

BITS_PER_BYTE = 10  # 8N1: start + 8 data + stop
#: unread input a Linux tty keeps (the host side the drivers count on)
TTY_BUFFER_BYTES = TTY_INPUT_BYTES


class Serial(SerialBase):
    """Simulated port (pyserial ``SerialBase`` interface)."""

    def open(self) -> None:
        if self.is_open:
            raise SerialException("port already open")
        url = str(self.port)
        prefix = f"{SCHEME}://"
        if not url.lower().startswith(prefix):
            raise SerialException(f"expected a URL {prefix}<name>, got {url!r}")
        name = url[len(prefix) :].split("?", 1)[0]
        device = DEVICES.get(name)
        if device is None:
            raise SerialException(f"could not open port {url!r}: no simulated device {name!r}")
        if device.unplugged():
            raise SerialException(f"could not open port {url!r}: [Errno 2] No such file or directory")
        self.device = device
        device.produce()  # what the device sent while no port was open is lost
        self._line = bytearray()
        self._credit = 0.0
        #: bytes dropped because the host's buffer was full (test back door)
        self.sim_dropped = 0
        self._t_ns = device.clock.now_ns()
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def _reconfigure_port(self) -> None:
        """Baud rate etc. live in SerialBase; nothing to push to a simulated line."""

    def _check(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        if self.device.unplugged():
            raise SerialException("device reports readiness to read but returned no data (device disconnected?)")

    def _pull(self) -> None:
        now = self.device.clock.now_ns()
        self._line += self.device.produce()
        self._credit = min(self._credit + (now - self._t_ns) * 1e-9 * self.baudrate / BITS_PER_BYTE, 1e9)
        self._t_ns = now
        arrived = min(len(self._line), int(self._credit))
        if arrived > TTY_BUFFER_BYTES:
            # the host's buffer filled up while nobody read: the rest of what arrived is lost
            drop = arrived - TTY_BUFFER_BYTES
            del self._line[TTY_BUFFER_BYTES:arrived]
            self._credit -= drop
            self.sim_dropped += drop

    def _host_late(self) -> None:
        """The device's ``stall`` / ``slow`` faults: this read call returns late."""
        plan = self.device.plan
        if plan is not None:
            late = (plan.fire_duration("stall") or 0.0) + plan.delay_s("slow")
            if late:
                self.device.clock.sleep(late)

    @property
    def in_waiting(self) -> int:
        self._check()
        self._host_late()
        self._pull()
        return min(len(self._line), int(self._credit))

    def read(self, size: int = 1) -> bytes:
        self._check()
        self._pull()
        n = min(size, len(self._line), int(self._credit))
        out = bytes(self._line[:n])
        del self._line[:n]
        self._credit -= n
        fixed = self.device.baud
        if fixed is not None and fixed != self.baudrate:
            # a receiver at the wrong rate samples the wrong bits
            out = bytes((b * 37 + 11) & 0xFF for b in out)
        return out

    def write(self, data) -> int:
        self._check()
        data = bytes(data)
        self.device.receive(data)
        return len(data)

    def reset_input_buffer(self) -> None:
        self._check()
        self._pull()
        self._line.clear()

    def reset_output_buffer(self) -> None:
        self._check()
