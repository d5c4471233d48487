"""Calibration runs from event files: the source rebuilt from a file's run settings.

``photonflow simulate`` stores its settings in the root attribute ``run`` (JSON text):
the source kind (``"source": "IsotropicSource"`` ...) and every field of the source
(position m, n_photons, time ns, pulse_width ns, direction, opening_angle rad,
anisotropy), with the seed, event count and bounces. ``open_runs`` turns a list of such
files into the ``(source, events)`` pairs that ``photonflow.calibration.calibrate``
takes, checking them against the detector being calibrated.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from ..errors import ConfigError, EventFileError
from ..geometry.detector import Detector
from ..params import Params
from .reader import EventFile, read_events


@dataclasses.dataclass
class OpenRuns:
    """Calibration runs read from event files (close with ``close`` or ``with``).

    Attributes:
        runs: one (source, ``EventFile``) pair per file, in the given order.
        settings: each file's run settings (the parsed ``run`` attribute).
        truth: the ``Params`` stored in the files when all files hold the same ones
            (pseudo-data: the true parameters), else None.
    """

    runs: list[tuple[object, EventFile]]
    settings: list[dict]
    truth: Params | None

    @property
    def bounces(self) -> int | None:
        """The largest ``bounces`` run setting of the files (None if none records it)."""
        values = [int(s["bounces"]) for s in self.settings if "bounces" in s]
        return max(values) if values else None

    def close(self) -> None:
        """Close every file."""
        for _, events in self.runs:
            events.close()

    def __enter__(self) -> OpenRuns:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def run_settings(events: EventFile) -> dict:
    """The run settings of an event file (its root attribute ``run``, JSON).

    Raises:
        EventFileError: no ``run`` attribute (a file not written by one
            ``photonflow simulate`` run, or appended to) or one that is not JSON.
    """
    text = events.h5.attrs.get("run")
    if text is None:
        raise EventFileError(
            f"{events.path}: no run settings (root attribute 'run'): the calibration source"
            " is unknown; use a file written by one 'photonflow simulate' run"
        )
    if isinstance(text, bytes):
        text = text.decode()
    try:
        settings = json.loads(str(text))
    except json.JSONDecodeError as error:
        raise EventFileError(f"{events.path}: run settings are not JSON ({error})") from None
    if not isinstance(settings, dict):
        raise EventFileError(f"{events.path}: run settings are not a JSON object")
    return settings


def source_from_settings(settings: dict, path: str | os.PathLike = "run"):
    """Rebuild the calibration source recorded in run settings.

    Args:
        settings: parsed run settings: ``source`` (class name: IsotropicSource,
            LaserSource or DiffuserSource) and the source's fields (m, ns, rad, photons).
        path: the file, named in errors.

    Raises:
        EventFileError: a particle-track run, no or an unknown source kind, or a missing
            source field (one line naming the file).
    """
    from ..sources import SOURCE_KINDS

    classes = {cls.__name__: cls for cls in SOURCE_KINDS.values()}
    kind = settings.get("source")
    if kind is None:
        what = (f"a {settings['particle']} particle-track run" if "particle" in settings
                else "no 'source' in its run settings")
        raise EventFileError(f"{path}: {what}; calibration needs a calibration-source run")
    if kind not in classes:
        raise EventFileError(
            f"{path}: run source = {kind!r}: not one of {', '.join(classes)}"
        )
    cls = classes[kind]
    values = {}
    for field in dataclasses.fields(cls):
        if field.name in settings:
            values[field.name] = np.asarray(settings[field.name], dtype=np.float64)
        elif field.default is dataclasses.MISSING:
            raise EventFileError(f"{path}: run source {kind}: field {field.name!r} missing")
    return cls(**values)


def _same_params(a: Params, b: Params) -> bool:
    first, second = a.to_dict(), b.to_dict()
    return all(
        np.array_equal(np.asarray(first[name]), np.asarray(second[name]), equal_nan=True)
        for name in first
    )


def open_runs(paths, detector: Detector) -> OpenRuns:
    """Open event files as calibration runs of ``detector``, one run per file.

    Each file must have been recorded in ``detector`` (same sensors) and hold the
    run settings of one ``photonflow simulate`` run, from which its source is rebuilt.

    Args:
        paths: event files (HDF5).
        detector: the detector being calibrated.

    Returns:
        ``OpenRuns`` (the files stay open until it is closed).

    Raises:
        ConfigError: no files, or a file recorded in another detector (naming it).
        EventFileError: a file that cannot be read, has no run settings or no
            calibration source (naming it).
    """
    from ..calibration.runs import same_sensors
    from ..sources import check_source

    paths = [Path(path) for path in paths]
    if not paths:
        raise ConfigError("FILE: give at least one event file of a calibration run")
    opened: list[tuple[object, EventFile]] = []
    settings: list[dict] = []
    try:
        for path in paths:
            events = read_events(path)
            opened.append((None, events))
            stored = events.detector
            if not same_sensors(stored, detector):
                raise ConfigError(
                    f"{path}: recorded in {stored.name} ({stored.n_sensors} sensors), not in"
                    f" {detector.name} ({detector.n_sensors} sensors): calibrate each"
                    " detector with its own runs"
                )
            if len(events) == 0:
                raise EventFileError(f"{path}: no events")
            run = run_settings(events)
            source = source_from_settings(run, path)
            try:
                check_source(source, detector)
            except ConfigError as error:
                raise ConfigError(f"{path}: {error}") from None
            opened[-1] = (source, events)
            settings.append(run)
        stored_params = [events.params for _, events in opened]
    except BaseException:
        for _, events in opened:
            with contextlib.suppress(Exception):
                events.close()
        raise
    truth = stored_params[0]
    if not all(_same_params(truth, other) for other in stored_params[1:]):
        truth = None
    return OpenRuns(runs=opened, settings=settings, truth=truth)
