"""Adding events to an open event file: ``_EventChunks``, the part of ``EventWriter``
(``writer.py``) that checks each ``Event``, buffers it and writes the buffer to the
``/events`` datasets chunk by chunk (hits: sensor id, charge in p.e., time in ns; truth:
position m, direction, kinetic energy MeV, time ns, seed).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from time import monotonic

import numpy as np

from ..errors import EventFileError
from ..interrupts import interrupts_deferred
from .events import Event, Truth, hit_arrays_problem, unknown_vector
from .hdf5 import HIT_FIELDS, TRUTH_FIELDS
from .partial_files import CHECKPOINT_SECONDS

#: Truth columns stored for an event without truth (all "unknown").
_UNKNOWN_TRUTH = ("", "", unknown_vector(), unknown_vector(), math.nan, math.nan, -1)


class _EventChunks:
    """The adding half of ``EventWriter``, which sets what it uses: ``path``, ``detector``,
    ``chunk_events``, ``run``, the open file ``_h5``, the buffer ``_buffer``, the counts
    ``_n_events`` and ``_n_hits`` written so far, ``_checkpointed`` (``monotonic()`` time of
    the last checkpoint) and the property ``n_events``."""

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
