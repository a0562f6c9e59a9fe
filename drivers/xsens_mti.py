"""Xsens MTi-100 series over serial: Xbus framing, configuration and MTData2 streaming.

Protocol: ``docs/reference/sensors.md`` §5 (sources there: ethz-asl xsens
driver ``mtdef.py``/``mtdevice.py`` [XS-DEF][XS-DEV], Xsens public SDK in MRPT
[XS-SDK]). A message is ``FA FF MID LEN DATA CS`` (``LEN = FF`` + u16 for long
payloads); ``CS`` makes the sum of BID..CS zero mod 256; fields are big-endian;
an acknowledgement has MID + 1.

The driver puts the device in config mode, reads its identity, sets one output
configuration (PacketCounter, SampleTimeFine, Temperature, Acceleration,
RateOfTurn, all float32, all at ``rate_hz``) and returns to measurement mode.

Storage: the MTi's output *is* IEEE float32 in SI units, so gyro (rad/s),
accel (m/s^2) and temperature (degC) are stored as float32 datasets with
scale 1 - bit for bit what the device sent, no quantisation added. The
PacketCounter (u16) is unwrapped into the run file's int64 ``counter``;
the station counts the packets a jump skipped, exactly (a message dropped
for its checksum, packets a full tty buffer dropped).
"""

from __future__ import annotations

import struct
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from imustation.channels import ChannelSpec, DriverInfo
from imustation.drivers.base import Block, Setting, Sleep, check_settings
from imustation.drivers.bus.serial_port import TTY_INPUT_BYTES, FramedStreamReader, Scan, SerialPort
from imustation.errors import DeviceError, SettingError

# --- framing (docs/reference/sensors.md §5.1) ----------------------------------------
PREAMBLE = 0xFA
BID = 0xFF  # "master device" bus identifier
EXT_LEN = 0xFF  # LEN byte announcing a u16 length
MAX_SHORT_LEN = 254  # longer payloads use the extended header [XS-DEV] write_msg
MAX_PAYLOAD = 2048  # larger lengths are taken as garbage while resynchronising

# --- message IDs (docs/reference/sensors.md §5.2 [XS-DEF]) ---------------------------
MID_REQ_DID = 0x00
MID_DEVICE_ID = 0x01
MID_GOTO_MEASUREMENT = 0x10
MID_REQ_FW_REV = 0x12
MID_REQ_PRODUCT_CODE = 0x1C
MID_GOTO_CONFIG = 0x30
MID_MTDATA2 = 0x36
MID_WAKEUP = 0x3E
MID_WAKEUP_ACK = 0x3F  # the host's answer to WakeUp keeps the device in config state, §5.2
MID_RESET = 0x40
MID_ERROR = 0x42
MID_SET_OUTPUT_CONFIG = 0xC0
ERROR_TEXT = {4: "invalid or not implemented message", 32: "baud rate out of range", 33: "invalid parameter"}

# --- data identifiers (docs/reference/sensors.md §5.3 [XS-SDK]) -----------------------
ID_TEMPERATURE = 0x0810
ID_PACKET_COUNTER = 0x1020
ID_SAMPLE_TIME_FINE = 0x1060
ID_ACCELERATION = 0x4020
ID_RATE_OF_TURN = 0x8020
ID_STATUS_WORD = 0xE020
PRECISION_MASK = 0x0003  # bits1:0: 00 float32, 01 fp12.20, 10 fp16.32, 11 float64
FREQ_EVERY_PACKET = 0xFFFF  # for counters/time stamps (recorded configurations; UNCONFIRMED)
#: SampleTimeFine tick, s (10 kHz; UNCONFIRMED in docs/reference/sensors.md §5.3)
SAMPLE_TIME_FINE_TICK_S = 1e-4
#: the device's internal rate the output rates divide ([XS-DEV-N] max 2000 Hz for acc/gyro)
BASE_RATE_HZ = 2000


@dataclass(frozen=True)
class Item:
    data_id: int
    size: int
    fmt: str  # numpy big-endian dtype of the content
    count: int


