"""The HDF5 layout of a photonflow event file (see ``docs/file-format.md``).

Low-level helpers shared by the writer, the reader and the summary: format
constants, creating the empty layout, writing and reading the ``/detector`` and
``/params`` provenance groups, and opening a file with one-line errors.
"""

from __future__ import annotations

import json
import os
from datetime import UTC, datetime
from pathlib import Path

import h5py
import numpy as np

from .._version import __version__
from ..errors import EventFileError, PhotonflowError
from ..geometry.detector import Detector, make_detector
from ..geometry.shapes import shape_from_dict, shape_to_dict
from ..params import PARAM_SPECS, Params

#: Value of the root attribute ``format``.
FORMAT = "photonflow-events"
#: Newest layout version this code reads and the one it writes.
FORMAT_VERSION = 1

#: HDF5 chunk length (elements) of the flat hit datasets.
HIT_CHUNK = 1 << 15
#: HDF5 chunk length (events) of the per-event datasets.
EVENT_CHUNK = 1 << 12
#: Compression filter of all resizable datasets (portable: any HDF5 build reads it).
COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}

#: name -> (dtype, trailing shape) of the flat hit datasets in /events/hits.
HIT_FIELDS = {
    "sensor_id": (np.dtype(np.int32), ()),
    "charge": (np.dtype(np.float32), ()),
    "time": (np.dtype(np.float32), ()),
}
STRING_DTYPE = h5py.string_dtype("utf-8")
#: name -> (dtype, trailing shape) of the per-event datasets in /events/truth.
TRUTH_FIELDS = {
    "source_kind": (STRING_DTYPE, ()),
    "particle": (STRING_DTYPE, ()),
    "position": (np.dtype(np.float64), (3,)),
    "direction": (np.dtype(np.float64), (3,)),
    "energy": (np.dtype(np.float64), ()),
    "time": (np.dtype(np.float64), ()),
    "seed": (np.dtype(np.int64), ()),
}


def now_iso() -> str:
    """Current UTC time as an ISO 8601 string (seconds precision)."""
    return datetime.now(UTC).isoformat(timespec="seconds")


def _resizable(group: h5py.Group, name: str, dtype, tail: tuple, chunk: int) -> None:
    group.create_dataset(
        name,
        shape=(0, *tail),
        maxshape=(None, *tail),
        dtype=dtype,
        chunks=(chunk, *tail),
        **COMPRESSION,
    )


def create_layout(h5: h5py.File, detector: Detector, params: Params) -> None:
    """Write root attributes, ``/detector``, ``/params`` and an empty ``/events`` group."""
    h5.attrs["format"] = FORMAT
    h5.attrs["format_version"] = np.int64(FORMAT_VERSION)
    h5.attrs["photonflow_version"] = __version__
    h5.attrs["created"] = now_iso()
    write_detector(h5.create_group("detector"), detector)
    write_params(h5.create_group("params"), params)
    events = h5.create_group("events")
    events.attrs["n_events"] = np.int64(0)
    events.create_dataset(
        "offsets", data=np.zeros(1, np.int64), maxshape=(None,), chunks=(EVENT_CHUNK,),
        **COMPRESSION,
    )
    hits = events.create_group("hits")
    for name, (dtype, tail) in HIT_FIELDS.items():
        _resizable(hits, name, dtype, tail, HIT_CHUNK)
    truth = events.create_group("truth")
    for name, (dtype, tail) in TRUTH_FIELDS.items():
        _resizable(truth, name, dtype, tail, EVENT_CHUNK)


def write_detector(group: h5py.Group, detector: Detector) -> None:
    """Store a detector's name, shape, sensor models and sensor arrays in ``group``."""
    group.attrs["name"] = detector.name
    group.attrs["shape"] = json.dumps(shape_to_dict(detector.shape))
    group.attrs["sensor_models"] = json.dumps(list(detector.sensor_models))
    group.create_dataset(
        "sensor_positions", data=np.asarray(detector.sensor_positions, np.float64)
    ).attrs["unit"] = "m"
    group.create_dataset(
        "sensor_normals", data=np.asarray(detector.sensor_normals, np.float64)
    ).attrs["unit"] = ""
    group.create_dataset(
        "sensor_radius", data=np.asarray(detector.sensor_radius, np.float64)
    ).attrs["unit"] = "m"
    group.create_dataset("sensor_type", data=np.asarray(detector.sensor_type, np.int32))


