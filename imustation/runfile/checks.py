"""Validation of a run file on read: every reader gets a sound file or one line saying why not.

:func:`check_structure` runs once when :func:`imustation.runfile.open_run` opens a
file. It visits every object the readers use (root, ``/devices/*``,
``/thermometers/*``, ``/events`` and their attributes), so damaged metadata
fails here, as one :class:`~imustation.errors.RunFileError`, instead of as an
h5py traceback somewhere in a reader. Data chunks are not read (a 12 h file
holds hundreds of MB); a damaged chunk fails when it is read, through
:class:`CheckedDataset`, with the same kind of one-line error.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import math
import os
from collections.abc import Callable, Iterator
from typing import Any

import h5py
import numpy as np
from h5py import h5d

from imustation.errors import RunFileError
from imustation.runfile.rate import (  # noqa: F401 - RATE_FLOOR, RATE_SIGMAS: the reader's rule, named here too
    RATE_FLOOR,
    RATE_SIGMAS,
    WINDOW_ROWS,
    confirmed,
    probe_windows,
    span_rate,
    windows_rate,
)
from imustation.runfile.schema import (
    CELSIUS,
    COUNTER,
    DEVICES,
    EVENT_KINDS,
    EVENTS,
    FORMAT,
    FORMAT_VERSION,
    IMPORT_DRIVER,
    THERMOMETERS,
    TIME,
    Event,
)

#: rows by which the datasets of one device may differ in a file cut off during a flush
#: (a flush writes at most the writer's max_buffer_rows, 2^20, plus one block)
TORN_ROWS_MAX = 1 << 21
#: highest sample rate a run file may state, Hz (no inertial sensor comes near it)
MAX_RATE_HZ = 1e6
#: rate_hz and the rate its timestamps show (probed across the record) may differ by at most this factor;
#: beyond it the file is refused (the stamps or the rate are not what the file says)
RATE_TOLERANCE = 1.33
#: within it, a rate is corrected to the stamps' (with a RateCorrected warning) only where the whole
#: record contradicts it (:func:`.rate.confirmed`: RATE_SIGMAS, RATE_FLOOR)
#: timestamps of a window the rate is probed in (:func:`.rate.probe_windows`: windows spread over the
#: whole record); a record of fewer than RATE_MIN_ROWS is not checked
RATE_PROBE_ROWS = WINDOW_ROWS - 1
RATE_MIN_ROWS = 64
#: a rate whose period fewer than this fraction of the positive steps are near contradicts the stamps
RATE_MIN_REGULAR = 0.1
#: largest |scale| and |offset| of a data channel (value = raw * scale + offset): far beyond any
#: sensor's range in SI units, and small enough that no reader overflows converting a value
SCALE_MAX = 1e6
OFFSET_MAX = 1e6
#: largest loss an event may state, samples (a day at MAX_RATE_HZ)
LOST_MAX = 86_400 * 10**6
#: root attributes that are text when present
ROOT_TEXT = ("config", "software_version", "host", "ended_utc", "stopped", "run_id", "previous_part", "next_part",
             "part_started_utc", "source", "source_format", "import_report")  # fmt: skip
#: columns of /events and their numpy kinds
EVENT_FIELDS = {"t": "i", "source": "S", "kind": "S", "lost": "i", "detail": "S"}

#: what h5py raises for damaged files: OSError (I/O, decompression, checksum),
#: KeyError (an object that cannot be opened), RuntimeError (library state),
#: ValueError/TypeError (a stored type or shape h5py cannot map to numpy)
H5_ERRORS = (OSError, KeyError, RuntimeError, ValueError, TypeError)


#: how HDF5 reports a chunk its filters refuse on read (h5py shows only the top of the stack)
_FILTER_FAILURE = ("filter returned failure", "checksum", "Data error")


def _reason(exc: BaseException, ds: h5py.Dataset | None = None) -> str:
    text = str(exc).strip().strip("'\"").splitlines()
    first = (text[0] if text else exc.__class__.__name__)[:200]
    if any(s in first for s in _FILTER_FAILURE):
        # fletcher32 is the last filter written, so the first one read: with it, any changed
        # byte of a stored chunk fails the checksum before gzip sees it
        if ds is None:
            return "a stored chunk fails its checksum or does not decompress"
        if ds.fletcher32:
            return "a stored chunk fails its fletcher32 checksum (changed on disk)"
        return "a stored chunk does not decompress (written without checksums)"
    return first


@contextlib.contextmanager
def damaged_file(path: str, what: str = "", ds: h5py.Dataset | None = None) -> Iterator[None]:
    """Turn an h5py error raised inside the block into one :class:`RunFileError` line.

    ``ds``: the dataset being read, to name a chunk its filters refuse (checksum) as such.
    """
    try:
        yield
    except RunFileError:
        raise
    except H5_ERRORS as exc:
        where = f" ({what})" if what else ""
        raise RunFileError(f"{path}: damaged run file{where}: {_reason(exc, ds)}") from None


class CheckedDataset:
    """An h5py dataset whose reads raise :class:`RunFileError` on a damaged chunk.

    Offers what the readers use: slicing, ``len``, ``shape``, ``dtype``,
    ``ndim``, ``attrs``, ``refresh()``.
    """

    __slots__ = ("_ds", "_path", "_what")

    def __init__(self, ds: h5py.Dataset, path: str, what: str):
        self._ds, self._path, self._what = ds, path, what

    def __getitem__(self, key: Any):
        with damaged_file(self._path, f"{self._what} rows {_rows(key)}", self._ds):
            return self._ds[key]

    def __len__(self) -> int:
        return self._ds.shape[0]

    @property
    def shape(self) -> tuple[int, ...]:
        return self._ds.shape

    @property
    def dtype(self):
        return self._ds.dtype

    @property
    def ndim(self) -> int:
        return self._ds.ndim

    @property
    def attrs(self):
        return self._ds.attrs

    def refresh(self) -> None:
        with damaged_file(self._path, self._what):
            self._ds.refresh()


def _rows(key: Any) -> str:
    k = key[0] if isinstance(key, tuple) and key else key
    if isinstance(k, slice):
        return f"{k.start or 0}:{'' if k.stop is None else k.stop}"
    return str(k) if isinstance(k, (int, np.integer)) else "..."


def _members(path: str, group: h5py.Group, name: str) -> dict[str, h5py.HLObject]:
    """The members of ``group``, each opened, refusing links that lead out of the file."""
    out = {}
    with damaged_file(path, name):
        for key in group:
            link = group.get(key, getlink=True)
            if not isinstance(link, h5py.HardLink):
                kind = "external link" if isinstance(link, h5py.ExternalLink) else "soft link"
                raise RunFileError(f"{path}: {name}/{key} is a {kind}; a run file holds its data itself")
            out[key] = group[key]
    return out


def plain_value(value: Any) -> Any:
    """An HDF5 attribute value as plain Python (bytes decoded, numpy scalars unwrapped)."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _attrs(path: str, obj: h5py.HLObject, name: str) -> dict[str, Any]:
    """Every attribute of ``obj`` as plain Python values (loads its object header)."""
    with damaged_file(path, f"{name} attributes"):
        return {k: plain_value(v) for k, v in obj.attrs.items()}


