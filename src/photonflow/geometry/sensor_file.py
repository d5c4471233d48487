"""Measured sensor layouts: read (and write) sensor positions from CSV, NPZ or HDF5 files.

File schema (one record per sensor; column names are case-insensitive):

========  ========  ====================================================
column    unit      meaning
========  ========  ====================================================
x, y, z   m         disc centre, detector frame (origin at the centre,
                    cylinder axis along z)
nx,ny,nz  --        unit normal pointing into the detector (where the
                    sensor looks); lengths within 1e-3 of 1 are accepted
                    and renormalised
radius    m         disc radius (optional; default: ``default_radius``)
type      --        integer index into the detector's sensor models
                    (optional; default 0)
========  ========  ====================================================

* CSV (``.csv``): a header row with the column names, then one row per sensor,
  comma-separated (or semicolon/tab-separated if the header uses those). Blank lines
  and lines starting with ``#`` are skipped; extra columns (labels, ids) are ignored.
* NPZ (``.npz``): one 1-D array per column, named by the column.
* HDF5 (``.h5``, ``.hdf5``): one 1-D dataset per column, in a ``/sensors`` group
  or at the root; or a compound (table) dataset ``/sensors`` with named fields.

Every problem raises a one-line ``SensorFileError`` naming the file, the record
(CSV row and line, or array index) and the value. Whether the sensors lie inside
the detector is checked by ``make_detector`` against a shape (pass ``shape=``).
"""

from __future__ import annotations

import csv
import math
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..errors import SensorFileError, format_value
from .detector import NORMAL_TOLERANCE, Detector, make_detector
from .shapes import Shape

#: Columns every sensor file must have (positions in m, inward unit normals).
REQUIRED_COLUMNS: tuple[str, ...] = ("x", "y", "z", "nx", "ny", "nz")
#: Optional columns: disc radius (m) and sensor-model type index.
OPTIONAL_COLUMNS: tuple[str, ...] = ("radius", "type")
#: File name suffixes understood by ``load_sensor_file``.
SENSOR_FILE_SUFFIXES: tuple[str, ...] = (".csv", ".npz", ".h5", ".hdf5")

_COLUMNS = REQUIRED_COLUMNS + OPTIONAL_COLUMNS

#: A function naming record i of a file for messages ("row 3 (line 5)", "index 2").
Locator = Callable[[int], str]
#: A reader's result: column name -> float64 array, and the file's ``Locator``.
Columns = tuple[dict[str, np.ndarray], Locator]
SensorArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _index_locator(i: int) -> str:
    return f"index {i}"


# ---- readers ----------------------------------------------------------------------------


