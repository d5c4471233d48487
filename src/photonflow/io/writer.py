"""Writing event files: ``EventWriter`` (streaming, crash-safe) and ``write_events``.

Every write goes to a temporary file next to the target (``.{name}.partial-{pid}``)
that replaces the target with ``os.replace`` only when the writer closes without an
error. An exception (KeyboardInterrupt included) removes the temporary file; a
process killed outright leaves the target as it was (absent, or the old file) and
at worst a stale ``.partial`` file beside it.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
from collections.abc import Iterable
from pathlib import Path

import h5py
import numpy as np

from ..errors import EventFileError
from ..geometry.detector import Detector
from ..params import PARAM_SPECS, Params
from .events import Event, Truth, hit_arrays_problem, unknown_vector
from .hdf5 import (
    HIT_FIELDS,
    TRUTH_FIELDS,
    create_layout,
    detector_difference,
    now_iso,
    open_checked,
    params_difference,
)

MODES = ("create", "recreate", "append")

#: Truth columns stored for an event without truth (all "unknown").
_UNKNOWN_TRUTH = ("", "", unknown_vector(), unknown_vector(), math.nan, math.nan, -1)


def _temporary_path(target: Path) -> Path:
    """Create (exclusively, honouring the umask) an empty temporary file beside ``target``."""
    base = target.parent / f".{target.name}.partial-{os.getpid()}"
    for attempt in range(1000):
        candidate = base if attempt == 0 else base.with_name(f"{base.name}-{attempt}")
        try:
            fd = os.open(candidate, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
        except FileExistsError:
            continue
        except OSError as error:
            raise EventFileError(
                f"{target}: cannot create a temporary file in {target.parent}"
                f" ({error.strerror or error})"
            ) from None
        os.close(fd)
        return candidate
    raise EventFileError(
        f"{target}: cannot create a temporary file (too many stale .partial files)"
    )


def _fsync(path: Path) -> None:
    with open(path, "rb+") as handle:
        os.fsync(handle.fileno())


class EventWriter:
    """Context manager that streams events into an event file, chunk by chunk.

    Example::

        with EventWriter("run.h5", detector, params) as writer:
            writer.extend(events)

    Args:
        path: target file.
        detector: the detector the events were recorded in (stored in ``/detector``).
        params: the detector parameters (stored in ``/params``, units per field).
        mode: "create" (refuse an existing file), "recreate" (overwrite) or "append"
            (add events to an existing file with the same detector and params).
        chunk_events: events buffered in memory between writes (memory bound).

    The target only changes when the ``with`` block ends without an exception.

    Raises:
        EventFileError: one-line messages for a bad mode, an existing (create) or
            missing (append) target, a detector/params mismatch on append, or an
            invalid event.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        detector: Detector,
        params: Params,
        *,
        mode: str = "create",
        chunk_events: int = 10000,
    ) -> None:
        self.path = Path(path).expanduser()
        if mode not in MODES:
            raise EventFileError(f"mode = {mode!r}: must be one of {', '.join(MODES)}")
        if isinstance(chunk_events, bool) or not isinstance(chunk_events, int | np.integer) or (
            chunk_events < 1
        ):
            raise EventFileError(f"chunk_events = {chunk_events!r}: must be a positive integer")
        if not isinstance(detector, Detector):
            raise EventFileError(
                f"{self.path}: detector is a {type(detector).__name__}, expected a Detector"
            )
        if not isinstance(params, Params):
            raise EventFileError(
                f"{self.path}: params is a {type(params).__name__}, expected a Params"
            )
        for spec in PARAM_SPECS:
            shape = np.shape(getattr(params, spec.name))
            if spec.per_sensor and shape != (detector.n_sensors,):
                raise EventFileError(
                    f"{self.path}: params.{spec.name} has shape {shape}, expected"
                    f" ({detector.n_sensors},) for detector {detector.name!r}"
                )
        self.detector = detector
        self.params = params
        self.mode = mode
        self.chunk_events = int(chunk_events)
        self._tmp: Path | None = None
        self._h5: h5py.File | None = None
        self._buffer: list[tuple] = []
        self._n_events = 0
        self._n_hits = 0

    # ---- lifecycle -------------------------------------------------------------
    @property
    def n_events(self) -> int:
        """Events in the file so far (written and buffered, including pre-existing ones)."""
        return self._n_events + len(self._buffer)

    def __enter__(self) -> EventWriter:
        if self._h5 is not None:
            raise EventFileError(f"{self.path}: EventWriter is already open")
        target = self.path
        if not target.parent.is_dir():
            raise EventFileError(f"{target}: directory {target.parent} does not exist")
        if target.is_dir():
            raise EventFileError(f"{target}: is a directory")
        if self.mode == "create" and target.exists():
            raise EventFileError(
                f"{target}: file exists; use mode=\"recreate\" to overwrite it"
                " or mode=\"append\" to add events"
            )
        if self.mode == "append":
            self._check_append_target()
        self._tmp = _temporary_path(target)
        try:
            if self.mode == "append":
                shutil.copyfile(target, self._tmp)
                self._h5 = h5py.File(self._tmp, "r+")
                self._h5.attrs["modified"] = now_iso()
                self._n_events = self._h5["events/offsets"].shape[0] - 1
                self._n_hits = int(self._h5["events/offsets"][self._n_events])
            else:
                self._h5 = h5py.File(self._tmp, "w")
                create_layout(self._h5, self.detector, self.params)
        except BaseException as error:
            self._discard()
            if isinstance(error, OSError):
                raise EventFileError(f"{target}: cannot write ({error})") from None
            raise
        return self

    def _check_append_target(self) -> None:
        target = self.path
        if not target.exists():
            raise EventFileError(
                f"{target}: no such file to append to; use mode=\"create\""
            )
        with open_checked(target) as h5:
            difference = detector_difference(h5["detector"], self.detector)
            if difference is not None:
                raise EventFileError(
                    f"{target}: cannot append, the file's detector differs ({difference})"
                )
            difference = params_difference(h5["params"], self.params)
            if difference is not None:
                raise EventFileError(
                    f"{target}: cannot append, the file's parameters differ ({difference})"
                )

    def __exit__(self, exc_type, exc, traceback) -> None:
        if exc_type is not None:
            self._discard()
            return
        try:
            self._flush()
            self._h5.close()
            self._h5 = None
            _fsync(self._tmp)
            if self.mode == "create" and self.path.exists():
                raise EventFileError(
                    f"{self.path}: file appeared while writing; use mode=\"recreate\""
                )
            os.replace(self._tmp, self.path)
            self._tmp = None
        except BaseException as error:
            self._discard()
            if isinstance(error, OSError):
                raise EventFileError(f"{self.path}: cannot write ({error})") from None
            raise

    def _discard(self) -> None:
        """Close and delete the temporary file; the target stays untouched."""
        self._buffer = []
        if self._h5 is not None:
            with contextlib.suppress(Exception):
                self._h5.close()
            self._h5 = None
        if self._tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                self._tmp.unlink()
            self._tmp = None

    # ---- adding events ---------------------------------------------------------
    def append(self, event: Event) -> None:
        """Add one event (buffered; written every ``chunk_events`` events).

        Raises:
            EventFileError: not an ``Event``, hit arrays of unequal length, a bad truth.
        """
        if self._h5 is None:
            raise EventFileError(f"{self.path}: EventWriter is not open; use it in a with block")
        index = self.n_events
        if not isinstance(event, Event):
            raise EventFileError(
                f"{self.path}: events[{index}] is a {type(event).__name__}, expected an Event"
            )
        ids, charge, time = (np.asarray(a) for a in (event.sensor_ids, event.charge, event.time))
        problem = None
        if not (ids.ndim == 1 and charge.shape == ids.shape and time.shape == ids.shape):
            problem = hit_arrays_problem(ids, charge, time)
        elif ids.dtype.kind not in "iu" and ids.size:
            problem = f"sensor_ids has dtype {ids.dtype}, expected integers"
        truth = event.truth
        if truth is None:
            record = _UNKNOWN_TRUTH
        elif not isinstance(truth, Truth):
            problem = problem or f"truth is a {type(truth).__name__}, expected a Truth or None"
        else:
            position = np.asarray(truth.position, dtype=np.float64)
            direction = np.asarray(truth.direction, dtype=np.float64)
            if position.shape != (3,) or direction.shape != (3,):
                problem = problem or "truth.position and truth.direction must have shape (3,)"
            record = (
                str(truth.source_kind), str(truth.particle), position, direction,
                float(truth.energy), float(truth.time), int(truth.seed),
            )
        if problem is not None:
            raise EventFileError(f"{self.path}: events[{index}]: {problem}")
        self._buffer.append((ids, charge, time, *record))
        if len(self._buffer) >= self.chunk_events:
            self._flush()

    def extend(self, events: Iterable[Event]) -> None:
        """Add every event of an iterable (a list, a generator...) with bounded memory."""
        for event in _iterate(events, self.path):
            self.append(event)

    def _flush(self) -> None:
        """Write the buffered events to the temporary file."""
        if not self._buffer:
            return
        buffer, self._buffer = self._buffer, []
        columns = list(zip(*buffer, strict=True))
        counts = np.fromiter((len(ids) for ids in columns[0]), dtype=np.int64, count=len(buffer))
        ids = np.concatenate([np.asarray(a, dtype=np.int64).ravel() for a in columns[0]])
        bad = np.flatnonzero((ids < 0) | (ids >= self.detector.n_sensors))
        if bad.size:
            event = int(np.searchsorted(np.cumsum(counts), bad[0], side="right"))
            raise EventFileError(
                f"{self.path}: events[{self._n_events + event}]: sensor id {int(ids[bad[0]])}"
                f" out of range 0..{self.detector.n_sensors - 1}"
            )
        hits = {
            "sensor_id": ids.astype(np.int32),
            "charge": np.concatenate([np.asarray(a, np.float32) for a in columns[1]]),
            "time": np.concatenate([np.asarray(a, np.float32) for a in columns[2]]),
        }
        truth = {
            "source_kind": np.array(columns[3], dtype=object),
            "particle": np.array(columns[4], dtype=object),
            "position": np.stack(columns[5]),
            "direction": np.stack(columns[6]),
            "energy": np.array(columns[7], dtype=np.float64),
            "time": np.array(columns[8], dtype=np.float64),
            "seed": np.array(columns[9], dtype=np.int64),
        }
        events = self._h5["events"]
        n0, n1 = self._n_events, self._n_events + len(buffer)
        h0, h1 = self._n_hits, self._n_hits + int(counts.sum())
        for name in HIT_FIELDS:
            dataset = events["hits"][name]
            dataset.resize((h1,))
            dataset[h0:h1] = hits[name]
        for name in TRUTH_FIELDS:
            dataset = events["truth"][name]
            dataset.resize((n1, *dataset.shape[1:]))
            dataset[n0:n1] = truth[name]
        offsets = events["offsets"]
        offsets.resize((n1 + 1,))
        offsets[n0 + 1 : n1 + 1] = h0 + np.cumsum(counts)
        events.attrs["n_events"] = np.int64(n1)
        self._n_events, self._n_hits = n1, h1


