"""Stop signals of ``imustation capture``, recorded from the command's first line.

Python's own SIGINT handler raises ``KeyboardInterrupt`` wherever the main thread
happens to be - inside an import, or inside a finaliser, where it is printed as
"Exception ignored" and swallowed (the capture then records on until killed) - and
SIGTERM's default action ends the process with nothing written. A capture must
instead finish its file, so the command's entry point (``imustation.__main__``)
calls :func:`record` before it imports anything heavy: from then on SIGINT and
SIGTERM only append their number to :data:`received`, which the capture reads
once its own handlers are in place (``early_stop``). Only ``capture`` does this:
every other command keeps Ctrl-C as an interrupt.

This module imports nothing but :mod:`signal` and :mod:`threading`: it must be
ready within milliseconds of the interpreter's start.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Sequence

#: the signals an operator (or systemd) stops a capture with
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: stop signals received since :func:`record`, in order
received: list[int] = []
_recording = False


def _handler(signum: int, frame: object) -> None:  # noqa: ARG001 - signal handler signature
    received.append(signum)


def record() -> list[int]:
    """From now on, SIGINT and SIGTERM are appended to :data:`received` (main thread only; idempotent)."""
    global _recording
    if not _recording and threading.current_thread() is threading.main_thread():
        for sig in STOP_SIGNALS:
            signal.signal(sig, _handler)
        _recording = True
    return received


def recording() -> bool:
    """Whether :func:`record` holds the stop signals in this process."""
    return _recording


def is_capture(argv: Sequence[str]) -> bool:
    """Whether a command line (without the program name) runs ``capture``: its first word that is not an
    option (``imustation --debug capture ...``)."""
    return next((a for a in argv if not a.startswith("-")), None) == "capture"