#: MTData2 content per data ID (float32 precision)
ITEMS = {
    ID_PACKET_COUNTER: Item(ID_PACKET_COUNTER, 2, ">u2", 1),
    ID_SAMPLE_TIME_FINE: Item(ID_SAMPLE_TIME_FINE, 4, ">u4", 1),
    ID_TEMPERATURE: Item(ID_TEMPERATURE, 4, ">f4", 1),
    ID_ACCELERATION: Item(ID_ACCELERATION, 12, ">f4", 3),
    ID_RATE_OF_TURN: Item(ID_RATE_OF_TURN, 12, ">f4", 3),
    ID_STATUS_WORD: Item(ID_STATUS_WORD, 4, ">u4", 1),
}
#: what the driver asks for, in this order (the device sends items in configuration order)
LAYOUT = (ID_PACKET_COUNTER, ID_SAMPLE_TIME_FINE, ID_TEMPERATURE, ID_ACCELERATION, ID_RATE_OF_TURN)

# --- timing ------------------------------------------------------------------------
REPLY_TIMEOUT_S = 1.0
REPLY_POLL_S = 0.01
#: reads that empty the tty before a request (each takes all that waits; the line refills it slowly)
DISCARD_READS = 8
COMMAND_TRIES = 3  # GoToConfig may be lost in a full line of MTData2 [XS-DEV] retries
BITS_PER_BYTE = 10  # 8N1
#: the MTi's factory baud rate, which the driver assumes when the bus URL names none ([XS-DEV] driver default)
FACTORY_BAUD = 115200
#: output rates the device divides its 2000 Hz base rate into, Hz
RATES_HZ = (10, 20, 25, 40, 50, 80, 100, 200, 250, 400, 500, 1000, 2000)


def checksum(body: bytes) -> int:
    """Xbus checksum of BID..last data byte: sum(BID..CS) = 0 mod 256 (§5.1)."""
    return -sum(body) & 0xFF


def encode(mid: int, payload: bytes = b"") -> bytes:
    """One Xbus message, extended length header when the payload exceeds 254 bytes."""
    n = len(payload)
    head = bytes([BID, mid, n]) if n <= MAX_SHORT_LEN else bytes([BID, mid, EXT_LEN, n >> 8, n & 0xFF])
    return bytes([PREAMBLE]) + head + payload + bytes([checksum(head + payload)])


@dataclass(frozen=True)
class Message:
    mid: int
    payload: bytes


def parse_stream(buf: bytes) -> tuple[list[Message], int, int, int]:
    """Split ``buf`` into Xbus messages, resynchronising after garbage.

    Returns ``(messages, consumed, garbage_bytes, bad_checksums)``; bytes after
    ``consumed`` may start a message still arriving.
    """
    out: list[Message] = []
    i, n, garbage, bad = 0, len(buf), 0, 0
    while True:
        j = buf.find(PREAMBLE, i)
        if j < 0:
            garbage += n - i
            return out, n, garbage, bad
        garbage += j - i
        i = j
        if n - i < 4:
            break
        if buf[i + 1] != BID:
            garbage, i = garbage + 1, i + 1
            continue
        length, head = buf[i + 3], 4
        if length == EXT_LEN:
            if n - i < 6:
                break
            length, head = int.from_bytes(buf[i + 4 : i + 6], "big"), 6
        if length > MAX_PAYLOAD:
            garbage, i = garbage + 1, i + 1
            continue
        end = i + head + length + 1
        if end > n:
            break
        if sum(buf[i + 1 : end]) & 0xFF:
            bad, garbage, i = bad + 1, garbage + 1, i + 1
            continue
        out.append(Message(buf[i + 2], bytes(buf[i + head : end - 1])))
        i = end
    return out, i, garbage, bad


def parse_mtdata2(payload: bytes) -> dict[int, bytes]:
    """MTData2 payload -> {data ID: content bytes} (``ID(u16) size(u8) data``, §5.3)."""
    out, i = {}, 0
    while i + 3 <= len(payload):
        data_id, size = struct.unpack_from(">HB", payload, i)
        if i + 3 + size > len(payload):
            raise DeviceError(f"MTData2 item 0x{data_id:04X} of {size} bytes overruns the message")
        out[data_id] = payload[i + 3 : i + 3 + size]
        i += 3 + size
    return out


