"""Per-channel analyses of many runs, serially or on a dask.distributed cluster.

The unit of work is one channel of one input file, named by two strings,
``(path, channel id)``: each task opens the file itself and reads only its own
channel (no sample arrays travel through the scheduler), runs
:func:`~imustation.analysis.pipeline.channel.analyze_channel` and returns the same
:class:`~imustation.analysis.pipeline.channel.ChannelAnalysis` the serial path builds,
with the channel's samples released (a few kB: Allan curve, fits, verdict). So
the JSON of a parallel analysis is identical to the serial one.

A task that fails (missing or corrupt file, bad channel, worker killed for
exceeding its memory limit) becomes a :class:`TaskFailure`; the others finish.
A degenerate channel (constant, saturated, stuck, all quantisation) is a failure
marked ``skipped`` with its kind.
Results come back in task order whatever the completion order.

With ``threads_per_worker=1`` a worker runs one task at a time, so the worker's
memory limit bounds the memory of a task (one channel: about 13 bytes per
sample at the peak over the imports, e.g. +217 MiB for 12 h at 400 Hz; docs/fleet.md).
"""

from __future__ import annotations

import contextlib
import glob
import logging
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

from imustation.analysis.pipeline.channel import ChannelAnalysis, DegenerateChannel, analyze_channel
from imustation.analysis.pipeline.choices import DEFAULT_ESTIMATOR, DEFAULT_METHOD, DEFAULT_MODEL, DEFAULT_WARMUP
from imustation.analysis.pipeline.loaders import Channel, NoChannelsError, load_inputs
from imustation.analysis.pipeline.warmup import cut_channels
from imustation.errors import ImustationError, InputError
from imustation.runfile import join_parts

#: environment of local worker processes: one compute thread each (numba, OpenMP, BLAS)
SINGLE_THREAD_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}
#: seconds to wait for an existing scheduler to answer
CONNECT_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class ChannelTask:
    """One channel of one input: ``path`` as given, ``channel`` its id (``device/gyro/z``).

    ``data``: the channel itself when it is already in memory (a field recording streamed by
    the importer, which has no file to read it back from); a cluster then ships its samples
    to the worker. None: the task reads its channel from ``path``.
    """

    path: str
    channel: str
    data: Channel | None = None


@dataclass(frozen=True)
class TaskFailure:
    """A run (``channel`` None: it could not be opened or listed) or one channel that failed."""

    path: str
    channel: str | None
    error: str
    #: set when the channel was skipped as degenerate: "constant", "saturated", "stuck", "quantisation"
    skipped: str | None = None

    def as_dict(self) -> dict:
        out = {"source": self.path, "channel": self.channel, "error": self.error}
        if self.skipped:
            out["skipped"] = self.skipped
        return out


@dataclass(frozen=True)
class AnalysisOptions:
    """Options of :func:`analyze_channel` plus the sampling rate of plain arrays (Hz)."""

    pattern: str | None = None
    m: int = 1000
    model: str = DEFAULT_MODEL
    compare: tuple[str, ...] = ()
    method: str = DEFAULT_METHOD
    rate_hz: float | None = None
    estimator: str = DEFAULT_ESTIMATOR
    #: parameters the "enough data?" verdict judges (None: the model's sigma_w, sigma_b, tau_b)
    need: tuple[str, ...] | None = None
    #: ``--warmup``: the start of each run-file device's record left out (:mod:`.warmup`)
    warmup: str = DEFAULT_WARMUP


def _message(path: str, channel: str | None, exc: BaseException) -> str:
    if isinstance(exc, ImustationError):
        return str(exc)
    where = f"{path} {channel}" if channel else path
    return f"{where}: {type(exc).__name__}: {exc}"