def write_params(group: h5py.Group, params: Params) -> None:
    """Store every ``Params`` field as a float64 dataset with ``unit`` and ``doc`` attributes."""
    for spec in PARAM_SPECS:
        dataset = group.create_dataset(
            spec.name, data=np.asarray(getattr(params, spec.name), dtype=np.float64)
        )
        dataset.attrs["unit"] = spec.unit
        dataset.attrs["doc"] = spec.doc


def _text(value) -> str:
    return value.decode("utf-8") if isinstance(value, bytes) else str(value)


def read_detector(h5: h5py.File, path: Path) -> Detector:
    """Rebuild the ``Detector`` stored in ``/detector`` (validated by ``make_detector``).

    Raises:
        EventFileError: the group is missing or its content is invalid.
    """
    where = f"{path}: /detector"
    try:
        group = h5["detector"]
        shape = shape_from_dict(json.loads(_text(group.attrs["shape"])))
        models = json.loads(_text(group.attrs["sensor_models"]))
        return make_detector(
            shape,
            group["sensor_positions"][()],
            group["sensor_normals"][()],
            group["sensor_radius"][()],
            group["sensor_type"][()],
            name=_text(group.attrs["name"]),
            sensor_models=tuple(str(m) for m in models),
            source=where,
        )
    except PhotonflowError as error:
        raise EventFileError(f"{where}: {error}") from None
    except READ_ERRORS as error:
        raise EventFileError(f"{where}: malformed ({_reason(error)})") from None


def read_params(h5: h5py.File, path: Path) -> Params:
    """Rebuild the ``Params`` stored in ``/params`` (JAX default float dtype).

    Raises:
        EventFileError: the group or a field is missing or unreadable.
    """
    where = f"{path}: /params"
    try:
        group = h5["params"]
        missing = [spec.name for spec in PARAM_SPECS if spec.name not in group]
        if missing:
            raise EventFileError(f"{where}: malformed, {missing[0]} is missing")
        # Unknown extra datasets (from a newer writer) are ignored.
        return Params.from_dict({spec.name: group[spec.name][()] for spec in PARAM_SPECS})
    except PhotonflowError as error:
        raise EventFileError(f"{where}: {error}") from None
    except READ_ERRORS as error:
        raise EventFileError(f"{where}: malformed ({_reason(error)})") from None


def detector_difference(stored: h5py.Group, detector: Detector) -> str | None:
    """How ``detector`` differs from the one stored in ``stored`` (name, shape, sensor
    positions), or None when they match."""
    name = _text(stored.attrs["name"])
    if name != detector.name:
        return f"name {detector.name!r} != {name!r}"
    shape = json.loads(_text(stored.attrs["shape"]))
    if shape != shape_to_dict(detector.shape):
        return f"shape {shape_to_dict(detector.shape)} != {shape}"
    positions = stored["sensor_positions"][()]
    given = np.asarray(detector.sensor_positions, dtype=np.float64)
    if positions.shape != given.shape:
        return f"{given.shape[0]} sensors != {positions.shape[0]}"
    if not np.array_equal(positions, given):
        i = int(np.flatnonzero(np.any(positions != given, axis=1))[0])
        return f"sensor_positions[{i}] {given[i].tolist()} != {positions[i].tolist()}"
    return None


def params_difference(stored: h5py.Group, params: Params) -> str | None:
    """The first ``Params`` field whose value differs from the stored one, or None."""
    for spec in PARAM_SPECS:
        given = np.asarray(getattr(params, spec.name), dtype=np.float64)
        old = stored[spec.name][()] if spec.name in stored else None
        if old is None or old.shape != given.shape or not np.array_equal(
            old, given, equal_nan=True
        ):
            return f"params.{spec.name} differs"
    return None


#: What h5py raises for a file whose bytes are corrupted: OSError for unreadable
#: data, KeyError for an object it cannot open, RuntimeError for a damaged B-tree, and
#: ValueError/TypeError for attributes of the wrong kind.
READ_ERRORS = (OSError, KeyError, RuntimeError, ValueError, TypeError)