def decode_item(data_id: int, content: bytes) -> np.ndarray:
    """One item's values (float32 precision or integer); precision bits other than float32 are refused."""
    base = data_id & ~PRECISION_MASK
    item = ITEMS.get(base)
    if item is None or data_id & PRECISION_MASK:
        raise DeviceError(f"MTData2 item 0x{data_id:04X}: not a float32/integer item this driver decodes")
    return np.frombuffer(content, dtype=item.fmt, count=item.count)


def output_configuration(rate_hz: int) -> bytes:
    """SetOutputConfiguration payload: (ID, frequency) per item of ``LAYOUT``."""
    every = (ID_PACKET_COUNTER, ID_SAMPLE_TIME_FINE)
    return b"".join(struct.pack(">HH", i, FREQ_EVERY_PACKET if i in every else rate_hz) for i in LAYOUT)


def frame_length(layout: tuple[int, ...] = LAYOUT) -> int:
    """Bytes of one MTData2 message of ``layout``: header, items (ID, size, content), checksum (§5.1)."""
    return 4 + sum(3 + ITEMS[i].size for i in layout) + 1


def fastest_rate(baud: int, layout: tuple[int, ...] = LAYOUT) -> int | None:
    """The fastest output rate (Hz) whose MTData2 messages fit ``baud`` (8N1); None when none does."""
    fits = [r for r in RATES_HZ if frame_length(layout) * BITS_PER_BYTE * r <= baud]
    return max(fits) if fits else None


#: default output rate: the fastest the factory baud rate carries (200 Hz: 54 bytes x 10 bits x 200 =
#: 108 kbit/s of 115.2), so a config that names only the bus works on a device as delivered
DEFAULT_RATE_HZ = fastest_rate(FACTORY_BAUD)


class MTData2Reader(FramedStreamReader):
    """Vectorised reader of MTData2 messages of one fixed layout.

    Candidate starts are found with numpy (``FA FF 36 LEN``), checksums are
    tested for all at once, then a greedy pass keeps non-overlapping valid
    frames; everything else is garbage. Bytes between frames are re-parsed
    with :func:`parse_stream` so a WakeUp or Error message is not missed.
    """

    def __init__(self, layout: tuple[int, ...] = LAYOUT):
        super().__init__(max_pending=4096)
        self.layout = layout
        payload = sum(3 + ITEMS[i].size for i in layout)
        self.frame_len = frame_length(layout)
        template = np.zeros(self.frame_len, dtype=np.int64)
        fixed = [0, 1, 2, 3]
        template[:4] = (PREAMBLE, BID, MID_MTDATA2, payload)
        self.offsets: dict[int, int] = {}
        at = 4
        for i in layout:
            template[at : at + 3] = (i >> 8, i & 0xFF, ITEMS[i].size)
            fixed += [at, at + 1, at + 2]
            self.offsets[i] = at + 3
            at += 3 + ITEMS[i].size
        self._fixed = np.array(fixed)
        self._fixed_vals = template[self._fixed]

    def scan(self, buf: bytes) -> tuple[Scan, int]:
        a = np.frombuffer(buf, dtype=np.uint8)
        L, n = self.frame_len, len(a)
        if n < L:
            return Scan(np.zeros((0, L), np.uint8)), 0
        last = n - L  # the last complete start
        h = self._fixed_vals
        cand = np.flatnonzero(
            (a[: last + 1] == h[0]) & (a[1 : last + 2] == h[1]) & (a[2 : last + 3] == h[2]) & (a[3 : last + 4] == h[3])
        )
        starts = np.zeros(0, dtype=np.int64)
        bad = 0
        if cand.size:
            cs = np.concatenate(([0], np.cumsum(a, dtype=np.int64)))
            ok = (cs[cand + L] - cs[cand + 1]) & 0xFF == 0
            rows = a[cand[:, None] + self._fixed]
            ok &= (rows == h).all(axis=1)
            valid = cand[ok]
            if valid.size and (np.diff(valid) >= L).all():
                starts = valid  # the usual case: no overlaps to resolve
            else:
                pos, chosen = 0, []
                for p in valid.tolist():
                    if p >= pos:
                        chosen.append(p)
                        pos = p + L
                starts = np.array(chosen, dtype=np.int64)
            # damaged candidates, except chance header bytes inside an accepted frame
            damaged = cand[~ok]
            if starts.size and damaged.size:
                idx = np.searchsorted(starts, damaged, side="right") - 1
                covered = (idx >= 0) & (damaged < starts[np.maximum(idx, 0)] + L)
                bad = int(np.count_nonzero(~covered))
            else:
                bad = int(damaged.size)
        end = int(starts[-1]) + L if starts.size else 0
        consumed = max(end, last + 1)
        frames = a[starts[:, None] + np.arange(L)]
        garbage = consumed - len(starts) * L
        gaps = []
        if garbage:
            prev = 0
            for p in [*starts.tolist(), consumed]:
                if p > prev:
                    gaps.append(bytes(buf[prev:p]))
                prev = p + L if p != consumed else p
        return Scan(frames, garbage, bad, {"gaps": gaps}), consumed

    def column(self, frames: np.ndarray, data_id: int) -> np.ndarray:
        item = ITEMS[data_id]
        at = self.offsets[data_id]
        raw = np.ascontiguousarray(frames[:, at : at + item.size]).view(item.fmt)
        out = raw.astype(item.fmt[1:])  # native byte order
        return out if item.count > 1 else out[:, 0]


