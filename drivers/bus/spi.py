"""SPI seen by chip drivers, and the common part of the pyusb SPI bridges.

:class:`SPIDevice` is what a chip driver gets: full-duplex transfers with the
chip select asserted for each transfer. The bridges (CP2130, MCP2210) subclass
:class:`USBSPIBridge`, which finds the USB device by VID:PID and serial
number, claims its interface, retries timeouts a bounded number of times and
maps pyusb errors to :mod:`imustation.errors` with one-line messages.

Real and simulated bridges run the same code: only the pyusb *backend* differs
(libusb on hardware, :class:`imustation.drivers.sim.usb_backend.SimUSBBackend`
in simulation, which decodes the bridge framing and routes the SPI bytes to a
chip simulator).
"""

from __future__ import annotations

import array
import errno
import time
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, Protocol

from imustation.drivers.bus.url import BusURL, USBTarget, parse_bus_url, parse_usb_target
from imustation.errors import BusClosed, BusError, BusTimeout, DeviceError, SettingError


class SPIDevice(Protocol):
    """One chip on an SPI bus (one chip select).

    ``where`` names it for messages (``"cp2130:10C4:87A0?cs=0"``); ``mode`` is
    the SPI mode 0..3 and ``hz`` the clock actually used.
    """

    where: str
    mode: int
    hz: float

    def transfer(self, tx: bytes) -> bytes:
        """Clock ``tx`` out with CS asserted for the whole transfer; return the bytes clocked in."""
        ...

    def transfer_frames(self, frames: Sequence[bytes], gap_s: float) -> list[bytes]:
        """One CS-asserted transfer per frame, CS high for at least ``gap_s`` seconds between them."""
        ...

    def ensure_open(self) -> None:
        """(Re)open the bridge if it was closed or lost (cable re-plugged)."""
        ...

    def start_event_counter(self, pin: str) -> int:
        """Count the rising edges on the bridge's input ``pin`` from 0 (a chip's data-ready line wired to it);
        return the counter's modulus. Only the USB bridges have one (``docs/reference/bridge-counters.md``)."""
        ...

    def read_event_counter(self) -> int:
        """The edges counted since :meth:`start_event_counter`, modulo its modulus."""
        ...

    def close(self) -> None: ...


#: pyusb/libusb errnos that mean the device is gone (unplugged, re-enumerated)
_GONE = {errno.ENODEV, errno.ENOENT, errno.ESHUTDOWN}
#: default attempts per transfer before an error is raised (as the I2C bus)
DEFAULT_RETRIES = 3
#: default USB transfer timeout, ms
DEFAULT_TIMEOUT_MS = 500


