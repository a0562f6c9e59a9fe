"""Set-up files for a lab computer (``imustation setup udev|service``): udev rules and a systemd unit.

Both are plain text made from the drivers' own constants, so a bridge's VID:PID
is written in one place. Each has a small parser here (:func:`parse_udev_rules`,
:func:`parse_unit`) that the tests run on every machine; where the system's own
verifiers are installed (``udevadm verify``, ``systemd-analyze verify``) the
tests run them too. docs/hardware.md explains where the files go.
"""

from __future__ import annotations

import os
import re
import shlex
import sys
from dataclasses import dataclass

from imustation.drivers.bus.spi_cp2130 import CP2130
from imustation.drivers.bus.spi_mcp2210 import MCP2210
from imustation.errors import InputError

#: group given to the USB-SPI bridges' device nodes, and to I2C nodes (Raspberry Pi OS's names)
USB_GROUP = "plugdev"
I2C_GROUP = "i2c"
SERIAL_GROUP = "dialout"

#: Xsens USB ids (Linux ``drivers/usb/serial/xsens_mt.c``: VID 0x2639, MTi-10/20/30 0x0001-0x0003,
#: MTi-100/200/300 0x0011-0x0013, MTi-G-700 0x0017; ``ftdi_sio_ids.h``: the Xsens USB-serial
#: converters, among them the CA-USB-MTi cable, on the FTDI VID 0x0403 with PIDs 0xD388-0xD38F)
XSENS_VID = 0x2639
XSENS_FTDI_VID = 0x0403
XSENS_FTDI_PIDS = range(0xD388, 0xD390)

#: the service's scheduling grants (what the capture's readers may ask for; docs/hardware.md)
SERVICE_NICE = -5
SERVICE_RTPRIO = 50
SERVICE_STOP_TIMEOUT_S = 60
SERVICE_RESTART_S = 15


def udev_rules() -> str:
    """The rules file (``/etc/udev/rules.d/70-imustation.rules``)."""
    cp, mcp = CP2130, MCP2210
    lines = [
        "# imustation: device access for the station's user without root (imustation setup udev).",
        "# Install: imustation setup udev | sudo tee /etc/udev/rules.d/70-imustation.rules",
        "#          sudo udevadm control --reload && sudo udevadm trigger   (then replug USB devices)",
        f"# and join the groups: sudo usermod -aG {I2C_GROUP},{USB_GROUP},{SERIAL_GROUP} $USER (log in again).",
        "",
        "# I2C adapters (/dev/i2c-N through i2c-dev): BMX055, MPU-9150/6500, MCP9804",
        f'SUBSYSTEM=="i2c-dev", GROUP="{I2C_GROUP}", MODE="0660"',
        "",
        f"# Silicon Labs CP2130 USB-to-SPI bridge ({cp.DEFAULT_VID:04X}:{cp.DEFAULT_PID:04X}; ADIS16448), via libusb",
        f'SUBSYSTEM=="usb", ENV{{DEVTYPE}}=="usb_device", ATTR{{idVendor}}=="{cp.DEFAULT_VID:04x}", '
        f'ATTR{{idProduct}}=="{cp.DEFAULT_PID:04x}", GROUP="{USB_GROUP}", MODE="0660"',
        "",
        f"# Microchip MCP2210 USB-to-SPI bridge ({mcp.DEFAULT_VID:04X}:{mcp.DEFAULT_PID:04X}), via libusb (the driver"
        " detaches the kernel's HID driver)",
        f'SUBSYSTEM=="usb", ENV{{DEVTYPE}}=="usb_device", ATTR{{idVendor}}=="{mcp.DEFAULT_VID:04x}", '
        f'ATTR{{idProduct}}=="{mcp.DEFAULT_PID:04x}", GROUP="{USB_GROUP}", MODE="0660"',
        f'SUBSYSTEM=="hidraw", ATTRS{{idVendor}}=="{mcp.DEFAULT_VID:04x}", '
        f'ATTRS{{idProduct}}=="{mcp.DEFAULT_PID:04x}", GROUP="{USB_GROUP}", MODE="0660"',
        "",
        f"# Xsens MTi on USB: its own VID {XSENS_VID:04X} (kernel driver xsens_mt) and the Xsens USB-serial",
        f"# converters on the FTDI VID {XSENS_FTDI_VID:04X} (PIDs {XSENS_FTDI_PIDS[0]:04X}-{XSENS_FTDI_PIDS[-1]:04X}).",
        "# Name the port in the config by its stable link: serial:/dev/serial/by-id/usb-Xsens_...",
        f'SUBSYSTEM=="tty", ATTRS{{idVendor}}=="{XSENS_VID:04x}", GROUP="{SERIAL_GROUP}", MODE="0660"',
        f'SUBSYSTEM=="tty", ATTRS{{idVendor}}=="{XSENS_FTDI_VID:04x}", ATTRS{{idProduct}}=="d38[8-f]", '
        f'GROUP="{SERIAL_GROUP}", MODE="0660"',
        "",
    ]
    return "\n".join(lines)