class XsensMTi:
    """Xsens MTi-100 series streaming MTData2 (rate of turn, acceleration, temperature).

    Parameters
    ----------
    port : the serial port (``serial:/dev/ttyUSB0?baud=921600``).
    settings : ``rate_hz`` (output rate, a divisor of 2000 Hz; default :data:`DEFAULT_RATE_HZ`, the
        fastest the factory baud rate carries).
    sleep : delay function (the station's clock).
    """

    name: ClassVar[str] = "mti"
    bus_kind: ClassVar[str] = "serial"
    default_baud: ClassVar[int] = FACTORY_BAUD
    SETTINGS: ClassVar[tuple[Setting, ...]] = (Setting("rate_hz", DEFAULT_RATE_HZ, RATES_HZ, "output rate, Hz"),)

    def __init__(self, port: SerialPort, settings: Mapping[str, Any], *, sleep: Sleep = time.sleep):
        self.port = port
        self.settings = self.check_settings(settings)
        self._sleep = sleep
        self.reader = MTData2Reader()
        self._count: int | None = None  # unwrapped counter of the last packet
        self._buf = b""

    @classmethod
    def check_settings(cls, settings: Mapping[str, Any]) -> dict[str, Any]:
        return check_settings(cls.name, cls.SETTINGS, settings)

    # -- request / reply ---------------------------------------------------------------
    def request(self, mid: int, payload: bytes = b"", *, tries: int = 1) -> bytes:
        """Send a message and return the payload of its acknowledgement (MID + 1)."""
        want = mid + 1
        for _ in range(tries):
            # What waits in the tty is stale stream data, and after an overflow (a host that did not
            # read for a while: the kernel dropped the rest) it ends in a cut frame whose length
            # field would swallow the acknowledgement; a reply is looked for in fresh bytes only.
            self._discard_input()
            self.port.write(encode(mid, payload))
            for _ in range(int(REPLY_TIMEOUT_S / REPLY_POLL_S)):
                self._sleep(REPLY_POLL_S)
                buf = self._buf + self.port.read_available()
                messages, used, _garbage, _bad = parse_stream(buf)
                self._buf = buf[used:]
                for m in messages:
                    if m.mid == want:
                        return m.payload
                    if m.mid == MID_ERROR:
                        code = m.payload[0] if m.payload else -1
                        text = ERROR_TEXT.get(code, "unknown error")
                        raise DeviceError(
                            f"{self.port.where}: MTi answered message 0x{mid:02X} with error {code} ({text})"
                        )
        raise DeviceError(f"{self.port.where}: no acknowledgement of message 0x{mid:02X} from the MTi")

    def _discard_input(self) -> None:
        """Drop what the tty holds and any partial message kept from it."""
        for _ in range(DISCARD_READS):
            if not self.port.read_available():
                break
        self._buf = b""

    def open(self) -> DriverInfo:
        rate = int(self.settings["rate_hz"])
        need = self.reader.frame_len * BITS_PER_BYTE * rate
        if need > self.port.baud:
            fits = fastest_rate(self.port.baud, self.reader.layout)
            raise SettingError(
                f"rate_hz = {rate}: {self.reader.frame_len}-byte MTData2 messages need {need} bit/s, "
                f"more than {self.port.baud} baud; "
                + (f"rate_hz = {fits} or less fits it, or " if fits else "")
                + "configure the MTi and the bus URL for a faster baud rate"
            )
        self.port.ensure_open()
        self.reader.reset()
        self._buf = b""
        self.request(MID_GOTO_CONFIG, tries=COMMAND_TRIES)
        (device_id,) = struct.unpack(">I", self.request(MID_REQ_DID)[:4])
        product = self.request(MID_REQ_PRODUCT_CODE).rstrip(b"\0 ").decode("ascii", "replace")
        fw = self.request(MID_REQ_FW_REV)
        firmware = ".".join(str(b) for b in fw[:3])
        self.request(MID_SET_OUTPUT_CONFIG, output_configuration(rate))
        self.request(MID_GOTO_MEASUREMENT)
        self.reader.reset()
        self._count = None
        return DriverInfo(
            model=f"Xsens {product}",
            identity=f"device_id={device_id:08X} firmware={firmware}",
            rate_hz=float(rate),
            settings={
                "rate_hz": float(rate),
                "baud": self.port.baud,
                "precision": "float32",
                "output_configuration": output_configuration(rate).hex(" "),
                "sample_time_fine_tick_s": SAMPLE_TIME_FINE_TICK_S,
            },
            channels=(
                ChannelSpec("gyro", "float32", "rad/s", 1.0, 0.0, ("x", "y", "z")),
                ChannelSpec("accel", "float32", "m/s^2", 1.0, 0.0, ("x", "y", "z")),
                ChannelSpec("temp", "float32", "degC", 1.0, 0.0),
                ChannelSpec("sample_time_fine", "uint32", "s", SAMPLE_TIME_FINE_TICK_S),
            ),
            has_counter=True,
            poll_interval_s=0.1,
            # the counter counts what the tty drops when its buffer is full (the newest messages)
            overflow="oldest",
            buffer_s=TTY_INPUT_BYTES / (self.reader.frame_len * rate),
        )

    # -- streaming -------------------------------------------------------------------------
    def read_block(self) -> Block:
        scan = self.reader.feed(self.port.read_available())
        for gap in scan.extra.get("gaps", ()):
            for m in parse_stream(gap)[0]:
                if m.mid == MID_WAKEUP:
                    raise DeviceError(f"{self.port.where}: MTi sent WakeUp: it reset and lost its configuration")
                if m.mid == MID_MTDATA2:
                    raise DeviceError(f"{self.port.where}: MTData2 of another layout: output configuration lost")
                if m.mid == MID_ERROR:
                    code = m.payload[0] if m.payload else -1
                    raise DeviceError(f"{self.port.where}: MTi error {code} ({ERROR_TEXT.get(code, 'unknown')})")
        frames = scan.frames
        r = self.reader
        counter16 = r.column(frames, ID_PACKET_COUNTER).astype(np.int64)
        if len(counter16):
            # unwrapped; the station counts the packets a jump skipped (a dropped message, a full tty)
            prev = self._count if self._count is not None else int(counter16[0]) - 1
            steps = np.diff(np.concatenate(([prev & 0xFFFF], counter16))) % 65536
            steps[steps == 0] = 65536  # the same counter again = a full wrap
            counter = prev + np.cumsum(steps)
            self._count = int(counter[-1])
        else:
            counter = counter16
        notes = []
        if scan.bad_checksums:
            notes.append(f"checksum: {scan.bad_checksums} bad message(s) dropped")
        if scan.garbage and not scan.bad_checksums:
            notes.append(f"resync: {scan.garbage} bytes skipped")
        return Block(
            {
                "gyro": r.column(frames, ID_RATE_OF_TURN),
                "accel": r.column(frames, ID_ACCELERATION),
                "temp": r.column(frames, ID_TEMPERATURE),
                "sample_time_fine": r.column(frames, ID_SAMPLE_TIME_FINE),
            },
            counter=counter,
            note="; ".join(notes),
        )

    def close(self) -> None:
        self.port.close()