def _read_csv(path: Path) -> Columns:
    """Columns of a CSV file with a header row; only the known columns are parsed.

    The delimiter is a comma, or a semicolon or tab if the header has one of those
    instead. Values are checked in file order, so the first bad one is reported.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SensorFileError(f"{path}: cannot read ({_first_line(exc)})") from None
    numbered = [
        (number, line)
        for number, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not numbered:
        raise SensorFileError(f"{path}: empty (expected a header row {','.join(REQUIRED_COLUMNS)})")
    delimiter = next((d for d in ",;\t" if d in numbered[0][1]), ",")
    rows = list(csv.reader((line for _, line in numbered), delimiter=delimiter))
    header = [name.strip().lower() for name in rows[0]]
    duplicates = sorted({name for name in header if header.count(name) > 1})
    if duplicates:
        raise SensorFileError(f"{path}: column '{duplicates[0]}' appears twice in the header")
    _check_known_columns(path, header)
    lines = [number for number, _ in numbered[1:]]

    def locate(i: int) -> str:
        return f"row {i + 1} (line {lines[i]})"

    wanted = [(k, name) for k, name in enumerate(header) if name in _COLUMNS]
    table = np.empty((len(rows) - 1, len(wanted)))
    for i, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise SensorFileError(
                f"{path}: {locate(i)}: {len(row)} fields, the header has {len(header)}"
            )
        for j, (k, name) in enumerate(wanted):
            try:
                table[i, j] = float(row[k])
            except ValueError:
                raise SensorFileError(
                    f"{path}: {locate(i)}: {name} = {format_value(row[k].strip())}: not a number"
                ) from None
    return {name: table[:, j] for j, (_, name) in enumerate(wanted)}, locate


def _numeric_column(path: Path, name: str, array: np.ndarray) -> np.ndarray:
    """A dataset/array as a 1-D float64 column, or a ``SensorFileError``."""
    if not (np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)):
        raise SensorFileError(f"{path}: column '{name}' has dtype {array.dtype}, must be numeric")
    if array.ndim != 1:
        raise SensorFileError(
            f"{path}: column '{name}' has shape {array.shape}, must be 1-D (one value per sensor)"
        )
    return array.astype(np.float64)


def _read_arrays(path: Path, arrays: dict[str, np.ndarray]) -> Columns:
    """Known columns of a name -> array mapping (NPZ, HDF5), with equal lengths checked."""
    names = {name.lower(): name for name in arrays}
    _check_known_columns(path, list(names))
    columns = {
        key: _numeric_column(path, key, np.asarray(arrays[name]))
        for key, name in names.items()
        if key in _COLUMNS
    }
    n = len(columns["x"])
    for name, values in columns.items():
        if len(values) != n:
            raise SensorFileError(f"{path}: column '{name}' has {len(values)} entries, 'x' has {n}")
    return columns, _index_locator


def _read_npz(path: Path) -> Columns:
    """Columns of an NPZ archive (one array per column)."""
    if not zipfile.is_zipfile(path):
        raise SensorFileError(f"{path}: not an NPZ archive (no zip signature)")
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except Exception as exc:  # zipfile, pickle and OS errors alike: not a readable NPZ
        raise SensorFileError(f"{path}: cannot read as NPZ ({_first_line(exc)})") from None
    return _read_arrays(path, arrays)


def _read_hdf5(path: Path) -> Columns:
    """Columns of an HDF5 file: datasets in ``/sensors`` or at the root, or a ``/sensors`` table."""
    import h5py

    try:
        with h5py.File(path, "r") as handle:
            node = handle.get("sensors", handle)
            if isinstance(node, h5py.Dataset) and node.dtype.names:
                table = node[()]
                arrays = {name: table[name] for name in node.dtype.names}
            elif isinstance(node, h5py.Group):
                arrays = {
                    name: item[()] for name, item in node.items() if isinstance(item, h5py.Dataset)
                }
            else:
                raise SensorFileError(
                    f"{path}: '/sensors' is neither a group of column datasets nor a table"
                )
    except SensorFileError:
        raise
    except Exception as exc:  # h5py raises OSError, KeyError, ValueError for bad files
        raise SensorFileError(f"{path}: cannot read as HDF5 ({_first_line(exc)})") from None
    return _read_arrays(path, arrays)


_READERS: dict[str, Callable[[Path], Columns]] = {
    ".csv": _read_csv,
    ".npz": _read_npz,
    ".h5": _read_hdf5,
    ".hdf5": _read_hdf5,
}


def _check_known_columns(path: Path, found: Sequence[str]) -> None:
    missing = [name for name in REQUIRED_COLUMNS if name not in found]
    if missing:
        listed = ", ".join(found) if found else "none"
        raise SensorFileError(
            f"{path}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}"
            f" (found: {listed}; required: {', '.join(REQUIRED_COLUMNS)})"
        )


# ---- validation --------------------------------------------------------------------------


def _check_finite(path: Path, columns: dict[str, np.ndarray], locate: Locator) -> None:
    """First NaN / infinite value in file order (record, then column), if any."""
    names = [name for name in _COLUMNS if name in columns]
    table = np.column_stack([columns[name] for name in names])
    bad = np.argwhere(~np.isfinite(table))
    if bad.size:
        i, k = (int(v) for v in bad[0])
        raise SensorFileError(
            f"{path}: {locate(i)}: {names[k]} = {format_value(float(table[i, k]))}: not finite"
        )


def _radius_column(
    path: Path, columns: dict[str, np.ndarray], locate: Locator, default_radius: float | None
) -> np.ndarray:
    n = len(columns["x"])
    if "radius" not in columns:
        if default_radius is None:
            raise SensorFileError(f"{path}: no 'radius' column and no default radius given")
        if not (math.isfinite(default_radius) and default_radius > 0):
            raise SensorFileError(
                f"{path}: default radius = {format_value(default_radius)}: must be > 0 m"
            )
        return np.full(n, float(default_radius))
    radius = columns["radius"]
    bad = np.flatnonzero(radius <= 0)
    if bad.size:
        i = int(bad[0])
        raise SensorFileError(
            f"{path}: {locate(i)}: radius = {format_value(float(radius[i]))}: must be > 0 m"
        )
    return radius


def _type_column(path: Path, columns: dict[str, np.ndarray], locate: Locator) -> np.ndarray:
    n = len(columns["x"])
    if "type" not in columns:
        return np.zeros(n, dtype=np.int32)
    types = columns["type"]
    bad = np.flatnonzero((types < 0) | (types != np.round(types)))
    if bad.size:
        i = int(bad[0])
        raise SensorFileError(
            f"{path}: {locate(i)}: type = {format_value(float(types[i]))}: must be an integer >= 0"
        )
    return types.astype(np.int32)


def _unit_normals(path: Path, normals: np.ndarray, locate: Locator) -> np.ndarray:
    lengths = np.linalg.norm(normals, axis=1)
    bad = np.flatnonzero(np.abs(lengths - 1.0) > NORMAL_TOLERANCE)
    if bad.size:
        i = int(bad[0])
        raise SensorFileError(
            f"{path}: {locate(i)}: (nx, ny, nz) = {format_value(normals[i].tolist())}:"
            f" not a unit vector (length {lengths[i]:.4g}; allowed 1 +- {NORMAL_TOLERANCE:g})"
        )
    return normals / lengths[:, None]


def _validated(
    path: Path, columns: dict[str, np.ndarray], locate: Locator, default_radius: float | None
) -> SensorArrays:
    """Turn raw columns into checked (positions, normals, radius, type) arrays."""
    if len(columns["x"]) == 0:
        raise SensorFileError(f"{path}: no sensors (the file has a header but no records)")
    _check_finite(path, columns, locate)
    positions = np.column_stack([columns[name] for name in ("x", "y", "z")])
    normals = _unit_normals(
        path, np.column_stack([columns[name] for name in ("nx", "ny", "nz")]), locate
    )
    radius = _radius_column(path, columns, locate, default_radius)
    return positions, normals, radius, _type_column(path, columns, locate)


def _read(path: Path) -> Columns:
    suffix = path.suffix.lower()
    if suffix not in _READERS:
        raise SensorFileError(
            f"{path}: unknown sensor-file extension '{path.suffix}';"
            f" expected {', '.join(SENSOR_FILE_SUFFIXES)}"
        )
    if not path.is_file():
        raise SensorFileError(f"{path}: no such file")
    return _READERS[suffix](path)


# ---- public API ---------------------------------------------------------------------------


def load_sensor_file(
    path: str | Path, shape: Shape | None = None, *, default_radius: float | None = None
) -> SensorArrays:
    """Read a measured sensor layout (CSV, NPZ or HDF5; see the module docstring).

    Args:
        path: the file; its suffix selects the format.
        shape: if given, the sensors are also checked against this boundary
            (inside it, wall-mounted sensors facing inward), as ``make_detector`` does.
        default_radius: disc radius in m for files without a ``radius`` column.

    Returns:
        ``(positions, normals, radius, type)``: (N, 3) disc centres in m (float64),
        (N, 3) unit inward normals (renormalised), (N,) disc radii in m, (N,) int32
        sensor-model type indices.

    Raises:
        SensorFileError: a one-line message naming the file and the problem.
        ConfigError: a sensor lies outside ``shape`` (names ``<file>: sensors.positions[i]``).
    """
    path = Path(path)
    columns, locate = _read(path)
    arrays = _validated(path, columns, locate, default_radius)
    if shape is None:
        return arrays
    n_types = int(arrays[3].max()) + 1
    detector = detector_from_sensor_file(
        path, shape, sensor_models=tuple(f"type{k}" for k in range(n_types)), arrays=arrays
    )
    return (
        np.array(detector.sensor_positions),
        np.array(detector.sensor_normals),
        np.array(detector.sensor_radius),
        np.array(detector.sensor_type),
    )


def detector_from_sensor_file(
    path: str | Path,
    shape: Shape,
    *,
    name: str | None = None,
    sensor_models: Sequence[str] = ("R3600",),
    default_radius: float | None = None,
    arrays: SensorArrays | None = None,
) -> Detector:
    """A ``Detector`` with the boundary ``shape`` and the sensors of a sensor file.

    Args:
        path: sensor file (CSV, NPZ or HDF5).
        shape: detector boundary (lengths in m).
        name: detector name (default: the file's stem).
        sensor_models: photosensor model names; the file's ``type`` column indexes them.
        default_radius: disc radius in m for files without a ``radius`` column.
        arrays: already loaded ``(positions, normals, radius, type)`` (skips reading).

    Raises:
        SensorFileError: the file cannot be read or fails validation.
        ConfigError: a sensor outside the boundary, facing outward, or a type index
            without a sensor model; the message names ``<file>: sensors.<field>[i]``.
    """
    path = Path(path)
    if arrays is None:
        arrays = load_sensor_file(path, default_radius=default_radius)
    positions, normals, radius, types = arrays
    return make_detector(
        shape,
        positions,
        normals,
        radius,
        types,
        name=name or path.stem,
        sensor_models=tuple(sensor_models),
        source=f"{path}: sensors",
    )


def write_sensor_file(
    path: str | Path,
    positions,
    normals,
    radius=None,
    sensor_type=None,
    *,
    overwrite: bool = False,
) -> Path:
    """Write a sensor layout in the format of ``path``'s suffix (CSV, NPZ or HDF5).

    Args:
        path: destination; ``.csv``, ``.npz``, ``.h5`` or ``.hdf5``.
        positions: (N, 3) disc centres, m.
        normals: (N, 3) unit inward normals.
        radius: (N,) or scalar disc radius in m; omitted from the file if None.
        sensor_type: (N,) or scalar sensor-model index; omitted if None.
        overwrite: replace an existing file (default: refuse).

    Returns the path. CSV values are written with 9 significant digits; HDF5 columns
    go into a ``/sensors`` group with a ``unit`` attribute.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _READERS:
        raise SensorFileError(
            f"{path}: unknown sensor-file extension '{path.suffix}';"
            f" expected {', '.join(SENSOR_FILE_SUFFIXES)}"
        )
    if path.exists() and not overwrite:
        raise SensorFileError(f"{path}: exists (pass overwrite=True to replace it)")
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    n = len(positions)
    columns = dict(zip(REQUIRED_COLUMNS, [*positions.T, *normals.T], strict=True))
    if radius is not None:
        columns["radius"] = np.broadcast_to(np.asarray(radius, dtype=np.float64), (n,))
    if sensor_type is not None:
        columns["type"] = np.broadcast_to(np.asarray(sensor_type, dtype=np.int32), (n,))
    if suffix == ".csv":
        _write_csv(path, columns)
    elif suffix == ".npz":
        np.savez(path, **columns)
    else:
        _write_hdf5(path, columns)
    return path


_UNITS = {"x": "m", "y": "m", "z": "m", "radius": "m", "nx": "", "ny": "", "nz": "", "type": ""}


def _write_csv(path: Path, columns: dict[str, np.ndarray]) -> None:
    names = list(columns)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(names)
        for row in zip(*(columns[name] for name in names), strict=True):
            writer.writerow([_csv_cell(name, v) for name, v in zip(names, row, strict=True)])


def _csv_cell(name: str, value) -> str:
    return str(int(value)) if name == "type" else f"{value + 0.0:.9g}"  # no "-0"


def _write_hdf5(path: Path, columns: dict[str, np.ndarray]) -> None:
    import h5py

    with h5py.File(path, "w") as handle:
        group = handle.create_group("sensors")
        for name, values in columns.items():
            group.create_dataset(name, data=np.asarray(values)).attrs["unit"] = _UNITS[name]
