"""Writing event files: ``EventWriter`` (streaming, crash-safe) and ``write_events``.

Every write goes to a temporary file next to the target (``.{name}.partial-{pid}``)
that replaces the target with ``os.replace`` only when the writer closes without an
error. An exception (KeyboardInterrupt included) removes the temporary file; a
process killed outright leaves the target as it was (absent, or the old file) and
at worst a stale ``.partial`` file beside it.

A resumable write (``run=`` settings given) uses the fixed name ``.{name}.partial``
instead, checkpoints it as it goes and keeps it when interrupted, so that the same
run can continue from it with ``resume=True`` (docs/file-format.md, "Resuming").
Ctrl-C and SIGTERM wait while a chunk is written and while the file is closed or
renamed (``interrupts.interrupts_deferred``), so an interrupt never cuts a write.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from time import monotonic

import h5py
import numpy as np

from ..errors import EventFileError
from ..geometry.detector import Detector
from ..interrupts import interrupts_deferred
from ..params import PARAM_SPECS, Params
from ..progress import with_progress
from .events import Event, Truth, hit_arrays_problem, unknown_vector
from .hdf5 import (
    HIT_FIELDS,
    TRUTH_FIELDS,
    check_layout,
    create_layout,
    detector_difference,
    now_iso,
    open_checked,
    params_difference,
)

MODES = ("create", "recreate", "append")

#: Truth columns stored for an event without truth (all "unknown").
_UNKNOWN_TRUTH = ("", "", unknown_vector(), unknown_vector(), math.nan, math.nan, -1)


#: Seconds between checkpoints of a resumable write (also one every ``chunk_events``).
CHECKPOINT_SECONDS = 20.0


def checkpoint_path(target: str | os.PathLike) -> Path:
    """The partial file ``.{name}.partial`` beside ``target`` that a resumable write
    (``EventWriter(..., run=...)``) fills and keeps when interrupted."""
    target = Path(target).expanduser()
    return target.parent / f".{target.name}.partial"


def _settings_json(run: Mapping) -> str:
    """``run`` as canonical JSON (sorted keys); a one-line error if it is not JSON-able."""
    try:
        return json.dumps(dict(run), sort_keys=True, allow_nan=True)
    except (TypeError, ValueError) as error:
        raise EventFileError(f"run = {run!r}: not JSON-serialisable ({error})") from None


def run_difference(stored: str, run: Mapping) -> str | None:
    """The first setting (in key order) in which the JSON ``stored`` run settings differ
    from ``run``, as "KEY = stored, not given"; None when they are equal."""
    old, new = json.loads(stored), json.loads(_settings_json(run))
    for key in sorted(set(old) | set(new)):
        if old.get(key) != new.get(key):
            return f"{key} = {json.dumps(old.get(key))}, not {json.dumps(new.get(key))}"
    return None


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
        run: the settings of the run that makes the events (JSON-able mapping, e.g.
            seed, source, number of events), or None. Given, the write is resumable:
            the settings are stored (root attributes ``run``, ``run_first_event``), the
            partial file ``checkpoint_path(path)`` is checkpointed every
            ``chunk_events`` events or ``CHECKPOINT_SECONDS`` and kept when the
            ``with`` block ends with an exception after this run wrote an event.
        resume: continue the kept partial file of an interrupted run with the same
            ``mode``, detector, params and ``run`` settings (``n_run_events`` says how
            many of the run's events it holds; the caller adds the rest).

    The target only changes when the ``with`` block ends without an exception.

    Raises:
        EventFileError: one-line messages for a bad mode, an existing (create) or
            missing (append) target, a detector/params mismatch on append, or an
            invalid event; a partial file in the way (not resuming), none to resume,
            or one whose detector, params or run settings differ from the given ones.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        detector: Detector,
        params: Params,
        *,
        mode: str = "create",
        chunk_events: int = 10000,
        run: Mapping | None = None,
        resume: bool = False,
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
        if resume and run is None:
            raise EventFileError(f"{self.path}: resume needs the run settings (run=...)")
        self.detector = detector
        self.params = params
        self.mode = mode
        self.chunk_events = int(chunk_events)
        self.run = None if run is None else _settings_json(run)
        self.resume = bool(resume)
        self._tmp: Path | None = None
        self._h5: h5py.File | None = None
        self._buffer: list[tuple] = []
        self._n_events = 0
        self._n_hits = 0
        self._run_first_event = 0
        self._checkpointed = monotonic()

    # ---- lifecycle -------------------------------------------------------------
    @property
    def n_events(self) -> int:
        """Events in the file so far (written and buffered, including pre-existing ones)."""
        return self._n_events + len(self._buffer)

    @property
    def n_run_events(self) -> int:
        """Events of this run in the file so far (for a resumed run, those written before
        the interruption included); ``n_events`` less the events already in an appended
        file."""
        return self.n_events - self._run_first_event

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
        if self.mode == "append" and not self.resume:
            self._check_append_target()
        self._tmp = _temporary_path(target) if self.run is None else self._checkpoint_file()
        try:
            if self.resume:
                with _open_partial(self._tmp, target, "r") as h5:
                    self._check_resumable(h5)
                self._h5 = _reopen_checkpoint(self._tmp, target)
            elif self.mode == "append":
                shutil.copyfile(target, self._tmp)
                self._h5 = h5py.File(self._tmp, "r+")
                self._h5.attrs["modified"] = now_iso()
                for name in ("run", "run_first_event"):  # no longer one run's file
                    with contextlib.suppress(KeyError):
                        del self._h5.attrs[name]
            else:
                self._h5 = h5py.File(self._tmp, "w")
                create_layout(self._h5, self.detector, self.params)
            self._n_events = self._h5["events/offsets"].shape[0] - 1
            self._n_hits = int(self._h5["events/offsets"][self._n_events])
            if self.run is not None and not self.resume:
                self._h5.attrs["run"] = self.run
                self._h5.attrs["run_first_event"] = np.int64(self._n_events)
                self._h5.flush()
            self._run_first_event = int(self._h5.attrs.get("run_first_event", 0))
        except BaseException as error:
            if self.resume:
                self._close_keeping()
            else:
                self._discard()
            if isinstance(error, OSError):
                raise EventFileError(f"{target}: cannot write ({error})") from None
            raise
        return self

    def _checkpoint_file(self) -> Path:
        """The partial file of a resumable write: the kept one when resuming, else a new
        one (refused when an interrupted run's file is in the way, unless recreating)."""
        partial = checkpoint_path(self.path)
        if self.resume:
            if not partial.exists():
                raise EventFileError(
                    f"{self.path}: no interrupted run to resume ({partial.name} not found)"
                )
            return partial
        if self.mode == "recreate":
            with contextlib.suppress(FileNotFoundError):
                partial.unlink()
        try:
            os.close(os.open(partial, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        except FileExistsError:
            raise EventFileError(
                f"{self.path}: an interrupted run left {partial.name}; resume it (--resume)"
                " or delete it"
            ) from None
        except OSError as error:
            raise EventFileError(
                f"{self.path}: cannot create {partial.name} ({error.strerror or error})"
            ) from None
        return partial

    def _check_resumable(self, h5: h5py.File) -> None:
        """Refuse to resume a partial file of another detector, params or run."""
        target = self.path
        try:
            differences = (
                ("detectors", detector_difference(h5["detector"], self.detector)),
                ("parameters", params_difference(h5["params"], self.params)),
                ("settings", run_difference(_text_attr(h5, "run"), json.loads(self.run))),
            )
        except (KeyError, OSError, ValueError) as error:
            raise _damaged(self._tmp, target, error) from None
        for what, difference in differences:
            if difference is not None:
                raise EventFileError(
                    f"{target}: cannot resume, the {what} differ from the interrupted"
                    f" run's ({difference}); resume with the same settings or delete"
                    f" {checkpoint_path(target).name}"
                )

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

    @interrupts_deferred()  # an interrupt waits until the file is closed or kept
    def __exit__(self, exc_type, exc, traceback) -> None:
        if exc_type is not None:
            if self.run is not None and (self.resume or self.n_run_events > 0):
                self._close_keeping()
            else:
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
            if self.run is not None:
                self._close_keeping()
            else:
                self._discard()
            if isinstance(error, OSError):
                raise EventFileError(f"{self.path}: cannot write ({error})") from None
            raise

    def _close_keeping(self) -> None:
        """Checkpoint what can be and close, keeping the partial file of a resumable
        write (its ``/events`` attribute ``n_events`` counts the events it holds)."""
        if self._h5 is not None:
            with contextlib.suppress(Exception):
                self._flush()
            with contextlib.suppress(Exception):
                self._h5.close()
            self._h5 = None
            with contextlib.suppress(OSError):
                _fsync(self._tmp)
        self._buffer = []
        self._tmp = None

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
        due = self.run is not None and (
            monotonic() - self._checkpointed >= CHECKPOINT_SECONDS
        )
        if len(self._buffer) >= self.chunk_events or due:
            self._flush()

    def extend(self, events: Iterable[Event]) -> None:
        """Add every event of an iterable (a list, a generator...) with bounded memory."""
        for event in _iterate(events, self.path):
            self.append(event)

    @interrupts_deferred()  # a chunk is written whole: an interrupt waits for its end
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
        if self.run is not None:
            self._h5.flush()
            self._checkpointed = monotonic()


def _text_attr(h5: h5py.File, name: str) -> str:
    """A root string attribute ("{}" when absent), decoded from bytes if need be."""
    value = h5.attrs.get(name, "{}")
    return value.decode() if isinstance(value, bytes) else str(value)


def _damaged(partial: Path, target: Path, reason) -> EventFileError:
    """The one-line error for a partial file that cannot be resumed."""
    return EventFileError(
        f"{target}: cannot resume, {partial.name} is damaged ({reason}); delete it and run"
        " again without resuming"
    )


def _open_partial(partial: Path, target: Path, mode: str) -> h5py.File:
    """``h5py.File(partial, mode)`` with a one-line error naming the damage."""
    try:
        return h5py.File(partial, mode)
    except OSError as error:
        raise _damaged(partial, target, error) from None


def _reopen_checkpoint(partial: Path, target: Path) -> h5py.File:
    """Open an interrupted run's partial file read/write, cut every ``/events`` dataset
    back to the last checkpoint (``/events`` attribute ``n_events``) and check it.

    Raises:
        EventFileError: the file is not a readable partial event file (one line).
    """
    h5 = _open_partial(partial, target, "r+")
    try:
        events = h5["events"]
        n_events = int(events.attrs["n_events"])
        offsets = events["offsets"]
        if offsets.shape[0] < n_events + 1:
            raise _damaged(partial, target, f"{offsets.shape[0]} offsets < n_events + 1")
        n_hits = int(offsets[n_events])
        datasets = [(offsets, n_events + 1)]
        datasets += [(events["truth"][name], n_events) for name in TRUTH_FIELDS]
        datasets += [(events["hits"][name], n_hits) for name in HIT_FIELDS]
        for dataset, length in datasets:
            if dataset.shape[0] < length:
                raise _damaged(partial, target, f"{dataset.name} is too short")
            dataset.resize((length, *dataset.shape[1:]))
        check_layout(h5, partial)
    except EventFileError:
        h5.close()
        raise
    except Exception as error:
        h5.close()
        raise _damaged(partial, target, error) from None
    h5.attrs["modified"] = now_iso()
    return h5


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
            total = len(events) if hasattr(events, "__len__") else None
            events = with_progress(_iterate(events, writer.path),
                                   f"writing {writer.path.name}", total=total)
        writer.extend(events)
    return writer.path