def _is_real(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _require_text(path: str, where: str, attrs: dict[str, Any], keys: tuple[str, ...], optional=False) -> None:
    for key in keys:
        if key not in attrs:
            if optional:
                continue
            raise RunFileError(f"{path}: {where} has no {key!r} attribute")
        if not isinstance(attrs[key], str):
            raise RunFileError(f"{path}: {where} attribute {key!r} is {attrs[key]!r}, expected text")


def _check_utc(path: str, where: str, attrs: dict[str, Any], key: str) -> None:
    if key in attrs:
        try:
            _dt.datetime.fromisoformat(attrs[key])
        except ValueError:
            raise RunFileError(f"{path}: {where} attribute {key!r} is {attrs[key]!r}, not an ISO 8601 time") from None


def _utc(text: str) -> _dt.datetime:
    """An ISO 8601 time as an aware datetime (a time without zone is UTC, as the writer means it)."""
    t = _dt.datetime.fromisoformat(text)
    return t if t.tzinfo is not None else t.replace(tzinfo=_dt.UTC)


def _check_root(path: str, attrs: dict[str, Any]) -> None:
    _require_text(path, "the root", attrs, ("station", "started_utc"))
    _require_text(path, "the root", attrs, ROOT_TEXT, optional=True)
    for key in ("started_utc", "ended_utc", "part_started_utc"):
        _check_utc(path, "the root", attrs, key)
    if "ended_utc" in attrs and _utc(attrs["ended_utc"]) < _utc(attrs["started_utc"]):
        raise RunFileError(f"{path}: ended_utc {attrs['ended_utc']} is before started_utc {attrs['started_utc']}")
    if "simulated" in attrs and not isinstance(attrs["simulated"], bool):
        raise RunFileError(f"{path}: root attribute 'simulated' is {attrs['simulated']!r}, expected true/false")
    part = attrs.get("part")
    if part is not None and (type(part) is not int or part < 1):
        raise RunFileError(f"{path}: root attribute 'part' is {part!r}, expected a part number >= 1")


def _stored_rows(path: str, ds: h5py.Dataset, where: str) -> int:
    """Rows of ``ds`` that have storage in the file (an upper bound for chunked data)."""
    with damaged_file(path, where):
        layout = ds.id.get_create_plist().get_layout()
        if layout == h5d.CHUNKED:
            return ds.id.get_num_chunks() * ds.chunks[0]
        if layout == h5d.CONTIGUOUS:
            row = ds.dtype.itemsize * int(np.prod(ds.shape[1:], dtype=np.int64))
            return ds.id.get_storage_size() // row if row else ds.shape[0]
        return ds.shape[0]


def _check_extents(path: str, where: str, dsets: dict[str, h5py.Dataset], complete: bool) -> int:
    """Rows every dataset of a device or thermometer holds; refuses datasets whose
    lengths or storage contradict each other. Returns the shortest length."""
    rows = {k: ds.shape[0] for k, ds in dsets.items()}
    if not rows:
        return 0
    n, most = min(rows.values()), max(rows.values())
    # a kill or power cut during a flush can leave one block torn (docs/runfile.md); a
    # finished file never, and no flush writes more than TORN_ROWS_MAX rows of a device
    if most > n and (complete or most - n > TORN_ROWS_MAX):
        lengths = ", ".join(f"{k} {v}" for k, v in sorted(rows.items()))
        state = "in a file marked complete" if complete else "more than one flush apart"
        raise RunFileError(f"{path}: {where}: datasets of different lengths ({lengths}) {state}")
    slack = 0 if complete else TORN_ROWS_MAX
    for key, ds in dsets.items():
        stored = _stored_rows(path, ds, f"{where}/{key}")
        if stored + slack < ds.shape[0]:
            raise RunFileError(
                f"{path}: {where}/{key} claims {ds.shape[0]} rows but the file stores at most {stored} of them"
            )
    return n


def _check_rate_attr(path: str, where: str, attrs: dict[str, Any]) -> float:
    """The group's ``rate_hz``: a finite rate in (0, MAX_RATE_HZ]."""
    rate = attrs.get("rate_hz")
    if not (_is_real(rate) and 0 < rate <= MAX_RATE_HZ):
        raise RunFileError(
            f"{path}: {where} attribute 'rate_hz' is {rate!r}, expected a rate in (0, {MAX_RATE_HZ:g}] Hz"
        )
    return float(rate)


def _check_rate(
    path: str,
    where: str,
    t: h5py.Dataset,
    n: int,
    rate_hz: float,
    monotonic: bool,
    losses: Callable[[], tuple[np.ndarray, np.ndarray]] | None = None,
) -> tuple[float, str] | None:
    """``rate_hz`` against the timestamps probed across the record (:func:`.rate.probe_windows`; a fit over
    the runs of regular steps, :func:`.rate.windows_rate`: holes excluded, so a file whose every loss is
    logged reads).

    Refused: probed stamps stepping back where ``monotonic`` (every capture; an import keeps file order and
    says so in its events), a rate the stamps contradict beyond RATE_TOLERANCE or near whose period too few
    steps lie. Returns ``(the fitted rate, Hz; why)`` when the fit contradicts it beyond its standard error
    (RATE_SIGMAS, RATE_FLOOR) and so does the record's whole span, the same way, beyond RATE_FLOOR and its
    stamps' jitter (:func:`.rate.span_rate`, with ``losses()``: the times and counts of the losses the
    events log), else None (never without ``losses``).
    """
    if n < 2:
        return None
    windows = []
    for a, b in probe_windows(n):
        with damaged_file(path, f"{where}/t rows {a}:{b}", t):
            stamps = np.asarray(t[a:b], dtype=np.int64)
        d = np.diff(stamps)
        if monotonic and (d < 0).any():
            i = int(np.argmax(d < 0))
            raise RunFileError(
                f"{path}: {where}/t steps back at row {a + i + 1} ({int(stamps[i])} -> {int(stamps[i + 1])} ns); "
                "a capture's times only increase"
            )
        windows.append((a, stamps))
    if n < RATE_MIN_ROWS:
        return None
    k = sum(len(w) for _, w in windows)
    over = f"over {k} samples" if k == n else f"over {k} samples in {len(windows)} windows across {n}"
    sr = windows_rate(windows, rate_hz)
    head = f"{path}: {where}: rate_hz {rate_hz:g} contradicts its timestamps"
    if sr.regular < max(8, RATE_MIN_REGULAR * sr.steps):
        pos = np.concatenate([np.diff(w) for _, w in windows])
        pos = pos[pos > 0]
        seen = (
            f"median step {np.median(pos) / 1e6:.6g} ms: {1e9 / np.median(pos):.6g} Hz"
            if len(pos)
            else "times that do not increase"
        )
        raise RunFileError(f"{head} ({sr.regular} of {sr.steps} steps within 1.5 periods of it {over}; {seen})")
    ratio = rate_hz / sr.rate_hz
    if not 1 / RATE_TOLERANCE <= ratio <= RATE_TOLERANCE:
        raise RunFileError(f"{head} ({sr.rate_hz:.6g} Hz {over})")
    spans: list = []

    def span():
        spans.append(span_rate(windows, n, rate_hz, *losses()))
        return spans[0]

    # a fit over the runs of a short host-clock record follows its start-up transient: a rate is wrong only
    # where the whole span says so too. The span confirms, the fit over every probed run (holes logged or
    # not) gives the rate: a hole no event logs shortens the span's count, a transient at an end moves it
    if losses is None or not confirmed(sr, rate_hz, span):
        return None
    sp, hz = spans[0], sr.rate_hz
    return hz, (
        f"{head} over its whole span ({sp.rate_hz:.6g} Hz from {sp.count} periods in {sp.span_s:.6g} s, jitter "
        f"{sp.jitter_ns / 1e6:.3g} ms; {sr.rate_hz:.6g} +- {sr.sigma_hz:.2g} Hz fitted {over}; "
        f"{abs(rate_hz / hz - 1):.2%} off); using {hz:.6g} Hz"
    )


def _check_dataset(path: str, where: str, ds: Any, kinds: str, ndims: tuple[int, ...]) -> None:
    if not isinstance(ds, h5py.Dataset):
        raise RunFileError(f"{path}: {where} is a group, expected a dataset")
    if ds.dtype.kind not in kinds or ds.ndim not in ndims:
        what = where.rsplit("/", 1)[-1]
        raise RunFileError(f"{path}: {where} has type {ds.dtype} and shape {ds.shape}, not that of a run-file {what}")


def _check_channel(path: str, where: str, ds: h5py.Dataset) -> None:
    _check_dataset(path, where, ds, "iuf", (1, 2))
    attrs = _attrs(path, ds, where)
    for key in ("scale", "offset"):
        if key not in attrs:
            raise RunFileError(f"{path}: {where} has no {key!r} attribute (value = raw * scale + offset)")
        if not _is_real(attrs[key]):
            raise RunFileError(f"{path}: {where} attribute {key!r} is {attrs[key]!r}, expected a finite number")
    if attrs["scale"] == 0:
        raise RunFileError(f"{path}: {where} has scale 0")
    for key, limit in (("scale", SCALE_MAX), ("offset", OFFSET_MAX)):
        if abs(attrs[key]) > limit:
            raise RunFileError(
                f"{path}: {where} attribute {key!r} is {attrs[key]!r}, beyond any sensor's (|{key}| <= {limit:g})"
            )
    _require_text(path, where, attrs, ("units", "axes"))
    axes = attrs["axes"].split(",") if attrs["axes"] else []
    if (ds.ndim == 2 and len(axes) != ds.shape[1]) or (ds.ndim == 1 and axes):
        raise RunFileError(f"{path}: {where} has shape {ds.shape} but axes {attrs['axes']!r}")


def _check_device(
    path: str, name: str, g: Any, complete: bool, losses: Callable[[str], tuple[np.ndarray, np.ndarray]]
) -> tuple[float, str] | None:
    where = f"devices/{name}"
    if not isinstance(g, h5py.Group):
        raise RunFileError(f"{path}: {where} is a dataset, expected a device group")
    attrs = _attrs(path, g, where)
    _require_text(path, where, attrs, ("driver", "model", "bus"))
    for key, value in attrs.items():
        if not isinstance(value, (str, int, float, bool)):
            raise RunFileError(f"{path}: {where} attribute {key!r} is {value!r}, expected one value")
    rate = _check_rate_attr(path, where, attrs)
    dsets = _members(path, g, where)
    if TIME not in dsets:
        raise RunFileError(f"{path}: {where} has no timestamps ({where}/t)")
    for key, ds in dsets.items():
        if key == TIME:
            _check_dataset(path, f"{where}/t", ds, "i", (1,))
        elif key == COUNTER:
            _check_dataset(path, f"{where}/counter", ds, "iu", (1,))
        else:
            _check_channel(path, f"{where}/{key}", ds)
    n = _check_extents(path, where, dsets, complete)
    return _check_rate(path, where, dsets[TIME], n, rate, attrs["driver"] != IMPORT_DRIVER, lambda: losses(name))


def _check_thermometer(path: str, name: str, g: Any, complete: bool, _losses: Any = None) -> None:
    where = f"thermometers/{name}"
    if not isinstance(g, h5py.Group):
        raise RunFileError(f"{path}: {where} is a dataset, expected a thermometer group")
    dsets = _members(path, g, where)
    if set(dsets) != {TIME, CELSIUS}:
        raise RunFileError(f"{path}: {where} holds {sorted(dsets)}, expected ['celsius', 't']")
    _check_dataset(path, f"{where}/t", dsets[TIME], "i", (1,))
    _check_dataset(path, f"{where}/celsius", dsets[CELSIUS], "f", (1,))
    n = _check_extents(path, where, dsets, complete)
    # the poll rate, stored since it is checked against (files written before have none: not checked)
    attrs = _attrs(path, g, where)
    if "rate_hz" in attrs:
        # readings are dated when taken (late polls, then prompt ones): refused on a gross contradiction only
        _check_rate(path, where, dsets[TIME], n, _check_rate_attr(path, where, attrs), False)


def _check_events(path: str, ds: Any, complete: bool) -> None:
    if not isinstance(ds, h5py.Dataset) or ds.ndim != 1 or ds.dtype.names is None:
        raise RunFileError(f"{path}: events is not an event table")
    for key, kinds in EVENT_FIELDS.items():
        if key not in ds.dtype.names or ds.dtype[key].kind not in kinds:
            raise RunFileError(f"{path}: events has no {key!r} column of the run-file type (has {ds.dtype})")
    _check_extents(path, "events", {"": ds}, complete)


def check_structure(
    h5: h5py.File, path: str, corrections: dict[str, tuple[float, str]] | None = None
) -> dict[str, Any]:
    """Refuse a damaged or contradictory run file with one line (see the module docstring).

    Returns the root attributes as plain Python values. ``corrections`` (filled when given): device
    name -> (the rate its stamps show, Hz; the reason) for each device whose ``rate_hz`` they
    contradict beyond their jitter (:func:`_check_rate`).
    """
    attrs = _attrs(path, h5, "root")
    fmt = attrs.get("format")
    if not isinstance(fmt, str) or fmt != FORMAT:
        raise RunFileError(f"{path}: not an imustation run file (format attribute is {fmt!r})")
    version = attrs.get("format_version")
    if type(version) is not int or version != FORMAT_VERSION:
        raise RunFileError(f"{path}: run-file format version {version!r} is not supported (this is v1)")
    _check_root(path, attrs)
    complete = "ended_utc" in attrs
    if complete:
        # a finished file was cut to its end of allocation when it was closed; a SWMR
        # reader does not compare the two (the file grows while written), so check here
        with damaged_file(path, "superblock"):
            eoa = h5.id.get_filesize()
        size = os.path.getsize(path)
        if size < eoa:
            raise RunFileError(f"{path}: truncated: {size} of its {eoa} bytes are left (the capture had finished it)")
    root = _members(path, h5, "")
    unknown = sorted(set(root) - {DEVICES, THERMOMETERS, EVENTS})
    if unknown:
        raise RunFileError(
            f"{path}: unexpected member(s) {', '.join('/' + u for u in unknown)} at the root of a run file"
        )
    for gname in (DEVICES, THERMOMETERS, EVENTS):
        if gname not in root:
            raise RunFileError(f"{path}: no /{gname} (every run file has it)")
    logged: list[np.ndarray] = []

    def losses(name: str) -> tuple[np.ndarray, np.ndarray]:
        """Times (sorted) and counts of the losses the events log for device ``name`` (read once, when a
        rate is in doubt)."""
        if not logged:
            _check_events(path, root[EVENTS], complete)
            with damaged_file(path, "events", root[EVENTS]):
                logged.append(root[EVENTS].fields(["t", "source", "lost"])[()])
        rows = logged[0]
        mine = rows[(rows["source"] == name.encode()) & (rows["lost"] > 0)]
        order = np.argsort(mine["t"], kind="stable")
        return mine["t"][order].astype(np.int64), mine["lost"][order].astype(np.int64)

    for gname, check in ((DEVICES, _check_device), (THERMOMETERS, _check_thermometer)):
        grp = root[gname]
        if not isinstance(grp, h5py.Group):
            raise RunFileError(f"{path}: /{gname} is a dataset, expected a group")
        for name, sub in _members(path, grp, gname).items():
            note = check(path, name, sub, complete, losses)
            if note and corrections is not None:
                corrections[name] = (float(note[0]), note[1])
    _check_events(path, root[EVENTS], complete)
    return attrs


def parse_events(path: str, rows: np.ndarray) -> list[Event]:
    """Rows of ``/events`` as :class:`Event` objects; refuses kinds outside the schema and negative losses.

    ``detail`` is free text cut at 256 bytes by earlier writers even inside a
    character, so an undecodable byte there shows as U+FFFD; ``source`` and
    ``kind`` name things and must decode.
    """
    if len(rows) == 0:
        return []
    lost = rows["lost"]
    if np.any(lost < 0):
        i = int(np.argmax(lost < 0))
        raise RunFileError(f"{path}: event {i} has a negative loss ({int(lost[i])} samples)")
    if np.any(lost > LOST_MAX):
        i = int(np.argmax(lost > LOST_MAX))
        raise RunFileError(
            f"{path}: event {i} states a loss of {int(lost[i])} samples, more than any run holds ({LOST_MAX:.3g})"
        )
    kinds = np.isin(rows["kind"], [k.encode() for k in EVENT_KINDS])
    if not kinds.all():
        i = int(np.argmin(kinds))
        raise RunFileError(f"{path}: event {i} has kind {rows['kind'][i]!r}, not one of {', '.join(EVENT_KINDS)}")
    try:
        sources = [s.decode() for s in rows["source"]]
    except UnicodeDecodeError:
        raise RunFileError(f"{path}: an event's source is not UTF-8 text") from None
    return [
        Event(int(t), src, k.decode(), int(n), d.decode(errors="replace"))
        for t, src, k, n, d in zip(rows["t"], sources, rows["kind"], lost, rows["detail"], strict=True)
    ]


def read_events(path: str, h5: h5py.File) -> list[Event]:
    """Every row of the run file's ``/events``, checked (see :func:`parse_events`)."""
    with damaged_file(path, "events"):
        ds = h5[EVENTS]
    with damaged_file(path, "events", ds):
        rows = ds[()]
    return parse_events(path, rows)
