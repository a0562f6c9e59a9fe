"""A virtual pyusb backend: simulated USB functions behind the real ``usb.core``.

``usb.core.find(backend=SimUSBBackend([...]))`` returns genuine
``usb.core.Device`` objects, so the bridge code (device lookup, serial-number
strings, interface claiming, endpoint dispatch bulk vs interrupt, error
handling) runs unchanged. Each :class:`SimUSBFunction` answers control, OUT
and IN transfers as its bridge chip does (see ``drivers/sim/spi_bridges.py``:
``CP2130Sim`` and ``MCP2210Sim``).

Faults (from the function's :class:`~imustation.drivers.sim.faults.FaultPlan`):
``disconnect`` - the device is absent from enumeration and every transfer fails
with ENODEV while active; ``nack`` - one OUT transfer times out (the bridge
retries); ``stall`` - one OUT transfer completes ``duration_s`` late; ``slow`` -
every OUT transfer of the window ``delay_s`` late; ``corrupt`` - one SPI byte read
back has a bit flipped (applied by the bridge simulators).
"""

from __future__ import annotations

import array
import errno
from dataclasses import dataclass, field

import usb.backend
import usb.core

from imustation.drivers.sim.faults import FaultPlan

# standard requests (USB 2.0 §9.4) the backend answers itself
_GET_DESCRIPTOR = 0x06
_DESC_STRING = 0x03
_LANGID_EN_US = 0x0409


@dataclass
class DeviceDescriptor:
    idVendor: int
    idProduct: int
    iManufacturer: int = 1
    iProduct: int = 2
    iSerialNumber: int = 3
    bLength: int = 18
    bDescriptorType: int = 1
    bcdUSB: int = 0x0200
    bDeviceClass: int = 0
    bDeviceSubClass: int = 0
    bDeviceProtocol: int = 0
    bMaxPacketSize0: int = 64
    bcdDevice: int = 0x0100
    bNumConfigurations: int = 1
    address: int | None = None
    bus: int | None = 1
    port_number: int | None = None
    port_numbers: tuple | None = None
    speed: int | None = None


@dataclass
class ConfigurationDescriptor:
    bLength: int = 9
    bDescriptorType: int = 2
    wTotalLength: int = 32
    bNumInterfaces: int = 1
    bConfigurationValue: int = 1
    iConfiguration: int = 0
    bmAttributes: int = 0x80
    bMaxPower: int = 50
    extra_descriptors: list = field(default_factory=list)


@dataclass
class InterfaceDescriptor:
    bInterfaceClass: int
    bNumEndpoints: int
    bLength: int = 9
    bDescriptorType: int = 4
    bInterfaceNumber: int = 0
    bAlternateSetting: int = 0
    bInterfaceSubClass: int = 0
    bInterfaceProtocol: int = 0
    iInterface: int = 0
    extra_descriptors: list = field(default_factory=list)


@dataclass
class EndpointDescriptor:
    bEndpointAddress: int
    bmAttributes: int  # 2 bulk, 3 interrupt
    wMaxPacketSize: int = 64
    bLength: int = 7
    bDescriptorType: int = 5
    bInterval: int = 1
    bRefresh: int = 0
    bSynchAddress: int = 0
    extra_descriptors: list = field(default_factory=list)


def _gone() -> usb.core.USBError:
    return usb.core.USBError("No such device (it may have been disconnected)", -4, errno.ENODEV)


def usb_timeout() -> usb.core.USBTimeoutError:
    """The error pyusb raises when a transfer times out (LIBUSB_ERROR_TIMEOUT), for the simulated bridges."""
    return usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)


def usb_stall() -> usb.core.USBError:
    """The error pyusb raises when an endpoint stalls (LIBUSB_ERROR_PIPE), for the simulated bridges."""
    return usb.core.USBError("Pipe error", -9, errno.EPIPE)


class SimUSBFunction:
    """One simulated USB device: descriptors plus the bridge's transfer handlers.

    Subclasses implement :meth:`control` (vendor/class requests), :meth:`out`
    and :meth:`in_`.
    """

    INTERFACE_CLASS = 0xFF
    #: (address, attributes) of interface 0's endpoints
    ENDPOINTS: tuple[tuple[int, int], ...] = ()

    def __init__(self, vid: int, pid: int, serial: str, plan: FaultPlan | None = None, *, kernel_driver: bool = False):
        self.descriptor = DeviceDescriptor(vid, pid)
        self.strings = {1: "imustation", 2: type(self).__name__, 3: serial}
        self.serial = serial
        self.plan = plan
        self.kernel_driver = kernel_driver
        self.claimed = False
        self.sim_transfers = 0

    # -- fault gates ------------------------------------------------------------------
    def present(self) -> bool:
        return self.plan is None or not self.plan.active("disconnect")

    def gate(self, out: bool) -> None:
        if not self.present():
            raise _gone()
        if out and self.plan is not None:
            if self.plan.fire("nack"):
                raise usb_timeout()
            # the transfer is late (a stalled bridge or host; a slow window): the chip's clock runs on
            late = (self.plan.fire_duration("stall") or 0.0) + self.plan.delay_s("slow")
            if late:
                self.plan.clock.sleep(late)

    # -- handlers -------------------------------------------------------------------------
    def control(self, request_type: int, request: int, value: int, index: int, data: bytes | int) -> bytes | int:
        raise usb_stall()

    def out(self, ep: int, data: bytes) -> int:
        raise usb_stall()

    def in_(self, ep: int, size: int) -> bytes:
        raise usb_timeout()


