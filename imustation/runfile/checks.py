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
from collections.abc import Iterator
from typing import Any

import h5py
import numpy as np
from h5py import h5d

from imustation.errors import RunFileError
from imustation.runfile.schema import (
    CELSIUS,
    COUNTER,
    DEVICES,
    EVENT_KINDS,
    EVENTS,
    FORMAT,
    FORMAT_VERSION,
    THERMOMETERS,
    TIME,
    Event,
)

#: rows by which the datasets of one device may differ in a file cut off during a flush
#: (a flush writes at most the writer's max_buffer_rows, 2^20, plus one block)
TORN_ROWS_MAX = 1 << 21
#: highest sample rate a run file may state, Hz (no inertial sensor comes near it)
MAX_RATE_HZ = 1e6
#: rate_hz and the rate its first timestamps show may differ by at most this factor (a
#: chip's clock is off by a few %; stamps of imported logs are coarse)
RATE_TOLERANCE = 1.33
#: timestamps compared with rate_hz, and the window (samples) over which their steps are averaged
RATE_PROBE_ROWS = 4096
RATE_WINDOW = 16
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


def _check_root(path: str, attrs: dict[str, Any]) -> None:
    _require_text(path, "the root", attrs, ("station", "started_utc"))
    _require_text(path, "the root", attrs, ROOT_TEXT, optional=True)
    for key in ("started_utc", "ended_utc", "part_started_utc"):
        _check_utc(path, "the root", attrs, key)
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


def _check_rate(path: str, where: str, t: h5py.Dataset, n: int, rate_hz: float) -> None:
    """``rate_hz`` must agree with the spacing of the first timestamps (see RATE_TOLERANCE)."""
    k = min(n, RATE_PROBE_ROWS + 1)
    if k <= 4 * RATE_WINDOW:
        return
    with damaged_file(path, f"{where}/t rows 0:{k}", t):
        d = np.diff(np.asarray(t[:k], dtype=np.int64)).astype(np.float64)
    w = len(d) // RATE_WINDOW
    # median of window means: robust to a gap (one window) and to coarse stamp resolution (averaged)
    period_ns = float(np.median(d[: w * RATE_WINDOW].reshape(w, RATE_WINDOW).mean(axis=1)))
    ratio = period_ns * rate_hz / 1e9
    if not 1 / RATE_TOLERANCE <= ratio <= RATE_TOLERANCE:
        seen = f"{1e9 / period_ns:.6g} Hz" if period_ns > 0 else "times that do not increase"
        raise RunFileError(
            f"{path}: {where}: rate_hz {rate_hz:g} contradicts its timestamps ({seen} over the first {k} samples)"
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
    _require_text(path, where, attrs, ("units", "axes"))
    axes = attrs["axes"].split(",") if attrs["axes"] else []
    if (ds.ndim == 2 and len(axes) != ds.shape[1]) or (ds.ndim == 1 and axes):
        raise RunFileError(f"{path}: {where} has shape {ds.shape} but axes {attrs['axes']!r}")


def _check_device(path: str, name: str, g: Any, complete: bool) -> None:
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
    _check_rate(path, where, dsets[TIME], n, rate)


def _check_thermometer(path: str, name: str, g: Any, complete: bool) -> None:
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
        _check_rate(path, where, dsets[TIME], n, _check_rate_attr(path, where, attrs))


def _check_events(path: str, ds: Any, complete: bool) -> None:
    if not isinstance(ds, h5py.Dataset) or ds.ndim != 1 or ds.dtype.names is None:
        raise RunFileError(f"{path}: events is not an event table")
    for key, kinds in EVENT_FIELDS.items():
        if key not in ds.dtype.names or ds.dtype[key].kind not in kinds:
            raise RunFileError(f"{path}: events has no {key!r} column of the run-file type (has {ds.dtype})")
    _check_extents(path, "events", {"": ds}, complete)


def check_structure(h5: h5py.File, path: str) -> dict[str, Any]:
    """Refuse a damaged or contradictory run file with one line (see the module docstring).

    Returns the root attributes as plain Python values.
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
    for gname, check in ((DEVICES, _check_device), (THERMOMETERS, _check_thermometer)):
        grp = root[gname]
        if not isinstance(grp, h5py.Group):
            raise RunFileError(f"{path}: /{gname} is a dataset, expected a group")
        for name, sub in _members(path, grp, gname).items():
            check(path, name, sub, complete)
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