@dataclass(frozen=True)
class ServiceSpec:
    """What the unit runs: absolute paths, the capture's duration and rotation (text as the CLI takes it)."""

    config: str
    output: str
    duration: str
    rotate: str
    user: str
    station: str
    executable: str = ""

    def exec_start(self) -> str:
        exe = self.executable or f"{sys.executable} -m imustation"
        args = [
            "capture",
            self.config,
            "-o",
            self.output,
            "--duration",
            self.duration,
            "--rotate",
            self.rotate,
            "--resume",
            "--quiet",
            "--status-file",
            _stem(self.output) + ".status.json",
        ]
        return exe + " " + " ".join(shlex.quote(a) for a in args)


def _stem(path: str) -> str:
    return os.path.splitext(path)[0]


def service_unit(spec: ServiceSpec) -> str:
    """The systemd unit of an unattended capture (``/etc/systemd/system/imustation-<station>.service``).

    A clean stop is SIGTERM to the capture (it finishes its file: docs/capture.md),
    SIGKILL to what is left after TimeoutStopSec; a crash restarts it
    (Restart=on-failure) and every start resumes the run (``--resume``): after
    a power cut the night goes on as the next part of the same run.
    """
    for what, value in (("CONFIG", spec.config), ("--output", spec.output)):
        if not os.path.isabs(value):
            raise InputError(f"{what} {value!r}: the unit needs an absolute path")
        if any(c in value for c in "\n%"):
            raise InputError(f"{what} {value!r}: newlines and % cannot be written into a unit file")
    workdir = os.path.dirname(spec.output) or "/"
    return "\n".join(
        [
            f"# imustation: unattended capture of station {spec.station} (imustation setup service).",
            f"# Install: imustation setup service ... | sudo tee /etc/systemd/system/imustation-{spec.station}.service",
            f"#          sudo systemctl daemon-reload && sudo systemctl enable --now imustation-{spec.station}",
            "# Stop cleanly: sudo systemctl stop ... (SIGTERM: the capture finishes its file).",
            "[Unit]",
            f"Description=imustation capture of station {spec.station}",
            "Wants=time-sync.target",
            "After=time-sync.target local-fs.target",
            "StartLimitIntervalSec=600",
            "StartLimitBurst=5",
            "",
            "[Service]",
            "Type=simple",
            f"User={spec.user}",
            f"SupplementaryGroups={I2C_GROUP} {USB_GROUP} {SERIAL_GROUP}",
            f"WorkingDirectory={workdir}",
            f"ExecStart={spec.exec_start()}",
            "# the capture's clean stop: SIGTERM to the main process, which stops its readers and finishes the file",
            "KillSignal=SIGTERM",
            "KillMode=mixed",
            f"TimeoutStopSec={SERVICE_STOP_TIMEOUT_S}",
            "Restart=on-failure",
            f"RestartSec={SERVICE_RESTART_S}",
            "# what the bus readers may ask for: real-time priority up to this, locked memory, a higher priority",
            f"LimitRTPRIO={SERVICE_RTPRIO}",
            "LimitMEMLOCK=infinity",
            f"Nice={SERVICE_NICE}",
            "IOSchedulingClass=best-effort",
            "IOSchedulingPriority=2",
            "Environment=PYTHONUNBUFFERED=1",
            "",
            "[Install]",
            "WantedBy=multi-user.target",
            "",
        ]
    )


