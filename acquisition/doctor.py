"""Bring-up diagnosis (``imustation devices``): why a configured device does not answer, and what to do.

For each device and thermometer of a config, :func:`check_station` first looks
at the host (:class:`~imustation.acquisition.hostview.HostView`: device nodes,
kernel modules, USB devices, stable serial names, permissions) and only then
opens the driver as a capture would. Every failure becomes a :class:`Finding`
with its cause and its remedy:

* I2C: ``/dev/i2c-N`` missing (``i2c-dev`` not loaded, or the bus not enabled:
  the adapters present are listed), no permission (the node's group,
  ``usermod -aG``), no answer at the address (wiring, pull-ups, address strap);
* USB-SPI bridges: the bridge absent (the USB devices present are listed), no
  permission on its ``/dev/bus/usb`` node (the udev rule), no libusb;
* serial: the port absent (``/dev/serial/by-id`` listed), no permission, and a
  device that does not answer at the configured baud: the common rates are
  tried and the one it answers at is named.

A device that answers on an unstable name (``/dev/ttyUSB1``: the number depends
on the order adapters enumerate) gets a note naming its ``/dev/serial/by-id`` link.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

from imustation.acquisition.buses import BusFactory
from imustation.acquisition.config import DeviceConfig, StationConfig
from imustation.acquisition.hostview import HostView
from imustation.clock import Clock
from imustation.drivers import DRIVERS, THERMOMETER_DRIVERS
from imustation.drivers.bus.url import parse_bus_url, parse_usb_target
from imustation.errors import BusClosed, ConfigError, ImustationError, NackError, SettingError

#: rates a serial device is tried at when it does not answer at its configured one, most common first
PROBE_BAUDS = (115200, 38400, 921600, 460800, 230400, 57600, 19200, 9600)
#: the group the udev rules of ``imustation setup udev`` give I2C nodes and USB bridges
STATION_GROUP = "plugdev"
I2C_GROUP = "i2c"
#: written once for every remedy that needs the udev rules
UDEV_REMEDY = (
    "imustation setup udev | sudo tee /etc/udev/rules.d/70-imustation.rules && "
    "sudo udevadm control --reload && sudo udevadm trigger"
)


@dataclass(frozen=True)
class Finding:
    """The outcome for one device or thermometer: ``ok`` with its identity, or a cause and a remedy."""

    what: str  # "device" or "thermometer"
    name: str
    driver: str
    where: str
    ok: bool
    detail: str  # the identity line, or the error as the driver raised it
    cause: str = ""
    remedy: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)


def check_station(
    cfg: StationConfig,
    *,
    simulate: bool,
    clock: Clock,
    view: HostView | None = None,
    probe_bauds: tuple[int, ...] = PROBE_BAUDS,
) -> list[Finding]:
    """Diagnose every device and thermometer of ``cfg`` (devices first, config order).

    ``simulate``: the chips are simulated (the host is not looked at, the
    drivers and the baud probe run against the simulators); ``view``: the host
    (default: the real ``/dev`` and ``/sys``).
    """
    view = view or HostView()
    entries: list[tuple[str, DeviceConfig, Any]] = [("device", d, DRIVERS[d.driver]) for d in cfg.devices]
    entries += [("thermometer", t, THERMOMETER_DRIVERS[t.driver]) for t in cfg.thermometers]
    buses = BusFactory(simulate=simulate, clock=clock, seed=cfg.seed)
    out = []
    try:
        for what, entry, driver_cls in entries:
            out.append(_check_one(what, entry, driver_cls, buses, simulate, clock, view, probe_bauds, cfg.seed))
    finally:
        buses.close()
    return out


def _where(entry: DeviceConfig, driver_cls: Any) -> str:
    address = entry.address if entry.address is not None else getattr(driver_cls, "default_address", None)
    return entry.bus + (f"@0x{address:02X}" if address is not None else "")


def _open(what: str, entry: DeviceConfig, driver_cls: Any, buses: BusFactory, clock: Clock) -> str:
    """Open and close the driver as a capture would; its identity line."""
    regs = buses.register_thermometer(entry) if what == "thermometer" else buses.register_device(entry)
    driver = driver_cls(regs, entry.settings, sleep=clock.sleep)
    opened = driver.open()
    try:
        if what == "thermometer":
            return f"{opened}, {driver.read_celsius():.4f} degC"
        return f"{opened.identity}, {opened.model}, {opened.rate_hz:g} Hz"
    finally:
        driver.close()


def _check_one(
    what: str,
    entry: DeviceConfig,
    driver_cls: Any,
    buses: BusFactory,
    simulate: bool,
    clock: Clock,
    view: HostView,
    bauds: tuple[int, ...],
    seed: int,
) -> Finding:
    kind = driver_cls.bus_kind
    base = Finding(what, entry.name, entry.driver, _where(entry, driver_cls), False, "")
    if not simulate:
        try:
            pre = preflight(kind, entry, driver_cls, view)
        except ImustationError as exc:  # a malformed bus URL
            return replace(base, detail=str(exc), cause="malformed bus URL", remedy="correct bus = in the config")
        if pre is not None:
            return replace(base, detail=pre[0], cause=pre[0], remedy=pre[1])
    try:
        line = _open(what, entry, driver_cls, buses, clock)
    except ImustationError as exc:
        cause, remedy = explain(kind, entry, driver_cls, exc)
        # a port that opened but gave nothing readable: the line rate, most likely (a refused setting
        # or a config contradiction is not)
        if kind == "serial" and not isinstance(exc, (BusClosed, SettingError, ConfigError)) and bauds:
            cause, remedy = _baud_probe(entry, driver_cls, simulate, clock, seed, bauds) or (cause, remedy)
        return replace(base, detail=str(exc), cause=cause, remedy=remedy)
    notes = () if simulate or kind != "serial" else _stable_name_note(entry, view)
    return replace(base, ok=True, detail=line, notes=notes)


# -- before opening: the host ---------------------------------------------------------------
def preflight(kind: str, entry: DeviceConfig, driver_cls: Any, view: HostView) -> tuple[str, str] | None:
    """(cause, remedy) when the host cannot offer ``entry``'s bus, else None (then the driver is tried)."""
    url = parse_bus_url(entry.bus)
    if kind == "i2c" and url.scheme == "i2c":
        return _i2c_preflight(url.target, view)
    if kind == "spi" and url.scheme in ("cp2130", "mcp2210"):
        return _usb_preflight(url, view)
    if kind == "serial" and url.scheme == "serial":
        return _serial_preflight(url.target, view)
    return None


