"""What the host offers the station's buses, read from ``/dev`` and ``/sys`` (roots injectable for tests).

:class:`HostView` answers the questions a bring-up asks before any driver runs:
does ``/dev/i2c-N`` exist, is the ``i2c-dev`` module loaded, which I2C adapters
are there, which USB devices are plugged in (``/sys/bus/usb/devices``), which
stable serial names ``/dev/serial/by-id`` offers, who may open a device node.
Nothing here opens a bus; :mod:`~imustation.acquisition.doctor` turns the
answers into causes and remedies.
"""

from __future__ import annotations

import getpass
import grp
import os
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass(frozen=True)
class USBDevice:
    """One USB device as sysfs describes it (``/sys/bus/usb/devices/<port>``)."""

    vid: int
    pid: int
    busnum: int
    devnum: int
    manufacturer: str = ""
    product: str = ""
    serial: str = ""

    def __str__(self) -> str:
        text = " ".join(s for s in (self.manufacturer, self.product) if s) or "(no name)"
        serial = f" serial {self.serial}" if self.serial else ""
        return f"{self.vid:04X}:{self.pid:04X} {text}{serial} (bus {self.busnum:03d} device {self.devnum:03d})"


def _default_access(path: str) -> bool:
    return os.access(path, os.R_OK | os.W_OK)


def _default_group(path: str) -> str:
    gid = os.stat(path).st_gid
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def _default_user() -> str:
    try:
        return getpass.getuser()
    except Exception:  # noqa: BLE001 - no login name (a container): the uid will do
        return str(os.getuid())


@dataclass
class HostView:
    """The host's device nodes and sysfs, under ``dev_root`` and ``sys_root``.

    ``access(path)``: may this process read and write the node (default
    ``os.access``); ``group_of(path)``: the group owning it; ``user``: the login
    name the remedies address. Tests replace all three.
    """

    dev_root: str = "/dev"
    sys_root: str = "/sys"
    access: Callable[[str], bool] = _default_access
    group_of: Callable[[str], str] = _default_group
    user: str = field(default_factory=_default_user)

    def dev(self, path: str) -> str:
        """A ``/dev/...`` path under ``dev_root`` (other paths unchanged)."""
        if path == "/dev" or path.startswith("/dev/"):
            return self.dev_root + path[4:]
        return path

    def shown(self, path: str) -> str:
        """A path under ``dev_root`` as the user knows it (``/dev/...``)."""
        if path.startswith(self.dev_root + "/"):
            return "/dev" + path[len(self.dev_root) :]
        return path

    def module_loaded(self, name: str) -> bool:
        """Kernel module ``name`` is loaded or built in (``/sys/module/<name>``)."""
        return os.path.isdir(os.path.join(self.sys_root, "module", name.replace("-", "_")))

    def i2c_adapters(self) -> list[tuple[int, str]]:
        """(number, name) of every I2C adapter the kernel knows (``/sys/class/i2c-adapter``)."""
        base = os.path.join(self.sys_root, "class", "i2c-adapter")
        out = []
        for entry in _listdir(base):
            if entry.startswith("i2c-") and entry[4:].isdigit():
                out.append((int(entry[4:]), _read(os.path.join(base, entry, "name"))))
        return sorted(out)

    def usb_devices(self) -> list[USBDevice]:
        """Every USB device sysfs lists (interfaces and hubs' ports without ids are skipped)."""
        base = os.path.join(self.sys_root, "bus", "usb", "devices")
        out = []
        for entry in _listdir(base):
            d = os.path.join(base, entry)
            vid, pid = _read(os.path.join(d, "idVendor")), _read(os.path.join(d, "idProduct"))
            try:
                ids = int(vid, 16), int(pid, 16)
                nums = int(_read(os.path.join(d, "busnum")) or 0), int(_read(os.path.join(d, "devnum")) or 0)
            except ValueError:
                continue
            out.append(
                USBDevice(
                    *ids,
                    *nums,
                    manufacturer=_read(os.path.join(d, "manufacturer")),
                    product=_read(os.path.join(d, "product")),
                    serial=_read(os.path.join(d, "serial")),
                )
            )
        return sorted(out, key=lambda u: (u.busnum, u.devnum))

    def usb_node(self, dev: USBDevice) -> str:
        """The device node libusb opens for ``dev`` (``/dev/bus/usb/BBB/DDD``, under ``dev_root``)."""
        return os.path.join(self.dev_root, "bus", "usb", f"{dev.busnum:03d}", f"{dev.devnum:03d}")

    def serial_by_id(self) -> dict[str, str]:
        """``/dev/serial/by-id/<name>`` -> the tty it points to (``/dev/ttyUSB0``), by name."""
        base = os.path.join(self.dev_root, "serial", "by-id")
        out = {}
        for entry in _listdir(base):
            link = os.path.join(base, entry)
            target = os.path.normpath(os.path.join(base, os.readlink(link))) if os.path.islink(link) else link
            out["/dev/serial/by-id/" + entry] = self.shown(target)
        return dict(sorted(out.items()))


def _listdir(path: str) -> list[str]:
    try:
        return sorted(os.listdir(path))
    except OSError:
        return []


def _read(path: str) -> str:
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            return fh.read().strip()
    except OSError:
        return ""
