"""Reading event files lazily: ``EventFile`` and ``read_events``.

Nothing but the file's attributes is read on opening; events are read on demand,
one at a time (``f[i]``) or one block of hits at a time (iteration, ``iter_chunks``).
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np

from ..errors import EventFileError
from ..geometry.detector import Detector
from ..params import Params
from .events import Event, Truth
from .hdf5 import (
    HIT_FIELDS,
    READ_ERRORS,
    TRUTH_FIELDS,
    damaged,
    open_checked,
    read_detector,
    read_params,
)

#: Events per block when iterating over a file.
ITER_CHUNK = 10000


def _frozen(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


class EventFile:
    """An open event file: a lazy, read-only sequence of ``Event``.

    Supports ``len(f)``, ``f[i]`` (negative indices too), ``f[a:b]`` (a list),
    iteration, ``f.iter_chunks(n)``, and ``with`` (closes the file).

    Attributes:
        path: the file.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path).expanduser()
        self._h5: h5py.File | None = open_checked(self.path)
        try:
            self._n_events = int(self._h5["events/offsets"].shape[0]) - 1
            # Dataset handles are kept open: HDF5's chunk cache lives with the handle, so
            # consecutive small reads do not decompress the same chunk again.
            events = self._h5["events"]
            self._offsets = events["offsets"]
            self._hits = {name: events["hits"][name] for name in HIT_FIELDS}
            self._truth = {
                name: events["truth"][name].asstr() if dtype.kind == "O"
                else events["truth"][name]
                for name, (dtype, _) in TRUTH_FIELDS.items()
            }
        except READ_ERRORS as error:
            self.close()
            raise damaged(self.path, "/events", error) from None

    # ---- lifecycle -------------------------------------------------------------
    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._h5 is not None:
            self._h5.close()
            self._h5 = None

    def __enter__(self) -> EventFile:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def __del__(self) -> None:
        h5 = getattr(self, "_h5", None)
        if h5 is not None:
            with contextlib.suppress(Exception):
                h5.close()

    def __repr__(self) -> str:
        state = "closed" if self._h5 is None else f"{self._n_events} events"
        return f"EventFile({str(self.path)!r}, {state})"

    @property
    def h5(self) -> h5py.File:
        """The underlying open ``h5py.File`` (read-only)."""
        if self._h5 is None:
            raise EventFileError(f"{self.path}: file is closed")
        return self._h5

    # ---- provenance ------------------------------------------------------------
    @property
    def format_version(self) -> int:
        """Layout version of the file (``format_version`` root attribute)."""
        return int(self.h5.attrs["format_version"])

    @property
    def attrs(self) -> dict[str, str]:
        """Root attributes as strings: format, format_version, photonflow_version, created..."""
        return {
            key: value.decode() if isinstance(value, bytes) else str(value)
            for key, value in self.h5.attrs.items()
        }

    @functools.cached_property
    def detector(self) -> Detector:
        """The ``Detector`` the events were recorded in (rebuilt and validated)."""
        return read_detector(self.h5, self.path)

    @functools.cached_property
    def params(self) -> Params:
        """The ``Params`` stored with the events (JAX default float dtype)."""
        return read_params(self.h5, self.path)

    @property
    def n_hits(self) -> int:
        """Total number of hits in the file."""
        return int(self.h5["events/hits/sensor_id"].shape[0])

    # ---- events ----------------------------------------------------------------
    def __len__(self) -> int:
        return self._n_events

    def __getitem__(self, index):
        """Event ``index`` (negative counts from the end) or a list for a slice."""
        n = self._n_events
        if isinstance(index, slice):
            start, stop, step = index.indices(n)
            if step == 1:
                return self.read_block(start, max(start, stop))
            return [self[i] for i in range(start, stop, step)]
        if isinstance(index, bool) or not isinstance(index, int | np.integer):
            raise TypeError(
                f"event index must be an integer or a slice, not {type(index).__name__}"
            )
        i = int(index)
        if not -n <= i < n:
            valid = f"-{n}..{n - 1}" if n else "none, the file is empty"
            raise IndexError(f"event index {i} out of range for {self.path.name} (valid: {valid})")
        if i < 0:
            i += n
        return self.read_block(i, i + 1)[0]

    def __iter__(self) -> Iterator[Event]:
        for block in self.iter_chunks(ITER_CHUNK):
            yield from block

    def iter_chunks(self, n: int = ITER_CHUNK) -> Iterator[list[Event]]:
        """Yield lists of up to ``n`` consecutive events, reading one block of hits each."""
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
            raise EventFileError(f"iter_chunks(n = {n!r}): n must be a positive integer")
        for start in range(0, self._n_events, int(n)):
            yield self.read_block(start, min(start + int(n), self._n_events))

    def read_block(self, start: int, stop: int) -> list[Event]:
        """Events ``start`` to ``stop - 1`` (0 <= start <= stop <= len), read in one go.

        The returned arrays are read-only views of one block per dataset.
        """
        if not 0 <= start <= stop <= self._n_events:
            raise IndexError(
                f"event block {start}:{stop} out of range for {self.path.name}"
                f" (0..{self._n_events})"
            )
        if start == stop:
            return []
        if self._h5 is None:
            raise EventFileError(f"{self.path}: file is closed")
        try:
            offsets = self._offsets[start : stop + 1]
            h0, h1 = int(offsets[0]), int(offsets[-1])
            hits = {name: _frozen(dataset[h0:h1]) for name, dataset in self._hits.items()}
            truth = {
                name: _frozen(np.asarray(dataset[start:stop]))
                for name, dataset in self._truth.items()
            }
        except READ_ERRORS as error:
            raise damaged(self.path, f"events {start}:{stop}", error) from None
        local = offsets - h0
        if np.any(np.diff(local) < 0) or h1 - h0 != hits["sensor_id"].shape[0]:
            raise EventFileError(f"{self.path}: malformed, offsets {start}:{stop} not increasing")
        unknown = (
            (truth["source_kind"] == "")
            & (truth["particle"] == "")
            & np.all(np.isnan(truth["position"]), axis=1)
            & np.all(np.isnan(truth["direction"]), axis=1)
            & np.isnan(truth["energy"])
            & np.isnan(truth["time"])
            & (truth["seed"] == -1)
        )
        events = []
        for k in range(stop - start):
            a, b = local[k], local[k + 1]
            event_truth = None
            if not unknown[k]:
                event_truth = Truth(
                    source_kind=str(truth["source_kind"][k]),
                    particle=str(truth["particle"][k]),
                    position=truth["position"][k],
                    direction=truth["direction"][k],
                    energy=float(truth["energy"][k]),
                    time=float(truth["time"][k]),
                    seed=int(truth["seed"][k]),
                )
            events.append(
                Event(
                    hits["sensor_id"][a:b], hits["charge"][a:b], hits["time"][a:b],
                    truth=event_truth,
                )
            )
        return events


def read_events(path: str | os.PathLike) -> EventFile:
    """Open an event file for lazy reading (use as ``with read_events(p) as f: ...``).

    Args:
        path: an HDF5 file written by ``write_events`` / ``EventWriter``.

    Returns:
        An ``EventFile``: ``len``, indexing, iteration, ``iter_chunks``, ``detector``,
        ``params`` and ``format_version``.

    Raises:
        EventFileError: missing file, not HDF5, not a photonflow event file, a newer
            ``format_version``, or an inconsistent layout (one line, naming the file).
    """
    return EventFile(path)