def plan_tasks(
    paths: Sequence[str], globs: Sequence[str] = (), rate_hz: float | None = None
) -> tuple[list[ChannelTask], list[TaskFailure]]:
    """One task per selected channel of every input (metadata only); inputs that cannot be listed fail.

    As in the serial path, an input with no channel matching ``globs`` adds no
    task and no failure; :class:`NoChannelsError` when no input has any.
    """
    tasks: list[ChannelTask] = []
    failures: list[TaskFailure] = []
    for path in join_parts(paths):  # a rotated capture's parts: one input
        try:
            channels = load_inputs([path], globs, rate_hz)
        except NoChannelsError:
            if not globs:
                failures.append(TaskFailure(path, None, f"{path}: no gyro/accel channels"))
            continue
        except Exception as exc:  # noqa: BLE001 - any unreadable run is reported, the rest go on
            failures.append(TaskFailure(path, None, _message(path, None, exc)))
            continue
        tasks += [ChannelTask(path, ch.id) for ch in channels]
    if not tasks and not failures:
        sel = f" matching {', '.join(globs)}" if globs else ""
        raise NoChannelsError(f"no channels{sel} in {', '.join(paths)}")
    return tasks, failures


def _limit_numba_threads() -> None:
    """Honour NUMBA_NUM_THREADS in this thread: a dask worker imports numba before the worker's
    environment is applied (it then runs the parallel Allan kernels on every core: 2 workers
    oversubscribe 2 cores, measured), and numba's thread count is per calling thread."""
    want = os.environ.get("NUMBA_NUM_THREADS")
    if not want:
        return
    import numba

    if numba.get_num_threads() > int(want):
        numba.set_num_threads(min(int(want), numba.config.NUMBA_NUM_THREADS))


def tasks_of_channels(channels: Sequence[Channel]) -> list[ChannelTask]:
    """Tasks that analyse channels already in memory (see :class:`ChannelTask`)."""
    return [ChannelTask(ch.source, ch.id, ch) for ch in channels]


def analyze_task(path: str, channel: str, options: AnalysisOptions, data: Channel | None = None) -> ChannelAnalysis:
    """Read channel ``channel`` of ``path`` (or take ``data``, the channel in memory) and analyse it;
    the result holds no samples."""
    _limit_numba_threads()
    if data is not None:
        ch = data
    else:
        picked = [ch for ch in load_inputs([path], [glob.escape(channel)], options.rate_hz) if ch.id == channel]
        if not picked:
            raise InputError(f"{path}: no channel {channel}")
        ch = picked[0]
    cut_channels([ch], options.warmup)  # the same cut every command makes (run-file channels only)
    res = analyze_channel(
        ch,
        pattern=options.pattern,
        m=options.m,
        model=options.model,
        compare=options.compare,
        method=options.method,
        estimator=options.estimator,
        need=options.need,
    )
    ch.release()  # run-file channels come back without samples (plain arrays keep theirs)
    return res


def _analyze_mapped(path: str, channel: str, data: Channel | None, options: AnalysisOptions) -> ChannelAnalysis:
    """:func:`analyze_task` with the argument order ``client.map`` gives (one iterable per task field)."""
    return analyze_task(path, channel, options, data)


#: ``on_done(done, total, failure)`` after each task; ``failure`` None when it succeeded
Progress = Callable[[int, int, "TaskFailure | None"], None]
#: ``on_task(task)`` after each task: which one finished (for a progress line naming the channel)
TaskDone = Callable[["ChannelTask"], None]


