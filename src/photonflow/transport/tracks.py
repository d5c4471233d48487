"""Particle tracks in sampled mode: their photons, truth and random fiducial tracks.

A ``Track`` is generated (``photonflow.generate``) in the detector's medium; photons
emitted outside the detector are dropped and each is kept with the sensor's relative
spectral response (``spectral_keep_probability``), while ``spectral_params`` raises the
QE by the response's peak, so ``params.quantum_efficiency`` keeps meaning the QE at the
reference wavelength (docs/transport.md, "Particle tracks in sampled mode"). Lengths
m, times ns, energies MeV.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..config.loader import DEFAULT_MEDIUM
from ..errors import ConfigError, format_value
from ..generator import GeneratorSettings, Track, generate, generate_together
from ..geometry.detector import Detector
from ..geometry.presets import PRESETS
from ..io.events import Truth
from ..medium import MEDIA
from ..params import Params
from ..photosensors import SensorModel, peak_response, sensor_model, spectral_keep_probability
from .sampled import check_seed, inside_detector


class PhotonBundle(NamedTuple):
    """Photons to transport: ``position`` (M, 3) m, unit ``direction`` (M, 3), emission
    ``time`` (M,) ns."""

    position: np.ndarray
    direction: np.ndarray
    time: np.ndarray


@dataclasses.dataclass(frozen=True)
class TrackLight:
    """How a track's light is made for a detector.

    Attributes:
        medium: generator medium, "water" or "scintillator".
        sensor: the sensor model whose spectral response thins the photons (the
            detector's most common one, as in ``default_params``).
        settings: generator settings (None: defaults).
    """

    medium: str
    sensor: SensorModel
    settings: GeneratorSettings | None = None


def detector_medium(detector: Detector) -> str:
    """The medium of a preset detector ("water" or "scintillator"); "water" for others."""
    preset = PRESETS.get(detector.name)
    return DEFAULT_MEDIUM if preset is None else preset.medium


def principal_sensor_model(detector: Detector) -> SensorModel:
    """The detector's most common sensor model (the one ``default_params`` reads)."""
    counts = np.bincount(np.asarray(detector.sensor_type), minlength=len(detector.sensor_models))
    return sensor_model(detector.sensor_models[int(np.argmax(counts))])


def track_light(
    detector: Detector, medium: str | None = None, settings: GeneratorSettings | None = None
) -> TrackLight:
    """``TrackLight`` for ``detector``: ``medium`` (default ``detector_medium``), its
    principal sensor model and the generator ``settings``."""
    medium = detector_medium(detector) if medium is None else medium
    if medium not in MEDIA:
        raise ConfigError(f"medium = {format_value(medium)}: must be one of {', '.join(MEDIA)}")
    return TrackLight(medium, principal_sensor_model(detector), settings)


def event_seeds(seed: int, index: int):
    """(generator, spectral thinning, kinematics) ``SeedSequence``s of event ``index``:
    the children of ``SeedSequence(seed, spawn_key=(index,))``."""
    return np.random.SeedSequence(seed, spawn_key=(index,)).spawn(3)


def track_photons(
    detector: Detector, track: Track, seed: int, index: int, light: TrackLight
) -> PhotonBundle:
    """The generated photons of ``track`` (event ``index`` of ``seed``) that the
    single-wavelength transport follows (``detector_bundle``)."""
    generator_seed, thinning_seed, _ = event_seeds(seed, index)
    photons = generate(track, generator_seed, medium=light.medium, settings=light.settings)
    return detector_bundle(detector, photons, thinning_seed, light)


def together_seed(seed: int) -> np.random.SeedSequence:
    """The generator's ``SeedSequence`` for tracks generated together
    (``track_photons_together``): a child of ``seed`` that no single event uses."""
    return np.random.SeedSequence(seed, spawn_key=(0, 0))


def track_photons_together(
    detector: Detector, tracks: Sequence[Track], seed: int, light: TrackLight
) -> list[PhotonBundle]:
    """``track_photons`` of several tracks, one event each, from one run of the generator
    (``generator.generate_together``, seeded by ``together_seed``; event k thinned with
    the seed of event k of ``seed``): independent events, but not those of
    ``track_photons``."""
    photons = generate_together(tracks, together_seed(seed), medium=light.medium,
                                settings=light.settings)
    return [detector_bundle(detector, event, event_seeds(seed, k)[1], light)
            for k, event in enumerate(photons)]


def detector_bundle(detector: Detector, photons, thinning_seed, light: TrackLight
                    ) -> PhotonBundle:
    """The generator's ``photons`` that the single-wavelength transport follows: those
    emitted inside the detector (light made beyond the wall is dropped), each kept with
    ``spectral_keep_probability`` of its wavelength for ``light.sensor`` (uniforms from
    ``thinning_seed``)."""
    inside = inside_detector(detector, photons.position)
    keep_probability = spectral_keep_probability(light.sensor, photons.wavelength)
    kept = inside & (np.random.default_rng(thinning_seed).random(len(photons)) < keep_probability)
    return PhotonBundle(photons.position[kept], photons.direction[kept], photons.time[kept])


def spectral_params(params: Params, light: TrackLight) -> Params:
    """``params`` with the QE raised by the sensor's ``peak_response`` (>= 1), the partner
    of ``spectral_keep_probability``: kept photons are then detected with the QE at their
    own wavelength, while ``params.quantum_efficiency`` stays the QE at 400 nm."""
    return params.replace(
        quantum_efficiency=params.quantum_efficiency * peak_response(light.sensor)
    )


def track_truth(track: Track, seed: int) -> Truth:
    """The ``Truth`` of a track event: kind "track", particle, start position (m),
    direction, kinetic energy (MeV), start time (ns) and the seed."""
    return Truth(
        source_kind="track",
        particle=track.particle,
        position=np.asarray(track.position, dtype=np.float64),
        direction=np.asarray(track.direction, dtype=np.float64),
        energy=float(track.energy),
        time=float(track.time),
        seed=int(seed),
    )


def check_track(track: Track, detector: Detector) -> Track:
    """Raise a one-line ``ConfigError`` if the track (or a track of a batch) starts
    outside the detector."""
    positions = np.asarray(track.position, dtype=np.float64).reshape(-1, 3)
    distance = np.asarray(detector.shape.distance_to_wall(positions), dtype=np.float64)
    bad = np.flatnonzero(distance < 0)
    if bad.size:
        i = int(bad[0])
        where = f"[{i}]" if np.ndim(track.position) > 1 else ""
        raise ConfigError(
            f"track.position{where} = {format_value(positions[i].tolist())}: outside the "
            f"{detector.shape.describe()} by {-distance[i]:.3g} m"
        )
    return track


def uniform_vertex(rng: np.random.Generator, detector: Detector, margin: float) -> np.ndarray:
    """A point (3,) m uniform in the fiducial volume: inside the detector at least
    ``margin`` m from every wall (rejection from the cube of side ``shape.extent``
    about the origin, which holds every centred shape)."""
    half = 0.5 * detector.shape.extent
    while True:
        points = rng.uniform(-half, half, size=(256, 3))
        inside = np.asarray(detector.shape.distance_to_wall(points)) >= margin
        if inside.any():
            return points[np.argmax(inside)]


def isotropic_direction(rng: np.random.Generator) -> np.ndarray:
    """A unit vector (3,) uniform over the sphere."""
    cos_theta, phi = 2.0 * rng.random() - 1.0, 2.0 * math.pi * rng.random()
    sin_theta = math.sqrt(max(1.0 - cos_theta * cos_theta, 0.0))
    return np.array([sin_theta * math.cos(phi), sin_theta * math.sin(phi), cos_theta])


def parse_spectrum(spectrum: str, option: str = "spectrum") -> float:
    """The index GAMMA of an energy spectrum dN/dE proportional to E^-GAMMA (E in MeV):
    "uniform" is GAMMA = 0, "power:GAMMA" any finite GAMMA (1: log-uniform).

    Raises:
        ConfigError: anything else (one line naming ``option`` and the value).
    """
    if spectrum == "uniform":
        return 0.0
    kind, _, index = str(spectrum).partition(":")
    try:
        gamma = float(index) if kind == "power" else math.nan
    except ValueError:
        gamma = math.nan
    if not math.isfinite(gamma):
        raise ConfigError(
            f"{option} = {spectrum!r}: expected uniform or power:GAMMA (dN/dE ~ E^-GAMMA,"
            " GAMMA a finite number)"
        )
    return gamma


def spectrum_energy(quantile: float, low: float, high: float, gamma: float) -> float:
    """The energy (MeV) at ``quantile`` in [0, 1) of dN/dE ~ E^-gamma on [low, high] MeV
    (inverse cumulative distribution; gamma = 0 uniform, 1 log-uniform).

    Computed from logarithms, log(E / low) = log(1 + q ((high/low)^(1-gamma) - 1)) /
    (1 - gamma), so that any finite gamma works: a steep spectrum piles up at ``low``
    (gamma >> 1) or ``high`` (gamma << 0) instead of overflowing."""
    if gamma == 0:
        return low + (high - low) * quantile
    if gamma == 1:
        energy = low * (high / low) ** quantile
    elif quantile <= 0:
        energy = low
    else:
        power = 1.0 - gamma
        exponent = power * math.log(high / low)  # log (high/low)^power
        if exponent > 0:  # log(1 + q (e^x - 1)) = x + log(q + (1 - q) e^-x)
            log_ratio = exponent + math.log(quantile + (1.0 - quantile) * math.exp(-exponent))
        else:
            log_ratio = math.log1p(quantile * math.expm1(exponent))
        energy = low * math.exp(log_ratio / power)
    return min(max(energy, low), high)


#: Largest default fiducial margin, m, and the largest share of the distance from the
#: detector's centre to its nearest wall that the default takes.
DEFAULT_FIDUCIAL_MARGIN = 2.0
FIDUCIAL_MARGIN_SHARE = 0.25


def default_fiducial_margin(detector: Detector) -> float:
    """The default ``fiducial_margin`` of ``random_tracks``, m: 2 m, or a quarter of the
    distance from the detector's centre to its nearest wall where that is less (0.5 m
    in the 4 m toys, 0.34 m in WCTE, 0.255 m in TAO)."""
    depth = float(np.asarray(detector.shape.distance_to_wall(np.zeros(3))))
    return min(DEFAULT_FIDUCIAL_MARGIN, FIDUCIAL_MARGIN_SHARE * depth)


def random_tracks(
    detector: Detector,
    particle: str,
    energy,
    seed: int,
    n_events: int,
    *,
    vertex="uniform-fiducial",
    direction="isotropic",
    fiducial_margin: float | None = None,
    spectrum: str = "uniform",
) -> list[Track]:
    """``n_events`` tracks for ``sample_events(..., seed, n_events)``; track i draws its
    vertex, direction and energy from the kinematics seed of ``event_seeds(seed, i)``.

    Args:
        detector: where the vertices lie (m).
        particle: "mu-", "mu+", "e-", "e+" or "gamma".
        energy: kinetic energy, MeV, or (low, high) MeV drawn from ``spectrum``.
        seed: the events' seed.
        n_events: number of tracks.
        vertex: "uniform-fiducial" (uniform in the detector at least ``fiducial_margin``
            m from every wall) or a fixed point (3,) m.
        direction: "isotropic" or a fixed unit vector (3,).
        fiducial_margin: m, >= 0 and less than the detector's largest wall distance;
            default ``default_fiducial_margin(detector)`` (2 m in the large tanks).
        spectrum: of an energy range: "uniform" or "power:GAMMA" (dN/dE ~ E^-GAMMA;
            ``parse_spectrum``), drawn by ``spectrum_energy`` from one uniform number.

    Raises:
        ConfigError: bad energy range, spectrum, margin or fixed vector (one line).
    """
    seed = check_seed(seed)
    gamma = parse_spectrum(spectrum)
    low, high = (energy, energy) if isinstance(energy, numbers.Real) else energy
    if not 0 < low <= high:
        raise ConfigError(f"energy = {format_value(energy)}: must be > 0 MeV, low <= high")
    if fiducial_margin is None:
        fiducial_margin = default_fiducial_margin(detector)
    depth = float(np.asarray(detector.shape.distance_to_wall(np.zeros(3))))
    if vertex == "uniform-fiducial" and not 0 <= fiducial_margin < depth:
        raise ConfigError(
            f"fiducial margin = {format_value(fiducial_margin)} m: must be >= 0 and less than"
            f" {depth:.3g} m (no fiducial volume left in the {detector.shape.describe()})"
        )
    tracks = []
    for index in range(int(n_events)):
        rng = np.random.default_rng(event_seeds(seed, index)[2])
        fiducial = vertex == "uniform-fiducial"
        start = uniform_vertex(rng, detector, fiducial_margin) if fiducial else vertex
        heading = isotropic_direction(rng) if direction == "isotropic" else direction
        kinetic = low if low == high else spectrum_energy(rng.random(), low, high, gamma)
        tracks.append(check_track(Track(particle, start, heading, kinetic), detector))
    return tracks
