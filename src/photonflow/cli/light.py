"""The light of ``photonflow simulate`` from its options: a calibration source
(``--source``, ``--position``, ...) or per-event particle tracks (``--particle``,
``--energy``, ``--vertex``, ...), each with the JSON-able settings that the event file
records, and one-line errors naming the option."""

from __future__ import annotations

import math


def parse_vector(text: str, option: str) -> tuple[float, float, float]:
    """Three comma-separated numbers ("x,y,z"); a one-line ``ConfigError`` otherwise."""
    from ..errors import ConfigError

    parts = [part.strip() for part in text.split(",")]
    try:
        values = tuple(float(part) for part in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ConfigError(f"{option} = {text!r}: expected three comma-separated numbers")
    return values


def parse_unit_vector(text: str, option: str) -> tuple[float, float, float]:
    """``parse_vector`` normalised to unit length; a ``ConfigError`` for the zero vector."""
    from ..errors import ConfigError

    values = parse_vector(text, option)
    length = math.sqrt(sum(v * v for v in values))
    if not length > 0:
        raise ConfigError(f"{option} = {text!r}: must be a non-zero vector")
    return (values[0] / length, values[1] / length, values[2] / length)


def parse_energies(energy: float | None, energy_range: str | None, spectrum: str | None = None):
    """Kinetic energy (MeV) or (low, high) from ``--energy`` / ``--energy-range``;
    exactly one must be given, within (0, MAXIMUM_ENERGY] MeV; ``--spectrum`` only
    with a range (checked by ``parse_spectrum``)."""
    from ..errors import ConfigError
    from ..generator.track import MAXIMUM_ENERGY
    from ..transport.tracks import parse_spectrum

    if (energy is None) == (energy_range is None):
        raise ConfigError("--energy / --energy-range: give exactly one for a --particle")
    if spectrum is not None:
        parse_spectrum(spectrum, "--spectrum")
        if energy_range is None:
            raise ConfigError(f"--spectrum = {spectrum!r}: only with --energy-range")
    if energy is not None:
        if not 0 < energy <= MAXIMUM_ENERGY:
            raise ConfigError(f"--energy = {energy:g}: must be in (0, {MAXIMUM_ENERGY:g}] MeV")
        return energy
    parts = energy_range.split(",")
    try:
        low, high = (float(part) for part in parts)
    except ValueError:
        low = high = math.nan
    if not 0 < low < high <= MAXIMUM_ENERGY:
        raise ConfigError(
            f"--energy-range = {energy_range!r}: expected LOW,HIGH MeV with"
            f" 0 < LOW < HIGH <= {MAXIMUM_ENERGY:g}"
        )
    return (low, high)


def track_sources(detector, particle, energy, energy_range, vertex, direction, margin, seed,
                  events, spectrum=None):
    """The per-event ``Track``s of ``simulate --particle`` (``random_tracks``), with
    one-line errors naming the option, and the settings that make them (a JSON-able
    dict: particle, energy MeV or [low, high], spectrum, vertex, direction,
    fiducial_margin m; ``margin`` None: ``default_fiducial_margin``)."""
    from ..errors import ConfigError
    from ..generator.particles import PARTICLES
    from ..transport.tracks import default_fiducial_margin, random_tracks

    if particle not in PARTICLES:
        raise ConfigError(f"--particle = {particle!r}: must be one of {', '.join(PARTICLES)}")
    if vertex != "uniform-fiducial":
        point = parse_vector(vertex, "--vertex")
        if float(detector.shape.distance_to_wall(point)) < 0:
            raise ConfigError(f"--vertex = {vertex!r}: outside the {detector.shape.describe()}")
        vertex = point
    if direction != "isotropic":
        direction = parse_unit_vector(direction, "--direction")
    if margin is None:
        margin = default_fiducial_margin(detector)
    if not (math.isfinite(margin) and margin >= 0):
        raise ConfigError(f"--fiducial-margin = {margin:g}: must be >= 0 m")
    energies = parse_energies(energy, energy_range, spectrum)
    settings = {
        "particle": particle, "energy": energies, "spectrum": spectrum or "uniform",
        "vertex": vertex, "direction": direction, "fiducial_margin": margin,
    }
    tracks = random_tracks(
        detector, particle, energies, seed, events, vertex=vertex, direction=direction,
        fiducial_margin=margin, spectrum=spectrum or "uniform",
    )
    return tracks, settings


def source_settings(source) -> dict:
    """A calibration source as a JSON-able dict: its kind and every field (m, ns, rad,
    photons) as numbers or lists."""
    import dataclasses

    import numpy as np

    fields = {f.name: np.asarray(getattr(source, f.name)).tolist()
              for f in dataclasses.fields(source)}
    return {"source": type(source).__name__, **fields}


def calibration_source(detector, source, position, direction, opening_angle, anisotropy,
                       photons, pulse_width):
    """The calibration source of ``simulate`` without ``--particle`` (``make_source``;
    ``source`` None: isotropic), checked against ``detector``, and its settings
    (``source_settings``)."""
    from ..sources import check_source, make_source

    light = make_source(
        source or "isotropic", parse_vector(position, "--position"), photons,
        direction=None if direction is None else parse_vector(direction, "--direction"),
        opening_angle=opening_angle, anisotropy=anisotropy, pulse_width=pulse_width,
    )
    check_source(light, detector)
    return light, source_settings(light)