class SimUSBBackend(usb.backend.IBackend):
    """pyusb backend whose devices are :class:`SimUSBFunction` objects."""

    def __init__(self, functions: list[SimUSBFunction] | None = None):
        super().__init__()
        self.functions: list[SimUSBFunction] = list(functions or [])

    def attach(self, function: SimUSBFunction) -> None:
        self.functions.append(function)

    # -- enumeration and descriptors ------------------------------------------------------
    def enumerate_devices(self):
        return [f for f in self.functions if f.present()]

    def get_device_descriptor(self, dev: SimUSBFunction) -> DeviceDescriptor:
        return dev.descriptor

    def get_configuration_descriptor(self, dev: SimUSBFunction, config: int) -> ConfigurationDescriptor:
        return ConfigurationDescriptor()

    def get_interface_descriptor(self, dev: SimUSBFunction, intf: int, alt: int, config: int) -> InterfaceDescriptor:
        return InterfaceDescriptor(dev.INTERFACE_CLASS, len(dev.ENDPOINTS))

    def get_endpoint_descriptor(self, dev: SimUSBFunction, ep: int, intf: int, alt: int, config: int):
        address, attributes = dev.ENDPOINTS[ep]
        return EndpointDescriptor(address, attributes)

    # -- handles --------------------------------------------------------------------------
    def open_device(self, dev: SimUSBFunction) -> SimUSBFunction:
        if not dev.present():
            raise _gone()
        return dev

    def close_device(self, dev_handle: SimUSBFunction) -> None:
        dev_handle.claimed = False

    def set_configuration(self, dev_handle: SimUSBFunction, config_value: int) -> None:
        dev_handle.gate(False)

    def get_configuration(self, dev_handle: SimUSBFunction) -> int:
        dev_handle.gate(False)
        return 1

    def claim_interface(self, dev_handle: SimUSBFunction, intf: int) -> None:
        dev_handle.gate(False)
        if dev_handle.kernel_driver:
            raise usb.core.USBError("Resource busy", -6, errno.EBUSY)
        dev_handle.claimed = True

    def release_interface(self, dev_handle: SimUSBFunction, intf: int) -> None:
        dev_handle.claimed = False

    def is_kernel_driver_active(self, dev_handle: SimUSBFunction, intf: int) -> bool:
        return dev_handle.kernel_driver

    def detach_kernel_driver(self, dev_handle: SimUSBFunction, intf: int) -> None:
        dev_handle.kernel_driver = False

    def attach_kernel_driver(self, dev_handle: SimUSBFunction, intf: int) -> None:
        dev_handle.kernel_driver = True

    # -- transfers ----------------------------------------------------------------------------
    def _write(self, dev_handle: SimUSBFunction, ep: int, data: array.array) -> int:
        dev_handle.gate(True)
        if not dev_handle.claimed:
            raise usb.core.USBError("Access denied (interface not claimed)", -3, errno.EACCES)
        dev_handle.sim_transfers += 1
        return dev_handle.out(ep, data.tobytes())

    def _read(self, dev_handle: SimUSBFunction, ep: int, buff: array.array) -> int:
        dev_handle.gate(False)
        data = dev_handle.in_(ep, len(buff))
        n = len(data)
        memoryview(buff)[:n] = data
        return n

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        return self._write(dev_handle, ep, data)

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        return self._read(dev_handle, ep, buff)

    def intr_write(self, dev_handle, ep, intf, data, timeout):
        return self._write(dev_handle, ep, data)

    def intr_read(self, dev_handle, ep, intf, buff, timeout):
        return self._read(dev_handle, ep, buff)

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        dev_handle.gate(False)
        device_to_host = bool(bmRequestType & 0x80)
        if bmRequestType == 0x80 and bRequest == _GET_DESCRIPTOR and wValue >> 8 == _DESC_STRING:
            reply = self._string(dev_handle, wValue & 0xFF)
        elif device_to_host:
            reply = dev_handle.control(bmRequestType, bRequest, wValue, wIndex, len(data))
        else:
            return dev_handle.control(bmRequestType, bRequest, wValue, wIndex, data.tobytes())
        assert isinstance(reply, bytes)
        n = min(len(reply), len(data))
        data[:n] = array.array("B", reply[:n])
        return n

    @staticmethod
    def _string(dev: SimUSBFunction, index: int) -> bytes:
        if index == 0:
            body = _LANGID_EN_US.to_bytes(2, "little")
        elif index in dev.strings:
            body = dev.strings[index].encode("utf-16-le")
        else:
            raise usb_stall()
        return bytes([len(body) + 2, _DESC_STRING]) + body