def run_tasks(
    tasks: Sequence[ChannelTask],
    options: AnalysisOptions,
    client=None,
    on_done: Progress | None = None,
    on_task: TaskDone | None = None,
) -> tuple[list[ChannelAnalysis | None], list[TaskFailure]]:
    """Analyse every task, in this process (``client`` None) or on a dask ``distributed.Client``.

    Returns the results in task order (None where the task failed) and the
    failures in task order.
    """
    results: list[ChannelAnalysis | None] = [None] * len(tasks)
    failed: dict[int, TaskFailure] = {}
    total = len(tasks)

    def done(i: int, res: ChannelAnalysis | None, exc: BaseException | None, count: int) -> None:
        fail = None
        if exc is not None:
            t = tasks[i]
            kind = exc.kind if isinstance(exc, DegenerateChannel) else None
            fail = failed[i] = TaskFailure(t.path, t.channel, _message(t.path, t.channel, exc), kind)
        else:
            results[i] = res
        if on_task is not None:
            on_task(tasks[i])
        if on_done is not None:
            on_done(count, total, fail)

    if client is None:
        for i, t in enumerate(tasks):
            try:
                res, exc = analyze_task(t.path, t.channel, options, t.data), None
            except Exception as e:  # noqa: BLE001 - reported per task
                res, exc = None, e
            done(i, res, exc, i + 1)
    else:
        from distributed import as_completed

        futures = client.map(
            _analyze_mapped,
            [t.path for t in tasks],
            [t.channel for t in tasks],
            [t.data for t in tasks],
            options=options,
            pure=False,
            retries=0,
        )
        index = {f.key: i for i, f in enumerate(futures)}
        for count, fut in enumerate(as_completed(futures, loop=client.loop), start=1):
            i = index[fut.key]
            if fut.status == "finished":
                done(i, fut.result(), None, count)
            else:
                done(i, None, fut.exception(), count)
            fut.release()
    return results, [failed[i] for i in sorted(failed)]


def execute(
    tasks: Sequence[ChannelTask],
    options: AnalysisOptions,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    memory_limit: str | float | None = "auto",
    on_start: Callable[[object | None], None] | None = None,
    on_done: Progress | None = None,
    on_task: TaskDone | None = None,
) -> tuple[list[ChannelAnalysis | None], list[TaskFailure]]:
    """Analyse every task: in this process, on a local cluster of ``workers`` processes, or on the
    cluster at ``scheduler`` -- the one path of ``analyze`` and ``fleet``.

    ``on_start(client)`` is called once the client (None when serial) is ready, ``on_done`` and
    ``on_task`` after each task (see :func:`run_tasks`). Returns the results in task order (None where a task
    failed) and the failures. Raises :class:`InputError` when both ``workers`` and ``scheduler``
    are given or the scheduler cannot be reached.
    """
    if workers and scheduler:
        raise InputError("give --workers or --scheduler, not both")
    if not tasks:
        return [], []
    with dask_client(workers, scheduler, memory_limit=memory_limit) as client:
        if on_start is not None:
            on_start(client)
        return run_tasks(tasks, options, client, on_done, on_task)


@contextlib.contextmanager
def dask_client(
    workers: int | None = None,
    scheduler: str | None = None,
    *,
    processes: bool = True,
    memory_limit: str | float | None = "auto",
    dashboard_address: str | None = ":8787",
    timeout_s: float | None = None,
) -> Iterator[object | None]:
    """A ``distributed.Client``: on an existing ``scheduler`` (``tcp://host:8786``), on a new local
    cluster of ``workers`` single-threaded worker processes, or None (serial) when neither is given.

    ``memory_limit`` is per worker, hence per task (bytes or a dask size string such as ``"2GiB"``).
    Raises :class:`InputError` when the scheduler cannot be reached within ``timeout_s``
    (default :data:`CONNECT_TIMEOUT_S`).
    """
    if scheduler:
        from distributed import Client

        try:
            client = Client(scheduler, timeout=timeout_s or CONNECT_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise InputError(f"scheduler {scheduler}: cannot connect ({type(exc).__name__}: {exc})") from None
        try:
            yield client
        finally:
            client.close()
        return
    if not workers:
        yield None
        return
    from distributed import Client, LocalCluster

    # one core per worker: numba's parallel kernels and the BLAS run single-threaded in a worker
    # process (an idle OpenBLAS thread spin-waits after each call: +20 % CPU per task, measured)
    extra = {"env": dict(SINGLE_THREAD_ENV)} if processes else {}
    cluster = LocalCluster(
        n_workers=int(workers),
        threads_per_worker=1,
        processes=processes,
        memory_limit=memory_limit,
        dashboard_address=dashboard_address,
        silence_logs=logging.ERROR,
        **extra,
    )
    client = Client(cluster, set_as_default=False)
    try:
        yield client
    finally:
        client.close()
        cluster.close()
