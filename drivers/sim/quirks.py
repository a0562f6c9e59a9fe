"""Field quirks a chip simulator can be told to show (``[device.sim] quirks = [...]``).

A register map describes the chip as designed; parts in the field do things it does not
say, and the Linux drivers for the same parts record them in their code and history. Each
quirk here is one such behaviour, off unless named, so a test (or a lab config) can check
that a driver survives it. What each one does, and its source:
``docs/reference/conformance-invensense.md`` and ``conformance-dsp3000.md``.
"""

from __future__ import annotations

from collections.abc import Sequence

from imustation.errors import SettingError

_INVENSENSE = {
    "stuck_overflow_bit": "INT_STATUS.FIFO_OFLOW_INT reads 1 at every read, whatever the FIFO holds "
    "(Linux inv_mpu6050, commit 'fix no data on MPU6050')",
    "async_reset_tail": "FIFO_RST while FIFO_EN (0x23) routes sensors into the FIFO cuts the frame being written: "
    "its tail lands at the head of the emptied FIFO (MPU-6500: the reset is asynchronous)",
    "wake_write_loss": "register writes within the wake-up time after SLEEP is cleared are lost "
    "(Linux inv_mpu6050 waits 5-10 ms before writing)",
}
#: driver -> quirk -> what the simulator does
QUIRKS: dict[str, dict[str, str]] = {
    "mpu9150": _INVENSENSE,
    "mpu6500": _INVENSENSE,
    "dsp3000": {
        "trailing_blanks": "every line carries blanks after the status word, before CR LF "
        "(the ROS dsp3000 parser accepts them)",
    },
}
#: every quirk name some simulator knows (the config loader checks names against it)
ALL_QUIRKS = tuple(sorted({name for table in QUIRKS.values() for name in table}))


def quirks_problem(value: object) -> str | None:
    """What is wrong with a ``sim.quirks`` value, whatever the driver (``None``: nothing)."""
    names = f"a list of quirk names from {', '.join(ALL_QUIRKS)}"
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        return names
    unknown = [v for v in value if v not in ALL_QUIRKS]
    if unknown:
        return f"{names} ({unknown[0]!r} is none of them)"
    return None


def chip_quirks(driver: str, value: Sequence[str] | None) -> frozenset[str]:
    """The quirks ``sim.quirks`` asks of ``driver``'s simulator; SettingError for one it cannot show."""
    if not value:
        return frozenset()
    problem = quirks_problem(value)
    if problem:
        raise SettingError(f"sim.quirks: {problem}")
    known = QUIRKS.get(driver, {})
    for name in value:
        if name not in known:
            allowed = ", ".join(known) or "none"
            raise SettingError(f"sim.quirks: {name!r} is not a quirk of driver {driver!r} (allowed: {allowed})")
    return frozenset(value)