# -- parsers the tests run everywhere ------------------------------------------------------------
#: udev rule keys: matching keys (==, !=) and assignment keys (=, +=, -=, :=); {attr} ones take an argument
_UDEV_MATCH = {
    "ACTION", "DEVPATH", "KERNEL", "KERNELS", "SUBSYSTEM", "SUBSYSTEMS", "DRIVER", "DRIVERS", "ATTR", "ATTRS",
    "ENV", "TAG", "TAGS", "NAME", "SYMLINK", "TEST", "PROGRAM", "RESULT", "CONST", "SYSCTL",
}  # fmt: skip
_UDEV_ASSIGN = {"NAME", "SYMLINK", "OWNER", "GROUP", "MODE", "ENV", "TAG", "RUN", "LABEL", "GOTO", "OPTIONS", "ATTR"}
_UDEV_PAIR = re.compile(r'\s*(?P<key>[A-Z_]+)(\{(?P<arg>[^}]*)\})?\s*(?P<op>==|!=|\+=|-=|:=|=)\s*"(?P<value>[^"]*)"\s*')


def parse_udev_rules(text: str) -> list[list[tuple[str, str, str, str]]]:
    """Every rule of a rules file as (key, arg, operator, value) tuples; malformed lines raise ValueError."""
    rules = []
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        pairs, pos = [], 0
        while pos < len(line):
            m = _UDEV_PAIR.match(line, pos)
            if m is None:
                raise ValueError(f"line {number}: cannot parse from column {pos + 1}: {line[pos:]!r}")
            key, op = m["key"], m["op"]
            known = _UDEV_MATCH if op in ("==", "!=") else _UDEV_ASSIGN
            if key not in known:
                raise ValueError(f"line {number}: {key} {op} is not a udev rule key")
            if key in ("ATTR", "ATTRS", "ENV") and not m["arg"]:
                raise ValueError(f"line {number}: {key} needs {{name}}")
            if key == "MODE" and not re.fullmatch(r"0?[0-7]{3}", m["value"]):
                raise ValueError(f"line {number}: MODE {m['value']!r} is not an octal mode")
            pairs.append((key, m["arg"] or "", op, m["value"]))
            pos = m.end()
            if pos < len(line):
                if line[pos] != ",":
                    raise ValueError(f"line {number}: expected ',' at column {pos + 1}")
                pos += 1
        if not any(op in ("==", "!=") for _, _, op, _ in pairs):
            raise ValueError(f"line {number}: a rule without a match applies to every device")
        rules.append(pairs)
    return rules


#: directives the unit may use, per section (a subset of systemd.unit/service/exec/kill/resource-control)
_UNIT_KEYS = {
    "Unit": {"Description", "Documentation", "Wants", "After", "Requires", "StartLimitIntervalSec", "StartLimitBurst"},
    "Service": {
        "Type", "User", "Group", "SupplementaryGroups", "WorkingDirectory", "ExecStart", "KillSignal", "KillMode",
        "TimeoutStopSec", "Restart", "RestartSec", "LimitRTPRIO", "LimitMEMLOCK", "Nice", "IOSchedulingClass",
        "IOSchedulingPriority", "Environment", "CPUSchedulingPolicy", "CPUSchedulingPriority",
    },
    "Install": {"WantedBy"},
}  # fmt: skip


def parse_unit(text: str) -> dict[str, dict[str, str]]:
    """A unit file's sections and directives; unknown sections or keys and malformed lines raise ValueError."""
    out: dict[str, dict[str, str]] = {}
    section = None
    for number, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith(("#", ";")):
            continue
        if s.startswith("[") and s.endswith("]"):
            section = s[1:-1]
            if section not in _UNIT_KEYS:
                raise ValueError(f"line {number}: unknown section [{section}]")
            out.setdefault(section, {})
            continue
        if section is None or "=" not in s:
            raise ValueError(f"line {number}: expected Key=value inside a section: {s!r}")
        key, value = (p.strip() for p in s.split("=", 1))
        if key not in _UNIT_KEYS[section]:
            raise ValueError(f"line {number}: {key} is not a [{section}] directive")
        if key in out[section]:
            raise ValueError(f"line {number}: {key} given twice")
        out[section][key] = value
    return out