def _iterate(events, path: Path):
    """``iter(events)``, with a one-line error for a single Event or a non-iterable."""
    if isinstance(events, Event):
        raise EventFileError(f"{path}: expected an iterable of events, got one Event")
    try:
        return iter(events)
    except TypeError:
        raise EventFileError(
            f"{path}: events is a {type(events).__name__}, expected an iterable of Event"
        ) from None


def write_events(
    path: str | os.PathLike,
    events: Iterable[Event],
    detector: Detector,
    params: Params,
    *,
    mode: str = "create",
    chunk_events: int = 10000,
    progress: bool = False,
) -> Path:
    """Write events (any iterable, e.g. a generator) to an HDF5 event file.

    Args:
        path: target file (conventionally ``*.h5``).
        events: iterable of ``Event`` (hits: sensor ids, charge in p.e., time in ns).
        detector: detector the events belong to (stored as provenance).
        params: detector parameters used (stored as provenance, with units).
        mode: "create" (default; refuses an existing file), "recreate" (overwrites)
            or "append" (adds to an existing file whose detector and params match).
        chunk_events: events held in memory between writes.
        progress: show a progress bar on stderr.

    Returns:
        The target path. The file appears (or changes) atomically, only on success.

    Raises:
        EventFileError: see ``EventWriter``.
    """
    writer = EventWriter(path, detector, params, mode=mode, chunk_events=chunk_events)
    with writer:
        if progress:
            from rich.console import Console
            from rich.progress import track

            total = len(events) if hasattr(events, "__len__") else None
            events = track(
                _iterate(events, writer.path),
                description=f"writing {writer.path.name}",
                total=total,
                console=Console(stderr=True),
                transient=True,
            )
        writer.extend(events)
    return writer.path
