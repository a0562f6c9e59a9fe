"""KVH DSP-3000 fibre-optic gyro, 100 Hz ASCII serial variant (docs/reference/sensors.md §6).

Each output is one line ``(-)xxx.xxxxxx y`` + CR LF at 38 400 baud 8N1: the
value (rate in deg/s, or incremental angle in deg), spaces, and a BIT flag
(1 valid, 0 fault or starting up) [KVH-M]. Parsing follows the tested ROS
parser [KVH-R]: the value must be preceded by at least one space, the flag
must be 0 or 1, blanks may follow it before CR LF, and the stream resynchronises
on CR LF.

Storage: the value has six decimals, so it is stored *exactly* as an int32
count of 1e-6 deg/s (rate mode) or 1e-6 deg per output (incremental-angle
mode; scale = 1e-6 deg x rate_hz, i.e. the mean rate over the nominal output
period). The output rate varies +-2-3 % between units [KVH-M], so in
incremental-angle mode set ``rate_hz`` to the unit's measured rate. Lines with
flag 0 are not stored: they give a lost-sample block noting the fault; lines
that cannot be parsed (garbage, bytes lost on the line) count as lost samples
too (a lower bound: a lost CR LF merges two lines into one).
"""

from __future__ import annotations

import re
import time
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from imustation.channels import ChannelSpec, DriverInfo
from imustation.drivers.base import Block, Setting, Sleep, check_settings
from imustation.drivers.bus.serial_port import TTY_INPUT_BYTES, FramedStreamReader, Scan, SerialPort
from imustation.errors import DeviceError, SettingError
from imustation.units import DEG2RAD

EOL = b"\r\n"
#: one output line without CR LF: >= 1 leading space, value, >= 1 space, flag [KVH-R], then any
#: blanks or tabs before CR LF (units in the field pad their lines; the ROS drivers split the line
#: on whitespace and accept them - a strict match counted every such line as lost)
LINE_RE = re.compile(rb" +(-?)(\d+)\.(\d{1,6}) +([01])[ \t]*")
DECIMALS = 6
COUNTS_PER_UNIT = 10**DECIMALS  # 1e-6 deg/s (or deg) per count
STATUS_VALID = 1
NOMINAL_RATE_HZ = 100.0  # [KVH-M] ~100 outputs/s, +-2-3 % unit to unit
#: mode -> command letter; sent three times as the ROS driver does [KVH-R]
MODE_COMMANDS = {"rate": b"R", "incremental_angle": b"A"}
COMMAND_REPEAT = 3
MODE_SETTLE_S = 0.05  # lines already on the wire in the old mode are discarded
OPEN_TIMEOUT_S = 3.0  # a valid line must arrive within this (start-up lines carry flag 0)
OPEN_POLL_S = 0.05
POLL_INTERVAL_S = 0.2  # 20 lines, ~400 bytes: far below any tty buffer
#: the unit's rate may be this much above rate_hz (+-2-3 % unit to unit [KVH-M]): its lines fill a buffer sooner
RATE_MARGIN = 1.03


def parse_line(line: bytes) -> tuple[int, int] | None:
    """A line without CR LF -> ``(counts of 1e-6 unit, flag)``, or None if malformed."""
    m = LINE_RE.fullmatch(line)
    if m is None:
        return None
    sign, whole, frac, flag = m.groups()
    counts = int(whole) * COUNTS_PER_UNIT + int(frac.ljust(DECIMALS, b"0"))
    return (-counts if sign else counts), int(flag)


class LineReader(FramedStreamReader):
    """CR LF-terminated DSP-3000 lines; the first piece after a (re)start is a partial line."""

    def __init__(self) -> None:
        super().__init__(max_pending=256)
        self.synced = False

    def reset(self) -> None:
        super().reset()
        self.synced = False

    def scan(self, buf: bytes) -> tuple[Scan, int]:
        parts = buf.split(EOL)
        consumed = len(buf) - len(parts[-1])
        lines = parts[:-1]
        if not self.synced and lines:
            lines = lines[1:]  # joined mid-line: not an error
            self.synced = True
        counts, flags, garbage, bad_lines = [], [], 0, 0
        for line in lines:
            parsed = parse_line(line)
            if parsed is None:
                garbage += len(line) + len(EOL)
                bad_lines += 1
                continue
            counts.append(parsed[0])
            flags.append(parsed[1])
        frames = (np.array(counts, dtype=np.int64), np.array(flags, dtype=np.int8))
        return Scan(frames, garbage, 0, {"bad_lines": bad_lines}), consumed


