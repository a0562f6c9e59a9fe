"""``capture``'s live status on the terminal: a compact block redrawn in place, or plain lines in a log.

Built from the station's status document (:func:`imustation.status.capture_status`,
docs/capture.md) and nothing else: a header (state, elapsed of planned, time left,
bytes written, free disk) and one row per device (state, rate achieved / configured,
samples, gaps, samples lost, temperature), then the thermometers.

On a terminal the block fits its width and height: every line is shorter than the
width (so the terminal never wraps it), columns are dropped from the least needed
when the table is too wide, devices that are not ``ok`` come first when there are
more rows than lines, and the block is redrawn over itself (cursor up, erase to the
end of the screen). When the terminal's size changes the next block starts on a
fresh line below, since terminals differ in how they re-wrap what is on the screen.
Anywhere else (a pipe, a log file) each status is one plain line appended.

Hand-written rather than a terminal library: two escape sequences (cursor up, erase
below) and a width rule are all it needs, and it draws only when the caller hands it
a status, so tests drive every redraw under a pseudo-terminal of a chosen size.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any, TextIO

from imustation.units import format_duration

#: escape sequences (ECMA-48): cursor N lines up, erase from the cursor to the end of the screen
_UP = "\x1b[{n}A"
_ERASE_BELOW = "\x1b[J"
#: the size assumed when the stream cannot tell its own
DEFAULT_SIZE = (80, 24)
#: the rate column's window (s of station time). A status interval's window (1 s) holds a few FIFO
#: bursts, and where one falls moves the count by a burst: 429.6/400 Hz was shown for a device
#: delivering 400 Hz; over 10 s a burst moves the figure by well under 1 %, about the 0.1 Hz shown
RATE_VIEW_S = 10.0
#: with less station time than this to measure over, the rate column says it is still measuring ("…")
RATE_VIEW_MIN_S = 5.0
#: the key the view puts the rate it shows under, in its copy of each device's status
SHOWN_RATE = "rate_shown_hz"


def format_bytes(n: float) -> str:
    """``242614272`` -> ``"231.4 MiB"``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


def _celsius(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}°C"


def _clock(clock: dict[str, Any]) -> str:
    """The host clock in the header: its error when synchronised, else loud; and its steps."""
    sync, err = clock.get("sync"), clock.get("est_error_s")
    text = {"synchronised": "clock synced", "unsynchronised": "clock UNSYNCHRONISED"}.get(sync, "clock sync unknown")
    if sync == "synchronised" and err is not None:
        text += f" ±{err * 1e3:.1f} ms"
    steps = clock.get("steps") or 0
    return text + (f", STEPPED {steps}x" if steps else "")


def header(status: dict[str, Any]) -> list[str]:
    """The header's fields: state, elapsed of planned, time left, file size (and part), free disk, speed."""
    elapsed, planned = max(0.0, status["elapsed_s"]), status["duration_s"]
    state = status["state"]
    if state == "stopped" and status.get("reason"):
        state = f"stopped ({status['reason']})"
    fields = [f"{state} {format_duration(elapsed)} of {format_duration(planned)}"]
    left = status.get("remaining_s", planned - elapsed)
    if status["state"] == "recording" and left > 0:
        fields.append(f"{format_duration(left)} left")
    if status.get("file_bytes") is not None:
        part = f" (part {status['part']})" if status.get("part") else ""
        fields.append(f"{format_bytes(status['file_bytes'])} written{part}")
    if status.get("disk_free_bytes") is not None:
        fields.append(f"{format_bytes(status['disk_free_bytes'])} free")
    clock = status.get("clock")
    speed = status.get("speed")
    # the host clock where it matters (a real capture) and needs a look: not synchronised, or stepped
    if clock and (speed is None or speed <= 1.5) and (clock.get("sync") != "synchronised" or clock.get("steps")):
        fields.append(_clock(clock))
    if speed is not None and speed > 1.5:  # a simulation: virtual time runs faster
        fields.append(f"{speed:.0f}x real time")
    return fields


#: the device table's columns, most needed first: (title, right-aligned, cell of a device's status)
COLUMNS: tuple[tuple[str, bool, Callable[[str, dict[str, Any]], str]], ...] = (
    ("device", False, lambda name, d: name),
    ("rate/cfg Hz", True, lambda name, d: f"{_rate(d)}/{d['rate_cfg_hz']:g}"),
    ("gaps", True, lambda name, d: str(d["gaps"])),
    ("state", False, lambda name, d: d["state"] if d["state"] == "ok" else d["state"].upper()),
    ("lost", True, lambda name, d: str(d["lost"])),
    ("temp", True, lambda name, d: _celsius(d.get("temp_c"))),
    ("samples", True, lambda name, d: str(d["samples"])),
)
#: the order the columns are shown in (when kept)
SHOWN = ("device", "state", "rate/cfg Hz", "samples", "gaps", "lost", "temp")