class USBSPIBridge:
    """A USB-to-SPI bridge chip opened through pyusb.

    Parameters
    ----------
    url : ``scheme:[VID:PID][/SERIAL]?cs=N&hz=F`` (see ``docs/buses.md``).
    mode : SPI mode the chip needs (0..3).
    sleep : delay function (the station clock's; virtual in simulation).
    backend : pyusb backend; ``None`` = pyusb's default (libusb).
    """

    NAME: ClassVar[str] = ""
    SCHEME: ClassVar[str] = ""
    DEFAULT_VID: ClassVar[int] = 0
    DEFAULT_PID: ClassVar[int] = 0
    #: number of chip-select lines of the bridge
    N_CS: ClassVar[int] = 1
    MAX_HZ: ClassVar[float] = 12e6
    #: URL query keys the bridge accepts
    PARAMS: ClassVar[tuple[str, ...]] = ("cs", "hz", "retries", "timeout_ms")
    #: the one input pin whose edges the bridge counts (docs/reference/bridge-counters.md)
    COUNTER_PIN: ClassVar[str] = ""
    #: the event counter is 16 bits wide on both bridges
    COUNTER_MODULUS: ClassVar[int] = 1 << 16

    def __init__(self, url: str | BusURL, *, mode: int, sleep=time.sleep, backend: Any = None):
        parsed = url if isinstance(url, BusURL) else parse_bus_url(url, (self.SCHEME,))
        parsed.check_params(self.PARAMS)
        self.url = parsed
        self.target: USBTarget = parse_usb_target(parsed, self.DEFAULT_VID, self.DEFAULT_PID)
        self.cs = parsed.int_param("cs", 0, 0, self.N_CS - 1)
        self.requested_hz = float(parsed.int_param("hz", 1_000_000, 1, int(self.MAX_HZ)))
        self.retries = parsed.int_param("retries", DEFAULT_RETRIES, 1, 100)
        self.timeout_ms = parsed.int_param("timeout_ms", DEFAULT_TIMEOUT_MS, 1, 60_000)
        if mode not in (0, 1, 2, 3):
            raise ValueError(f"SPI mode {mode} not in 0..3")
        self.mode = mode
        self.hz = self.requested_hz
        self.where = f"{self.SCHEME}:{self.target}?cs={self.cs}"
        self._sleep = sleep
        self._backend = backend
        self.dev: Any = None
        #: transfers that needed a retry (a health figure)
        self.retried = 0
        #: IN buffers by size, reused (see :meth:`_data_in`)
        self._in_buffers: dict[int, array.array] = {}
        #: the counter input in use ("" none): configured again whenever the bridge is re-opened
        self.counter_pin = ""

    # -- device lookup ------------------------------------------------------------
    def _find(self) -> Any:
        import usb.core

        try:
            found = list(
                usb.core.find(find_all=True, idVendor=self.target.vid, idProduct=self.target.pid, backend=self._backend)
            )
        except usb.core.NoBackendError:
            raise BusError(f"{self.where}: pyusb found no USB backend (install libusb-1.0)") from None
        if not found:
            raise BusClosed(f"{self.where}: no {self.NAME} with VID:PID {self.target.vid:04X}:{self.target.pid:04X}")
        if self.target.serial is None:
            return found[0]
        serials = []
        for dev in found:
            try:
                serial = dev.serial_number
            except (usb.core.USBError, ValueError):
                serial = None
            if serial == self.target.serial:
                return dev
            serials.append(str(serial))
        raise BusClosed(
            f"{self.where}: no {self.NAME} with serial {self.target.serial!r} (found: {', '.join(serials)})"
        )

    def ensure_open(self) -> None:
        if self.dev is not None:
            return
        import usb.core
        import usb.util

        dev = self._find()
        try:
            try:
                if dev.is_kernel_driver_active(0):
                    dev.detach_kernel_driver(0)
            except NotImplementedError:
                pass  # backends/platforms without kernel drivers
            usb.util.claim_interface(dev, 0)
            self.dev = dev
            self._setup()
            if self.counter_pin:
                self._start_counter()  # a re-plugged bridge counts from 0 again: the driver's reader resyncs
        except usb.core.USBError as exc:
            self.dev = None
            usb.util.dispose_resources(dev)
            if exc.errno == errno.EACCES:
                raise BusError(f"{self.where}: permission denied opening the {self.NAME} (udev rule?)") from exc
            if exc.errno == errno.EBUSY:
                raise BusError(f"{self.where}: {self.NAME} interface busy (another program has it)") from exc
            raise self._error(exc, "setup") from exc

    def _endpoints(self, transfer_type: int) -> tuple[int, int]:
        """(OUT, IN) endpoint addresses of ``transfer_type`` on interface 0, from its descriptor."""
        import usb.util

        intf = self.dev.get_active_configuration()[(0, 0)]
        eps = [ep for ep in intf if usb.util.endpoint_type(ep.bmAttributes) == transfer_type]
        outs = [ep.bEndpointAddress for ep in eps if usb.util.endpoint_direction(ep.bEndpointAddress) == 0]
        ins = [ep.bEndpointAddress for ep in eps if usb.util.endpoint_direction(ep.bEndpointAddress) != 0]
        if not outs or not ins:
            raise DeviceError(f"{self.where}: interface 0 lacks the IN/OUT endpoints of a {self.NAME}")
        return outs[0], ins[0]

    # -- transfers ------------------------------------------------------------------
    def _data_out(self, packet: bytes) -> None:
        """Send one packet on the OUT endpoint (bulk on the CP2130, interrupt on the MCP2210).

        pyusb takes ``array('B')`` as is; bytes it first tries as a buffer
        length, which raises and is caught on every call (pyusb 1.3
        ``_interop.as_array``), so the packet goes over as an array.
        """
        self.dev.write(self.ep_out, array.array("B", packet), self.timeout_ms)

    def _data_in(self, size: int) -> bytes:
        """Read up to ``size`` bytes from the IN endpoint into a reused buffer."""
        buf = self._in_buffers.get(size)
        if buf is None:
            buf = self._in_buffers[size] = array.array("B", bytes(size))
        n = self.dev.read(self.ep_in, buf, self.timeout_ms)
        return buf[:n].tobytes()

    def _error(self, exc: Exception, what: str) -> BusError:
        import usb.core

        if isinstance(exc, usb.core.USBTimeoutError):
            return BusTimeout(f"{self.where}: {self.NAME} timeout during {what} ({self.retries} tries)")
        if getattr(exc, "errno", None) in _GONE:
            return BusClosed(f"{self.where}: {self.NAME} gone during {what}: {exc}")
        return BusError(f"{self.where}: USB error during {what}: {exc}")

    def transfer(self, tx: bytes) -> bytes:
        tx = bytes(tx)
        return self._retrying(lambda: self._transfer(tx), f"SPI transfer of {len(tx)} bytes")

    def _retrying(self, op: Callable[[], Any], what: str) -> Any:
        """Run ``op`` on the open bridge, retrying USB errors up to ``retries`` times; a gone device is dropped."""
        import usb.core

        self.ensure_open()
        last: Exception | None = None
        for _attempt in range(self.retries):
            try:
                return op()
            except usb.core.USBError as exc:
                last = exc
                if exc.errno in _GONE:
                    self._drop()
                    raise self._error(exc, what) from exc
                self.retried += 1
                self._recover()
        assert last is not None
        raise self._error(last, what) from last

    # -- data-ready counter ------------------------------------------------------------
    def start_event_counter(self, pin: str) -> int:
        """Count rising edges on ``pin`` (the bridge's counter input) from 0; return the modulus (2**16)."""
        if not self.COUNTER_PIN or pin != self.COUNTER_PIN:
            where = f"only on {self.COUNTER_PIN}" if self.COUNTER_PIN else "on no pin"
            raise SettingError(f"{self.where}: data_ready = {pin!r}: the {self.NAME} counts edges {where}")
        self.counter_pin = pin
        self._retrying(self._start_counter, f"starting the event counter on {pin}")
        return self.COUNTER_MODULUS

    def read_event_counter(self) -> int:
        """The rising edges counted on the counter input, modulo :attr:`COUNTER_MODULUS` (one USB transaction)."""
        if not self.counter_pin:
            raise DeviceError(f"{self.where}: event counter read before start_event_counter")
        return int(self._retrying(self._read_counter, "reading the event counter"))

    def transfer_frames(self, frames: Sequence[bytes], gap_s: float) -> list[bytes]:
        out = []
        for i, frame in enumerate(frames):
            if i:
                # each frame is its own USB transaction, so CS is high for this plus
                # the USB turnaround (>= 125 us) - always more than the chip needs
                self._sleep(gap_s)
            out.append(self.transfer(frame))
        return out

    def _drop(self) -> None:
        import usb.util

        if self.dev is not None:
            try:
                usb.util.dispose_resources(self.dev)
            except Exception:  # noqa: BLE001 - the device is already gone
                pass
        self.dev = None

    def close(self) -> None:
        self._drop()

    # -- bridge specifics --------------------------------------------------------------
    def _setup(self) -> None:
        """Configure chip select, mode and clock after the interface is claimed."""
        raise NotImplementedError

    def _transfer(self, tx: bytes) -> bytes:
        raise NotImplementedError

    def _start_counter(self) -> None:
        """Configure :attr:`COUNTER_PIN` as a rising-edge counter input and zero the count."""
        raise NotImplementedError

    def _read_counter(self) -> int:
        raise NotImplementedError

    def _recover(self) -> None:
        """Bring the bridge back to idle after a failed attempt (before a retry)."""
