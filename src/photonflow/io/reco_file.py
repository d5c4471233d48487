"""Reconstruction files (``photonflow reconstruct --out reco.h5``): the fitted tracks of
an event file, one row per event in event order, written as they are fitted.

Layout (``docs/file-format.md``, "Reconstruction files"): root attributes ``format`` =
"photonflow-reco", ``format_version``, ``photonflow_version``, ``created``, ``run`` (the
job's settings as canonical JSON) and ``events_file``; ``/detector`` as in an event
file; ``/reco`` (``RECO_FIELDS``, attribute ``n_events``: the rows checkpointed) and
``/truth`` (the events' truth, ``TRUTH_COPY``, NaN or "" where an event has none).

``RecoWriter`` fills the checkpoint file ``.{name}.partial`` beside the target: every
row is written, flushed and counted in ``/reco`` ``n_events``, so a job killed at any
moment (SIGKILL included) keeps every row counted; ``resume=True`` reopens it, cuts it
back to its count and refuses one of other settings. The target appears (renamed) only
when the writer closes without an error. Lengths m, times ns, energies MeV.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from collections.abc import Mapping
from pathlib import Path

import h5py
import numpy as np

from .._version import __version__
from ..errors import EventFileError
from ..interrupts import interrupts_deferred
from .hdf5 import (
    COMPRESSION,
    READ_ERRORS,
    STRING_DTYPE,
    now_iso,
    read_detector,
    write_detector,
)
from .partial_files import (
    _damaged,
    _fsync,
    _open_partial,
    _settings_json,
    _text_attr,
    checkpoint_path,
    run_difference,
)

#: Value of the root attribute ``format`` of a reconstruction file.
RECO_FORMAT = "photonflow-reco"
RECO_FORMAT_VERSION = 1
#: Rows per HDF5 chunk.
ROW_CHUNK = 256
#: name -> (dtype, trailing shape) of the per-event datasets in ``/reco``.
RECO_FIELDS = {
    "event": (np.dtype(np.int64), ()),
    "particle": (STRING_DTYPE, ()),
    "position": (np.dtype(np.float64), (3,)),
    "time": (np.dtype(np.float64), ()),
    "direction": (np.dtype(np.float64), (3,)),
    "energy": (np.dtype(np.float64), ()),
    "covariance": (np.dtype(np.float64), (7, 7)),
    "errors": (np.dtype(np.float64), (6,)),
    "nll": (np.dtype(np.float64), ()),
    "log_likelihood_ratio": (np.dtype(np.float64), ()),
    "converged": (np.dtype(np.bool_), ()),
    "iterations": (np.dtype(np.int64), ()),
    "evaluations": (np.dtype(np.int64), ()),
    "seconds": (np.dtype(np.float64), ()),
    "failure": (STRING_DTYPE, ()),
    "fisher_covariance": (np.dtype(np.float64), (7, 7)),
    "bias": (np.dtype(np.float64), (7,)),
    "correction": (np.dtype(np.float64), (7,)),
}
#: Fields a file written before they existed lacks (read as NaN).
LATER_FIELDS = ("fisher_covariance", "bias", "correction")
#: Order of the columns of ``/reco/errors`` (``RecoResult.errors``).
ERROR_NAMES = ("x", "y", "z", "time", "direction_deg", "energy_frac")
#: name -> (dtype, trailing shape) of the truth copied into ``/truth``.
TRUTH_COPY = {
    "particle": (STRING_DTYPE, ()),
    "position": (np.dtype(np.float64), (3,)),
    "direction": (np.dtype(np.float64), (3,)),
    "energy": (np.dtype(np.float64), ()),
    "time": (np.dtype(np.float64), ()),
}


def reco_row(index: int, result, truth) -> dict:
    """The ``/reco`` and ``/truth`` values of event ``index``: its ``RecoResult`` and its
    ``Truth`` (or None)."""
    ratio = result.log_likelihood_ratio
    errors = result.errors
    row = {
        "event": index, "particle": result.particle,
        "position": np.asarray(result.position, np.float64), "time": result.time,
        "direction": np.asarray(result.direction, np.float64), "energy": result.energy,
        "covariance": np.asarray(result.covariance, np.float64),
        "errors": np.array([errors[name] for name in ERROR_NAMES]), "nll": result.nll,
        "log_likelihood_ratio": np.nan if ratio is None else ratio,
        "converged": result.converged, "iterations": result.iterations,
        "evaluations": result.evaluations, "seconds": result.seconds,
        "failure": result.failure or "",
        "fisher_covariance": _or_nan(result.fisher_covariance, (7, 7)),
        "bias": _or_nan(result.bias, (7,)),
        "correction": _or_nan(result.correction, (7,)),
    }
    nan3 = np.full(3, np.nan)
    row["truth"] = {
        "particle": getattr(truth, "particle", "") or "",
        "position": nan3 if truth is None else np.asarray(truth.position, np.float64),
        "direction": nan3 if truth is None else np.asarray(truth.direction, np.float64),
        "energy": np.nan if truth is None else truth.energy,
        "time": np.nan if truth is None else truth.time,
    }
    return row


def _or_nan(value, shape) -> np.ndarray:
    """``value`` as a float64 array, or NaN of ``shape`` where it is None."""
    return np.full(shape, np.nan) if value is None else np.asarray(value, np.float64)


class RecoWriter:
    """Context manager that writes a reconstruction file row by row (module docstring).

    Args:
        path: target file.
        detector: the detector of the events (stored in ``/detector``).
        run: the job's settings (JSON-able; a resumed job must give the same).
        events_file: the event file reconstructed (recorded, for provenance).
        mode: "create" (refuse an existing target) or "recreate" (overwrite it).
        resume: continue the partial file of an interrupted job.

    Raises:
        EventFileError: one line: an existing target (create), a partial file in the way
            (not resuming), none to resume, one of other settings, or a damaged one.
    """

    def __init__(self, path, detector, run: Mapping, *, events_file: str = "",
                 mode: str = "create", resume: bool = False) -> None:
        if mode not in ("create", "recreate"):
            raise EventFileError(f"mode = {mode!r}: must be create or recreate")
        self.path = Path(path).expanduser()
        self.detector = detector
        self.run = _settings_json(run)
        self.events_file = str(events_file)
        self.mode = mode
        self.resume = bool(resume)
        self.partial = checkpoint_path(self.path)
        self._h5: h5py.File | None = None
        self._n = 0

    @property
    def n_events(self) -> int:
        """Rows written so far (those of the interrupted job included)."""
        return self._n

    def __enter__(self) -> RecoWriter:
        target = self.path
        if not target.parent.is_dir():
            raise EventFileError(f"{target}: directory {target.parent} does not exist")
        if target.is_dir():
            raise EventFileError(f"{target}: is a directory; name a file")
        if self.mode == "create" and target.exists():
            raise EventFileError(f"{target}: file exists; use --mode recreate to overwrite it")
        if self.resume:
            if not self.partial.exists():
                raise EventFileError(
                    f"{target}: no interrupted job to resume ({self.partial.name} not found)")
            self._h5 = self._reopen()
        else:
            if self.partial.exists():
                if self.mode != "recreate":
                    raise EventFileError(
                        f"{target}: an interrupted job left {self.partial.name}; resume it"
                        " (--resume) or delete it")
                self.partial.unlink()
            try:
                self._h5 = h5py.File(self.partial, "w")
                self._create()
            except BaseException as error:  # an interrupt too: leave nothing behind
                if self._h5 is not None:
                    with contextlib.suppress(Exception):
                        self._h5.close()
                    self._h5 = None
                self.partial.unlink(missing_ok=True)
                if isinstance(error, OSError):
                    raise EventFileError(f"{target}: cannot write ({error})") from None
                raise
        return self

    def _create(self) -> None:
        h5 = self._h5
        h5.attrs["format"] = RECO_FORMAT
        h5.attrs["format_version"] = np.int64(RECO_FORMAT_VERSION)
        h5.attrs["photonflow_version"] = __version__
        h5.attrs["created"] = now_iso()
        h5.attrs["run"] = self.run
        h5.attrs["events_file"] = self.events_file
        write_detector(h5.create_group("detector"), self.detector)
        for group_name, fields in (("reco", RECO_FIELDS), ("truth", TRUTH_COPY)):
            group = h5.create_group(group_name)
            for name, (dtype, tail) in fields.items():
                group.create_dataset(name, shape=(0, *tail), maxshape=(None, *tail),
                                     dtype=dtype, chunks=(ROW_CHUNK, *tail), **COMPRESSION)
        h5["reco"].attrs["n_events"] = np.int64(0)
        h5.flush()

    def _reopen(self) -> h5py.File:
        """The partial file, checked against this job and cut back to its count."""
        h5 = _open_partial(self.partial, self.path, "r+")
        try:
            if _text_attr(h5, "format") != RECO_FORMAT:
                raise _damaged(self.partial, self.path, "not a reconstruction file")
            difference = run_difference(_text_attr(h5, "run"), json.loads(self.run))
            if difference is not None:
                raise EventFileError(
                    f"{self.path}: cannot resume, the settings differ from the interrupted"
                    f" job's ({difference}); resume with the same settings or delete"
                    f" {self.partial.name}")
            n = int(h5["reco"].attrs["n_events"])
            for group_name, fields in (("reco", RECO_FIELDS), ("truth", TRUTH_COPY)):
                for name in fields:
                    dataset = h5[group_name][name]
                    if dataset.shape[0] < n:
                        raise _damaged(self.partial, self.path, f"{dataset.name} too short")
                    dataset.resize((n, *dataset.shape[1:]))
            h5.attrs["modified"] = now_iso()
        except EventFileError:
            h5.close()
            raise
        except READ_ERRORS as error:
            h5.close()
            raise _damaged(self.partial, self.path, error) from None
        self._n = n
        return h5

    @interrupts_deferred()  # a row is written whole or not at all
    def write(self, row: Mapping) -> None:
        """Append one row (``reco_row``), flush it and count it."""
        h5, n = self._h5, self._n
        for group_name, values in (("reco", row), ("truth", row["truth"])):
            group = h5[group_name]
            fields = RECO_FIELDS if group_name == "reco" else TRUTH_COPY
            for name in fields:
                dataset = group[name]
                dataset.resize((n + 1, *dataset.shape[1:]))
                dataset[n] = values[name]
        h5.flush()
        h5["reco"].attrs["n_events"] = np.int64(n + 1)
        h5.flush()
        self._n = n + 1

    @interrupts_deferred()
    def __exit__(self, exc_type, exc, traceback) -> None:
        h5, self._h5 = self._h5, None
        if exc_type is None:
            h5.close()  # an error here must not rename a file that was not closed
        else:
            with contextlib.suppress(Exception):
                h5.close()
        _fsync(self.partial)
        if exc_type is not None:
            if self._n == 0:  # nothing to resume: leave nothing behind
                self.partial.unlink(missing_ok=True)
            return  # the partial file stays, to be resumed
        if self.mode == "create" and self.path.exists():
            raise EventFileError(f"{self.path}: file appeared while writing")
        os.replace(self.partial, self.path)


@dataclasses.dataclass(frozen=True)
class RecoTable:
    """A reconstruction file read into memory: ``reco`` and ``truth`` map each field of
    ``RECO_FIELDS`` / ``TRUTH_COPY`` to its array (one row per event); ``run`` holds the
    job's settings, ``attrs`` the root attributes and ``detector`` the events'
    ``Detector`` (None where the file's cannot be read)."""

    reco: dict
    truth: dict
    run: dict
    attrs: dict
    detector: object = None

    def __len__(self) -> int:
        return int(self.reco["event"].shape[0])


def read_reco(path) -> RecoTable:
    """Read a reconstruction file written by ``RecoWriter``.

    Raises:
        EventFileError: missing, not HDF5, not a reconstruction file, or damaged (one
            line naming the file).
    """
    path = Path(path).expanduser()
    if not path.is_file():
        raise EventFileError(f"{path}: no such file")
    try:
        with h5py.File(path, "r") as h5:
            found = _text_attr(h5, "format", "")
            if found != RECO_FORMAT:
                raise EventFileError(
                    f"{path}: not a photonflow reconstruction file (format attribute"
                    f" {found or 'missing'!r}, expected {RECO_FORMAT!r})")
            if int(h5.attrs["format_version"]) > RECO_FORMAT_VERSION:
                raise EventFileError(f"{path}: format_version is newer than this photonflow"
                                     " reads; upgrade photonflow")
            n = int(h5["reco"].attrs["n_events"])

            def read(group, fields):
                return {name: (group[name].asstr()[:n] if dtype == STRING_DTYPE
                               else group[name][:n])
                        if name in group or name not in LATER_FIELDS
                        else np.full((n, *tail), np.nan)  # an older file's
                        for name, (dtype, tail) in fields.items()}

            reco, truth = read(h5["reco"], RECO_FIELDS), read(h5["truth"], TRUTH_COPY)
            attrs = {key: _text_attr(h5, key) for key in h5.attrs}
            try:
                detector = read_detector(h5, path)
            except EventFileError:  # the results stay readable without it
                detector = None
    except EventFileError:
        raise
    except READ_ERRORS as error:
        raise EventFileError(f"{path}: not a readable reconstruction file ({error})") from None
    reco = {k: np.asarray(v, dtype=object if v.dtype.kind == "O" else v.dtype)
            for k, v in reco.items()}
    return RecoTable(reco=reco, truth=truth, run=json.loads(attrs.get("run", "{}")),
                     attrs=attrs, detector=detector)