def _permission(node: str, view: HostView) -> tuple[str, str]:
    group = view.group_of(node)
    shown = view.shown(node)
    cause = f"permission denied on {shown} (group {group}; user {view.user} may not read and write it)"
    if group in ("root", "0"):
        remedy = (
            f"install the udev rules so the node belongs to a group ({UDEV_REMEDY}), then "
            f"sudo usermod -aG {I2C_GROUP if 'i2c' in shown else STATION_GROUP} {view.user} and log in again"
        )
    else:
        remedy = f"sudo usermod -aG {group} {view.user}, then log in again (or reboot)"
    return cause, remedy


def _i2c_preflight(target: str, view: HostView) -> tuple[str, str] | None:
    if not target.isdigit():
        return f"i2c:{target} is not an adapter number", 'write bus = "i2c:N" for /dev/i2c-N'
    node = view.dev(f"/dev/i2c-{target}")
    if os.path.exists(node):
        return None if view.access(node) else _permission(node, view)
    if not view.module_loaded("i2c-dev"):
        return (
            f"/dev/i2c-{target} does not exist: the kernel module i2c-dev is not loaded",
            "sudo modprobe i2c-dev; to load it at every boot: echo i2c-dev | sudo tee /etc/modules-load.d/i2c-dev.conf",
        )
    adapters = view.i2c_adapters()
    have = ", ".join(f"i2c-{n} ({name or 'no name'})" for n, name in adapters) or "none"
    return (
        f"/dev/i2c-{target} does not exist: no I2C adapter {target} (adapters present: {have})",
        "enable the bus - Raspberry Pi: sudo raspi-config nonint do_i2c 0, or dtparam=i2c_arm=on in "
        "/boot/firmware/config.txt (the header's bus, i2c-1; others: dtoverlay=i2c3 .. i2c6 or i2c-gpio), "
        "then reboot; a PC: plug in the USB-I2C adapter; or correct bus = to an adapter present",
    )


def _usb_preflight(url: Any, view: HostView) -> tuple[str, str] | None:
    from imustation.drivers.bus.spi_cp2130 import CP2130
    from imustation.drivers.bus.spi_mcp2210 import MCP2210

    bridge = CP2130 if url.scheme == "cp2130" else MCP2210
    target = parse_usb_target(url, bridge.DEFAULT_VID, bridge.DEFAULT_PID)
    present = view.usb_devices()
    match = [u for u in present if (u.vid, u.pid) == (target.vid, target.pid)]
    if target.serial is not None:
        match = [u for u in match if u.serial == target.serial]
    if not match:
        listed = "; ".join(str(u) for u in present) or "none (no USB device in /sys/bus/usb/devices)"
        return (
            f"no {bridge.NAME} with {target} on USB (USB devices present: {listed})",
            f"plug the {bridge.NAME} in (a powered hub, a data cable); a bridge with another VID:PID or serial "
            f"is named {url.scheme}:VID:PID/SERIAL in bus =",
        )
    node = view.usb_node(match[0])
    if os.path.exists(node) and not view.access(node):
        return _permission(node, view)
    return None


