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

The partial files and resuming from them are ``partial_files.py``; checking, buffering
and writing the events chunk by chunk is ``event_chunks.py`` (``_EventChunks``, the base
class of ``EventWriter``).
"""

from __future__ import annotations

import contextlib
import json
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
from .event_chunks import _EventChunks, _iterate
from .events import Event
from .hdf5 import create_layout, detector_difference, now_iso, open_checked, params_difference
from .partial_files import (
    _damaged,
    _fsync,
    _open_partial,
    _reopen_checkpoint,
    _settings_json,
    _temporary_path,
    _text_attr,
    checkpoint_path,
    run_difference,
)

MODES = ("create", "recreate", "append")


class EventWriter(_EventChunks):
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