def _rate(d: dict[str, Any]) -> str:
    """The rate shown (:func:`with_rates`): one decimal, "…" while there is too little time to tell."""
    r = d.get(SHOWN_RATE)
    return "…" if r is None else f"{r:.1f}"


def with_rates(status: dict[str, Any], history: dict[str, list[tuple[float, int]]] | None = None) -> dict[str, Any]:
    """``status`` with each device's rate to show (:data:`SHOWN_RATE`, Hz, None = still measuring): the samples
    over the last :data:`RATE_VIEW_S` of station time when ``history`` (per device, ``(elapsed s, samples)``
    of earlier statuses, oldest first; updated here) spans at least :data:`RATE_VIEW_MIN_S`; else the run's
    own rate (``rate_hz``: samples over its station time) once the run is that long, or has ended; never the
    status interval's ``rate_recent_hz`` alone (a window of a few FIFO bursts)."""
    elapsed = float(status.get("elapsed_s") or 0.0)
    ended = status.get("state") in ("done", "stopped")
    devices = {}
    for name, d in status.get("devices", {}).items():
        shown = d.get("rate_hz") if ended or elapsed >= RATE_VIEW_MIN_S else None
        if history is not None and not ended:
            h = history.setdefault(name, [])
            if h and (elapsed < h[-1][0] or d["samples"] < h[-1][1]):
                h.clear()  # a new run (resume) or a restarted count: measure afresh
            h.append((elapsed, int(d["samples"])))
            while len(h) > 2 and elapsed - h[1][0] >= RATE_VIEW_S:
                h.pop(0)
            span = elapsed - h[0][0]
            if span >= RATE_VIEW_MIN_S:
                shown = (h[-1][1] - h[0][1]) / span
        devices[name] = {**d, SHOWN_RATE: shown}
    return {**status, "devices": devices}


def _table(devices: Sequence[tuple[str, dict[str, Any]]], width: int) -> list[str]:
    """The device rows with their title row, dropping the least needed columns until they fit ``width``."""
    kept = list(COLUMNS)
    while True:
        cols = sorted(kept, key=lambda c: SHOWN.index(c[0]))
        cells = [[c[0] for c in cols]] + [[c[2](name, d) for c in cols] for name, d in devices]
        widths = [max(len(row[k]) for row in cells) for k in range(len(cols))]
        total = sum(widths) + 2 * (len(cols) - 1)
        if total <= width or len(kept) <= 2:
            break
        kept.pop()
    return [
        "  ".join(
            cell.rjust(w) if c[1] else cell.ljust(w) for cell, w, c in zip(row, widths, cols, strict=True)
        ).rstrip()
        for row in cells
    ]


def _thermometers(status: dict[str, Any]) -> str:
    parts = []
    for name, t in status.get("thermometers", {}).items():
        c = "-" if t.get("celsius") is None else f"{t['celsius']:.2f}°C"
        parts.append(f"{name} {c}" + ("" if t.get("state", "ok") == "ok" else " FAILED"))
    return "thermometers: " + "  ".join(parts) if parts else ""


def _summary(devices: Sequence[tuple[str, dict[str, Any]]], what: str = "devices") -> str:
    """Devices in one line: how many, those not ok, gaps and samples lost."""
    bad = [f"{name} {d['state'].upper()}" for name, d in devices if d["state"] != "ok"]
    gaps, lost = sum(d["gaps"] for _, d in devices), sum(d["lost"] for _, d in devices)
    return f"{len(devices)} {what}, " + (", ".join(bad) if bad else "all ok") + f"; gaps {gaps}, lost {lost}"


def _fit(line: str, width: int) -> str:
    return line if len(line) <= width else line[: max(0, width - 1)] + "…"


def _wrap(fields: Sequence[str], width: int) -> list[str]:
    """``fields`` joined by two spaces into lines of at most ``width`` (a field is never split)."""
    lines: list[str] = []
    for f in fields:
        if lines and len(lines[-1]) + 2 + len(f) <= width:
            lines[-1] += "  " + f
        else:
            lines.append(f)
    return lines