def damaged(path, what: str, error: BaseException) -> EventFileError:
    """The one-line error for an event file whose bytes cannot be read back: names the
    file, what was being read and h5py's reason."""
    return EventFileError(
        f"{path}: damaged, cannot read {what} ({_reason(error)}); write the file again"
    )


def _reason(error: BaseException) -> str:
    text = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
    return text.strip("'\"")


def open_checked(path: Path, mode: str = "r") -> h5py.File:
    """Open an existing event file after checking that it is one this code can read.

    Args:
        path: file path.
        mode: h5py mode, "r" (read) or "r+" (read/write).

    Raises:
        EventFileError: missing file, not HDF5, wrong ``format`` attribute, a
            ``format_version`` newer than ``FORMAT_VERSION``, or missing groups.
    """
    if not path.exists():
        raise EventFileError(f"{path}: no such file")
    if path.is_dir():
        raise EventFileError(f"{path}: is a directory, not an event file")
    if not os.access(path, os.R_OK):
        raise EventFileError(f"{path}: permission denied")
    try:
        is_hdf5 = h5py.is_hdf5(path)
    except OSError as error:
        raise EventFileError(f"{path}: cannot read ({_reason(error)})") from None
    if not is_hdf5:
        raise EventFileError(f"{path}: not an HDF5 file (expected a photonflow event file)")
    try:
        h5 = h5py.File(path, mode)
    except OSError as error:
        raise EventFileError(f"{path}: cannot open as HDF5 ({_reason(error)})") from None
    try:
        check_layout(h5, path)
    except READ_ERRORS as error:
        h5.close()
        if isinstance(error, PhotonflowError):
            raise
        raise damaged(path, "its layout", error) from None
    except BaseException:
        h5.close()
        raise
    return h5


def check_layout(h5: h5py.File, path: Path) -> None:
    """Check the root attributes and that every dataset exists with consistent lengths.

    Raises:
        EventFileError: naming the file and the first problem found.
    """
    fmt = _text(h5.attrs.get("format", ""))
    if fmt != FORMAT:
        shown = repr(fmt) if fmt else "missing"
        raise EventFileError(
            f"{path}: not a photonflow event file (format attribute {shown},"
            f" expected {FORMAT!r})"
        )
    try:
        version = int(h5.attrs["format_version"])
    except (KeyError, TypeError, ValueError):
        raise EventFileError(
            f"{path}: format_version attribute missing or not an integer"
        ) from None
    if version > FORMAT_VERSION:
        raise EventFileError(
            f"{path}: format_version {version} is newer than this photonflow"
            f" ({__version__}) can read (up to {FORMAT_VERSION}); upgrade photonflow"
        )
    if version < 1:
        raise EventFileError(f"{path}: format_version {version} is invalid (must be >= 1)")
    required = ["detector", "params", "events", "events/offsets"]
    required += [f"events/hits/{name}" for name in HIT_FIELDS]
    required += [f"events/truth/{name}" for name in TRUTH_FIELDS]
    for name in required:
        if name not in h5:
            raise EventFileError(f"{path}: malformed, /{name} is missing")
    n_offsets = h5["events/offsets"].shape[0]
    if n_offsets < 1:
        raise EventFileError(f"{path}: malformed, /events/offsets is empty")
    n_events = n_offsets - 1
    stated = h5["events"].attrs.get("n_events")
    if stated is not None and int(stated) != n_events:
        raise EventFileError(
            f"{path}: malformed, /events n_events = {int(stated)} but offsets hold {n_events}"
        )
    for name in TRUTH_FIELDS:
        length = h5[f"events/truth/{name}"].shape[0]
        if length != n_events:
            raise EventFileError(
                f"{path}: malformed, /events/truth/{name} has {length} rows, expected {n_events}"
            )
    n_hits = int(h5["events/offsets"][n_events])
    for name in HIT_FIELDS:
        length = h5[f"events/hits/{name}"].shape[0]
        if length != n_hits:
            raise EventFileError(
                f"{path}: malformed, /events/hits/{name} has {length} rows, expected {n_hits}"
            )
