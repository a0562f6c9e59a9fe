"""Which capture options go together: simulation levels, worker processes, trace, replay, rotation.

The rules live here once; the command line, :func:`~imustation.acquisition.capture`
and the :class:`~imustation.acquisition.station.Station` all ask
:func:`check_options`, so they cannot disagree. Both worker processes and the
model level need a simulation on its own virtual clock: every process then runs
its own clock, and a model-level device has no bus a trace could record.
"""

from __future__ import annotations

from imustation.errors import InputError

#: simulation levels (``capture --simulate --sim-level``): chip simulators behind the bus code,
#: or devices at the noise-model level (:mod:`~imustation.acquisition.modelsim`)
SIM_LEVELS = ("bus", "model")


def own_virtual_simulation(
    *, simulate: bool, virtual_clock: bool = True, trace: bool = False, replay: bool = False
) -> bool:
    """A simulation on its own virtual clock, without a trace being recorded or replayed."""
    return simulate and virtual_clock and not trace and not replay


def workers_possible(
    *, simulate: bool, virtual_clock: bool = True, trace: bool = False, replay: bool = False, rotate: bool = False
) -> bool:
    """Whether bus groups may be polled in worker processes (``--workers`` > 1)."""
    return own_virtual_simulation(simulate=simulate, virtual_clock=virtual_clock, trace=trace, replay=replay) and not (
        rotate
    )


def check_options(
    *,
    simulate: bool,
    sim_level: str = "bus",
    workers: int = 1,
    virtual_clock: bool = True,
    trace: bool = False,
    replay: bool = False,
    rotate: bool = False,
    cli: bool = False,
    real_time: bool = False,
) -> None:
    """Refuse a combination of capture options that cannot work, with one line naming the options.

    ``virtual_clock``: the capture runs on a virtual clock of its own (a caller that
    imposes a clock says False); ``trace``, ``replay``, ``rotate``: those options are
    given. ``cli``: the caller is the command line, where a simulation level without
    ``--simulate`` is a missing option. ``real_time``: a simulation on the host clock
    (``--real-time``). Raises :class:`~imustation.errors.InputError`.
    """
    if trace and replay:
        raise InputError("--trace and --replay exclude each other")
    if real_time:
        if not simulate:
            raise InputError("--real-time: needs --simulate (a capture of real devices runs on the host clock anyway)")
        if trace or replay:
            raise InputError("--real-time with --trace/--replay: a trace is recorded and replayed in one process")
        if workers > 1:
            raise InputError(
                f"--real-time with --workers {workers}: on the host clock every bus has a reader process of its own"
            )
        if sim_level != "bus":
            raise InputError(
                f"--real-time with --sim-level {sim_level}: only bus-level simulators run on the host clock"
            )
    if workers < 1:
        raise InputError(f"--workers {workers}: at least 1")
    if workers > 1 and rotate:
        raise InputError(
            f"--workers {workers} with --rotate: parts would not end at their times for every process; use --workers 1"
        )
    own = own_virtual_simulation(simulate=simulate, virtual_clock=virtual_clock, trace=trace, replay=replay)
    if workers > 1 and not own:
        raise InputError(
            f"--workers {workers}: only a simulated capture on its virtual clock, without --trace/--replay, "
            "uses worker processes (a capture on the host clock has a reader process per bus)"
        )
    if sim_level not in SIM_LEVELS:
        raise InputError(f"--sim-level {sim_level!r}: {' or '.join(SIM_LEVELS)}")
    if sim_level != "bus" and cli and not simulate:
        raise InputError(f"--sim-level {sim_level}: needs --simulate")
    if sim_level == "model" and not own:
        raise InputError("--sim-level model: only a simulated capture on its virtual clock, without --trace/--replay")