def status_block(status: dict[str, Any], width: int, height: int) -> list[str]:
    """The block for a terminal of ``width`` x ``height`` characters: at most ``height - 1`` lines, each
    shorter than ``width`` (the last column and the last line stay free, so nothing wraps or scrolls).

    The header takes a second line when it does not fit the width and the devices leave room;
    with fewer lines than devices, those not ``ok`` are shown first and the rest counted; with
    no room for a table, one line sums the devices up.
    """
    width, free = max(1, width - 1), max(1, height - 1)
    status = status if _has_rates(status) else with_rates(status)
    devices = list(status.get("devices", {}).items())
    therm = _thermometers(status)
    head = _wrap(header(status), width)
    tail = [therm] if therm and free > 1 else []
    if len(head) > 1 and free - len(head) - len(tail) < min(len(devices), 3) + 1:
        head = ["  ".join(head)]  # no room for two header lines: one, cut at the width
    room = free - len(head) - len(tail)  # for the table (title row + devices + a "more" line)
    if not devices:
        body: list[str] = []
    elif room >= min(len(devices), 2) + 1:
        shown, more = devices, []
        if len(devices) + 1 > room:
            # devices that need attention first, in config order within each group
            order = sorted(range(len(devices)), key=lambda k: (devices[k][1]["state"] == "ok", k))
            keep = sorted(order[: room - 2])
            shown = [devices[k] for k in keep]
            rest = [d for k, d in enumerate(devices) if k not in keep]
            more = ["… " + _summary(rest, "more devices")]
        body = _table(shown, width) + more
    else:
        body = [_summary(devices)]
    return [_fit(line, width) for line in head + body + tail][:free]


def _has_rates(status: dict[str, Any]) -> bool:
    return all(SHOWN_RATE in d for d in status.get("devices", {}).values())


def status_line(status: dict[str, Any]) -> str:
    """The whole status as one plain line (a log, a pipe)."""
    status = status if _has_rates(status) else with_rates(status)
    parts = [", ".join(header(status))]
    for name, d in status.get("devices", {}).items():
        state = "" if d["state"] == "ok" else f" {d['state'].upper()}"
        parts.append(
            f"{name}{state} {_rate(d)}/{d['rate_cfg_hz']:g} Hz {d['samples']} samples "
            f"gaps {d['gaps']} lost {d['lost']} {_celsius(d.get('temp_c'))}"
        )
    therm = _thermometers(status)
    return " | ".join(parts + ([therm] if therm else []))


class StatusView:
    """Shows each status handed to :meth:`show` on ``stream``: the block redrawn in place on a terminal,
    one appended line otherwise. :meth:`note` prints a message without breaking the block;
    :meth:`close` leaves the last block on the screen and moves below it."""

    def __init__(self, stream: TextIO):
        self.stream = stream
        try:
            self.tty = stream.isatty()
        except (AttributeError, ValueError):
            self.tty = False
        self._plain = False  # a stream that cannot carry the degree sign and the ellipsis gets ASCII
        encoding = getattr(stream, "encoding", None)  # None: text kept in memory
        if encoding:
            try:
                "°…".encode(encoding)
            except (LookupError, UnicodeEncodeError):
                self._plain = True
        self._drawn = 0  # lines of the block on the screen (the cursor is at the end of its last one)
        self._size: tuple[int, int] | None = None
        self._last: dict[str, Any] | None = None
        self._history: dict[str, list[tuple[float, int]]] = {}  # per device: (elapsed s, samples), for the rate

    def size(self) -> tuple[int, int]:
        """The terminal's (columns, lines), from the stream itself."""
        try:
            cols, lines = os.get_terminal_size(self.stream.fileno())
        except (AttributeError, ValueError, OSError):
            return DEFAULT_SIZE
        return (cols or DEFAULT_SIZE[0], lines or DEFAULT_SIZE[1])

    def show(self, status: dict[str, Any]) -> None:
        status = with_rates(status, self._history)
        self._last = status
        if not self.tty:
            self.stream.write(self._text(status_line(status)) + "\n")
            self.stream.flush()
            return
        size = self.size()
        lines = status_block(status, *size)
        out = self._clear(same_size=size == self._size)
        self.stream.write(out + self._text("\n".join(lines)))
        self.stream.flush()
        self._drawn, self._size = len(lines), size

    def _text(self, text: str) -> str:
        return text.replace("°C", " C").replace("…", ".") if self._plain else text

    def _clear(self, same_size: bool) -> str:
        """Escape sequences that take the cursor back to where the block began (or below it)."""
        if not self._drawn:
            return ""
        if not same_size:
            return "\n"  # the old block may have been re-wrapped: start afresh below it
        return "\r" + (_UP.format(n=self._drawn - 1) if self._drawn > 1 else "") + _ERASE_BELOW

    def note(self, message: str) -> None:
        """Print ``message`` on its own line(s); on a terminal the block is drawn again below it."""
        if self.tty and self._drawn:
            self.stream.write(self._clear(same_size=self.size() == self._size))
            self._drawn = 0
        self.stream.write(message + "\n")
        self.stream.flush()
        if self.tty and self._last is not None:
            self.show(self._last)

    def close(self) -> None:
        """End the live display: the last block stays, the cursor goes to the line after it."""
        if self.tty and self._drawn:
            self.stream.write("\n")
            self.stream.flush()
        self._drawn = 0
