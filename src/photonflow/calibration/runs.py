"""Calibration runs: a light source and the events it produced, as per-sensor arrays.

A run's events are reduced once, before any fit, to what the likelihoods need:

- the summed charge of every sensor over the run's E events and whether it saw any
  charge (the run-level charge likelihood, ``objective.summed_charge_nll``);
- for the charge-and-time likelihood, dense (E, N) arrays of hit flags, charges and
  first-hit times.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence

import numpy as np

from ..errors import ConfigError
from ..geometry.detector import Detector
from ..io.events import Event
from ..sources import DiffuserSource, IsotropicSource, LaserSource, check_source, source_kind

#: The likelihoods a calibration can use.
LIKELIHOODS = ("charge", "charge+time")


@dataclasses.dataclass(frozen=True)
class CalibrationRun:
    """One calibration run: a source and its events (not validated; see ``prepare_runs``).

    Attributes:
        source: ``IsotropicSource``, ``LaserSource`` or ``DiffuserSource`` (m, ns).
        events: the recorded events (``Event``s, charges p.e., times ns).
        label: where the run came from (a file name), for provenance.
    """

    source: IsotropicSource | LaserSource | DiffuserSource
    events: tuple[Event, ...]
    label: str = ""


@dataclasses.dataclass(frozen=True)
class RunData:
    """A run reduced to per-sensor arrays (numpy; read-only use).

    Attributes:
        source: the run's source.
        label: provenance label.
        n_events: E, number of events (flashes) in the run.
        charge_sum: (N,) summed charge per sensor over the run, p.e.
        hit_any: (N,) bool, the sensor recorded charge in at least one event.
        hit, charge, time: (E, N) per-event hit flags, charges (p.e.) and first-hit
            times (ns; 0 where not hit), or None when only the summed charge is needed.
    """

    source: object
    label: str
    n_events: int
    charge_sum: np.ndarray
    hit_any: np.ndarray
    hit: np.ndarray | None = None
    charge: np.ndarray | None = None
    time: np.ndarray | None = None


def _as_run(item, index: int) -> CalibrationRun:
    """A ``CalibrationRun`` from a run or a (source, events) pair; events may be one
    ``Event``, a sequence of them or an open ``EventFile``."""
    if isinstance(item, CalibrationRun):
        return item
    try:
        source, events = item
    except (TypeError, ValueError):
        raise ConfigError(
            f"runs[{index}]: a {type(item).__name__}, expected a (source, events) pair"
        ) from None
    label = str(getattr(events, "path", "") or "")
    events = (events,) if isinstance(events, Event) else tuple(events)
    return CalibrationRun(source=source, events=events, label=label)


def _check_events(run: CalibrationRun, index: int, n_sensors: int) -> None:
    if not run.events:
        raise ConfigError(f"runs[{index}]: no events")
    for number, event in enumerate(run.events):
        if not isinstance(event, Event):
            raise ConfigError(
                f"runs[{index}].events[{number}]: a {type(event).__name__}, expected an Event"
            )
        ids = np.asarray(event.sensor_ids)
        if ids.size and (ids.min() < 0 or ids.max() >= n_sensors):
            raise ConfigError(
                f"runs[{index}].events[{number}]: sensor id {int(ids.max())} is not a sensor"
                f" of this detector ({n_sensors} sensors): events from another detector?"
            )


def same_sensors(a: Detector, b: Detector, tolerance: float = 1e-3) -> bool:
    """Do two detectors have the same sensors (count, and centres within ``tolerance`` m)?"""
    if a.n_sensors != b.n_sensors:
        return False
    difference = np.asarray(a.sensor_positions) - np.asarray(b.sensor_positions)
    return bool(np.all(np.abs(difference) <= tolerance))


def reduce_run(run: CalibrationRun, n_sensors: int, per_event: bool) -> RunData:
    """Reduce a run's events to per-sensor arrays (``per_event``: also (E, N) arrays)."""
    n_events = len(run.events)
    charge_sum = np.zeros(n_sensors, dtype=np.float64)
    if per_event:
        hit = np.zeros((n_events, n_sensors), dtype=bool)
        charge = np.zeros((n_events, n_sensors), dtype=np.float32)
        time = np.zeros((n_events, n_sensors), dtype=np.float32)
    for number, event in enumerate(run.events):
        ids = np.asarray(event.sensor_ids, dtype=np.int64)
        q = np.asarray(event.charge, dtype=np.float64)
        np.add.at(charge_sum, ids, q)
        if per_event:
            hit[number, ids] = True
            np.add.at(charge[number], ids, q.astype(np.float32))
            first = np.full(n_sensors, np.inf, dtype=np.float32)
            np.minimum.at(first, ids, np.asarray(event.time, dtype=np.float32))
            time[number] = np.where(hit[number], first, 0.0)
    return RunData(
        source=run.source,
        label=run.label,
        n_events=n_events,
        charge_sum=charge_sum.astype(np.float32),
        hit_any=charge_sum > 0,
        hit=hit if per_event else None,
        charge=charge if per_event else None,
        time=time if per_event else None,
    )


def prepare_runs(
    runs: Sequence | Iterable, detector: Detector, likelihood: str
) -> list[RunData]:
    """Validate the runs against the detector and reduce them (``reduce_run``).

    Raises:
        ConfigError: no runs, a bad (source, events) pair, a source outside the
            detector, an event with a sensor id the detector does not have, an event file
            recorded in another detector, or an unknown likelihood (one line each).
    """
    if likelihood not in LIKELIHOODS:
        raise ConfigError(f"likelihood = {likelihood!r}: must be one of {', '.join(LIKELIHOODS)}")
    items = list(runs)
    if not items:
        raise ConfigError("runs: empty; give at least one (source, events) pair")
    prepared = []
    for index, item in enumerate(items):
        run = _as_run(item, index)
        stored = getattr(item[1], "detector", None) if isinstance(item, tuple) else None
        if stored is not None and not same_sensors(stored, detector):
            raise ConfigError(
                f"runs[{index}] ({run.label or 'events'}): recorded in {stored.name}"
                f" ({stored.n_sensors} sensors), not in {detector.name}"
                f" ({detector.n_sensors} sensors): calibrate each detector with its own runs"
            )
        check_source(run.source, detector)
        _check_events(run, index, detector.n_sensors)
        prepared.append(reduce_run(run, detector.n_sensors, likelihood == "charge+time"))
    return prepared


def run_provenance(runs: Sequence[RunData]) -> tuple[dict, ...]:
    """Per run, for result files: label, source kind, position (m), photons per flash,
    events."""
    return tuple(
        {
            "label": run.label,
            "source": source_kind(run.source),
            "position_m": np.asarray(run.source.position, np.float64).tolist(),
            "n_photons": float(np.asarray(run.source.n_photons)),
            "n_events": run.n_events,
        }
        for run in runs
    )
