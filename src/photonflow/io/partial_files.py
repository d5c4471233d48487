"""The partial files of an event write (``writer.py``) and resuming from them.

A plain write fills a temporary file ``.{name}.partial-{pid}`` beside the target
(``_temporary_path``); a resumable one (``run=`` settings given) fills the checkpoint file
``.{name}.partial`` (``checkpoint_path``), every ``CHECKPOINT_SECONDS`` seconds at least,
with the run's settings as canonical JSON in the root attribute ``run``
(``_settings_json``, ``run_difference``). Resuming reopens that file and cuts it back to
its last checkpoint (``_reopen_checkpoint``), with one-line errors for a damaged one.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

import h5py

from ..errors import EventFileError
from .hdf5 import HIT_FIELDS, TRUTH_FIELDS, check_layout, now_iso

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


def _text_attr(h5: h5py.File, name: str, default: str = "{}") -> str:
    """A root string attribute (``default`` when absent), decoded from bytes if need be."""
    value = h5.attrs.get(name, default)
    return value.decode() if isinstance(value, bytes) else str(value)


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