def _serial_preflight(target: str, view: HostView) -> tuple[str, str] | None:
    if "://" in target:  # a pyserial URL (rfc2217://, socket://): nothing on this host to look at
        return None
    node = view.dev(target)
    if os.path.exists(node):
        return None if view.access(node) else _permission(node, view)
    by_id = view.serial_by_id()
    listed = "; ".join(f"{k} -> {v}" for k, v in by_id.items()) or "none (no USB-serial adapter plugged in)"
    return (
        f"serial port {target} does not exist (/dev/serial/by-id: {listed})",
        "plug the adapter in and name it by its stable /dev/serial/by-id/... link in bus = "
        "(ttyUSB numbers change with the order adapters appear at boot)",
    )


def _stable_name_note(entry: DeviceConfig, view: HostView) -> tuple[str, ...]:
    target = parse_bus_url(entry.bus).target
    if target.startswith("/dev/serial/") or "://" in target:
        return ()
    links = [k for k, v in view.serial_by_id().items() if v == target]
    better = f": use {links[0]}" if links else ""
    return (f"{target} may get another number at the next boot{better}",)


# -- after opening: what the error says -------------------------------------------------------
def explain(kind: str, entry: DeviceConfig, driver_cls: Any, exc: ImustationError) -> tuple[str, str]:
    """(cause, remedy) of a driver's or bus's error."""
    text = str(exc)
    if isinstance(exc, ConfigError):
        return "the config contradicts itself", "correct the config entry the error names"
    if "permission denied" in text.lower():
        return "permission denied opening the bus", f"install the udev rules ({UDEV_REMEDY}) and join their group"
    if "no USB backend" in text:
        return "pyusb finds no libusb", "install libusb 1.0 (Debian/Raspberry Pi OS: sudo apt install libusb-1.0-0)"
    if "busy" in text:
        return "another program holds the bus", "stop the other program (another capture, a vendor tool)"
    if isinstance(exc, NackError):
        default = getattr(driver_cls, "default_address", None)
        hint = f" (the driver's default is 0x{default:02X})" if default is not None else ""
        return (
            f"nothing answers at {_where(entry, driver_cls)}",
            f"check the supply, SDA/SCL wiring and pull-ups, and the address strap{hint}; "
            f"i2cdetect -y {parse_bus_url(entry.bus).target} lists the addresses that answer",
        )
    if isinstance(exc, SettingError):
        return "a setting the device refuses", "correct the setting in the config (docs/hardware.md)"
    if isinstance(exc, BusClosed):
        return "the bus went away while opening", "check the cable and the adapter's power"
    return "the device answered wrongly or not at all", "check wiring and power (docs/hardware.md)"


def _baud_probe(
    entry: DeviceConfig, driver_cls: Any, simulate: bool, clock: Clock, seed: int, bauds: tuple[int, ...]
) -> tuple[str, str] | None:
    """(cause, remedy) naming the baud rate the device answers at, or that it answers at none."""
    url = parse_bus_url(entry.bus, ("serial", "sim"))
    configured = int(url.params.get("baud", getattr(driver_cls, "default_baud", 9600)))
    stem = entry.bus.split("?", 1)[0]
    tried = []
    for baud in bauds:
        if baud == configured:
            continue
        tried.append(baud)
        if _answers(replace(entry, bus=f"{stem}?baud={baud}"), driver_cls, simulate, clock, seed):
            return (
                f"no valid answer at {configured} baud; the device answers at {baud} baud",
                f"write ?baud={baud} in bus ="
                + (
                    f", or set the MTi to {configured} baud (MT Manager or the SetBaudrate message; docs/hardware.md)"
                    if getattr(driver_cls, "name", "") == "mti"
                    else ""
                ),
            )
    return (
        f"no valid answer at {configured} baud nor at {', '.join(map(str, tried))}",
        "check TX/RX (crossed), signal levels (RS-232 vs 3.3 V TTL), ground and the device's power",
    )


def _answers(entry: DeviceConfig, driver_cls: Any, simulate: bool, clock: Clock, seed: int) -> bool:
    """The driver identifies its device on ``entry``'s bus (slower output rates tried if the line is too slow)."""
    attempts: list[Callable[[dict], dict]] = [lambda s: s]
    rates = next((s.allowed for s in getattr(driver_cls, "SETTINGS", ()) if s.key == "rate_hz" and s.allowed), None)
    if rates:
        attempts.append(lambda s: {**s, "rate_hz": min(rates)})
    for adjust in attempts:
        buses = BusFactory(simulate=simulate, clock=clock, seed=seed)
        try:
            _open("device", replace(entry, settings=adjust(dict(entry.settings))), driver_cls, buses, clock)
            return True
        except SettingError:
            continue
        except ImustationError:
            return False
        finally:
            buses.close()
    return False