class KVHDSP3000:
    """KVH DSP-3000 single-axis (z) fibre-optic gyro on RS-232.

    Parameters
    ----------
    port : the serial port (``serial:/dev/ttyUSB0?baud=38400``).
    settings : ``mode`` (``rate`` or ``incremental_angle``), ``rate_hz`` (the unit's output rate).
    sleep : delay function (the station's clock).
    """

    name: ClassVar[str] = "dsp3000"
    bus_kind: ClassVar[str] = "serial"
    default_baud: ClassVar[int] = 38400  # [KVH-M][KVH-R]
    SETTINGS: ClassVar[tuple[Setting, ...]] = (
        Setting("mode", "rate", tuple(MODE_COMMANDS), "output: rate (deg/s) or incremental angle (deg)"),
        Setting("rate_hz", NOMINAL_RATE_HZ, None, "the unit's output rate, Hz (nominal 100, +-3 %)"),
    )

    def __init__(self, port: SerialPort, settings: Mapping[str, Any], *, sleep: Sleep = time.sleep):
        self.port = port
        self.settings = self.check_settings(settings)
        self._sleep = sleep
        self.reader = LineReader()

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        out = check_settings(cls.name, cls.SETTINGS, settings)
        rate = out["rate_hz"]
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 90.0 <= rate <= 110.0:
            raise SettingError(f"rate_hz = {rate!r}: the 100 Hz DSP-3000 outputs 90 .. 110 lines/s")
        out["rate_hz"] = float(rate)
        return out

    @property
    def scale(self) -> float:
        """rad/s per count."""
        unit = DEG2RAD / COUNTS_PER_UNIT
        return unit if self.settings["mode"] == "rate" else unit * self.settings["rate_hz"]

    def open(self) -> DriverInfo:
        self.port.ensure_open()
        self.port.write(MODE_COMMANDS[self.settings["mode"]] * COMMAND_REPEAT)
        self._sleep(MODE_SETTLE_S)
        self.port.read_available()
        self.reader.reset()
        bad = received = lines = 0
        for _ in range(int(OPEN_TIMEOUT_S / OPEN_POLL_S)):
            self._sleep(OPEN_POLL_S)
            data = self.port.read_available()
            received += len(data)
            scan = self.reader.feed(data)
            bad += scan.extra["bad_lines"]
            lines += len(scan.frames[1]) + scan.extra["bad_lines"]
            if (scan.frames[1] == STATUS_VALID).any():
                break
        else:
            if not received:
                hint = "nothing received: cable, power?"
            elif bad or not scan.frames[1].size:
                hint = f"{received} bytes but no readable line: wrong baud rate? (38400 8N1)"
            else:
                hint = "every line flags a fault (BIT = 0)"
            raise DeviceError(
                f"{self.port.where}: DSP-3000 did not start streaming within {OPEN_TIMEOUT_S:g} s ({hint})"
            )
        mode = self.settings["mode"]
        # a line count of the bytes received (the first, partial line is not counted: a longer line is safer)
        line_bytes = received / lines if lines else float(len(EOL) + 24)
        buffer_s = TTY_INPUT_BYTES / (line_bytes * self.settings["rate_hz"] * RATE_MARGIN)
        return DriverInfo(
            model="KVH DSP-3000 (100 Hz ASCII)",
            identity="no identity query in the 100 Hz ASCII protocol",
            rate_hz=self.settings["rate_hz"],
            settings={
                "mode": mode,
                "rate_hz": self.settings["rate_hz"],
                "baud": self.port.baud,
                "counts_per_unit": COUNTS_PER_UNIT,
                "unit": "deg/s" if mode == "rate" else "deg per output",
            },
            channels=(ChannelSpec("gyro", "int32", "rad/s", self.scale, 0.0, ("z",)),),
            has_counter=False,
            poll_interval_s=POLL_INTERVAL_S,
            # no counter, and the tty drops the newest lines when its buffer is full: losses from read times
            overflow="oldest",
            buffer_s=buffer_s,
        )

    def read_block(self) -> Block:
        scan = self.reader.feed(self.port.read_available())
        counts, flags = scan.frames
        valid = flags == STATUS_VALID
        faults = int(np.count_nonzero(~valid))
        bad = scan.extra["bad_lines"]
        notes = []
        if faults:
            notes.append(f"status 0: {faults} line(s) flagged fault/start-up, not stored")
        if bad:
            notes.append(f"resync: {bad} unreadable line(s) skipped")
        gyro = counts[valid].astype(np.int32).reshape(-1, 1)
        return Block({"gyro": gyro}, lost=faults + bad, note="; ".join(notes))

    def close(self) -> None:
        self.port.close()
