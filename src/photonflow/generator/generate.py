"""The generator's entry point: one primary particle in, photons and energy records out."""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Iterator, Sequence

import numpy as np

from photonflow.errors import ConfigError, format_value

from .cherenkov import EmissionPhotons, cherenkov_photons, cherenkov_spectrum
from .constants import CM_PER_M, ELECTRON_MASS
from .materials import Material, refractive_index, resolve_material
from .particles import PARTICLES
from .records import Deposits, EnergyBudget, Steps, Tracks
from .scintillation import scintillation_photons
from .settings import GeneratorSettings
from .tables import build_tables
from .track import Track
from .transport import transport


class Process(enum.IntEnum):
    """Emission process codes stored in :attr:`Photons.process`."""

    CHERENKOV = 0
    SCINTILLATION = 1


@dataclasses.dataclass(frozen=True)
class Photons:
    """Optical photons of one event and the event's energy records.

    Attributes:
        position: (M, 3) emission points, m (float32).
        direction: (M, 3) unit directions (float32).
        time: (M,) emission times, ns (float32).
        wavelength: (M,) nm (float32).
        process: (M,) :class:`Process` codes (int8): 0 Cherenkov, 1 scintillation.
        parent: (M,) id of the emitting track (int32; see ``tracks``).
        deposits: local energy deposits (m, ns, MeV).
        budget: energy bookkeeping (MeV).
        tracks: every particle of the event by track id (primary 0).
        steps: charged steps, the Cherenkov emitters (m, ns).
    """

    position: np.ndarray
    direction: np.ndarray
    time: np.ndarray
    wavelength: np.ndarray
    process: np.ndarray
    parent: np.ndarray
    deposits: Deposits
    budget: EnergyBudget
    tracks: Tracks
    steps: Steps

    def __len__(self) -> int:
        return int(self.time.size)


def resolve_settings(settings: GeneratorSettings | None, changes: dict) -> GeneratorSettings:
    """``settings`` (default: :class:`GeneratorSettings`) with keyword ``changes`` applied."""
    base = settings if settings is not None else GeneratorSettings()
    names = {f.name for f in dataclasses.fields(GeneratorSettings)}
    unknown = sorted(set(changes) - names)
    if unknown:
        raise ConfigError(f"unknown generator setting {unknown[0]!r}; known: {sorted(names)}")
    return dataclasses.replace(base, **changes)


def electron_cut_for(material: Material, settings: GeneratorSettings) -> float:
    """The e-/e+ cut, MeV: as set, or the Cherenkov threshold at the band's shortest wavelength."""
    if settings.electron_cut is not None:
        return float(settings.electron_cut)
    index = float(refractive_index(material, settings.band[0]))
    return float(ELECTRON_MASS * (1.0 / np.sqrt(1.0 - 1.0 / index**2) - 1.0))


def generate(
    track: Track,
    seed: int | np.random.SeedSequence,
    medium: str | Material = "water",
    settings: GeneratorSettings | None = None,
    **changes,
) -> Photons:
    """Generate the optical photons of one primary particle in an infinite medium.

    Args:
        track: the primary (species, start point m, unit direction, kinetic energy MeV,
            start time ns).
        seed: seed of the numpy random generator; the same seed gives identical output.
        medium: "water", "scintillator" (LAB) or a :class:`Material` (e.g.
            :func:`water_based_scintillator`).
        settings: cuts, steps, band and yield scale (:class:`GeneratorSettings`).
        **changes: individual settings overriding ``settings``, e.g. ``yield_scale=0.1``.

    Returns:
        :class:`Photons`: Cherenkov photons (band ``settings.band``) then scintillation
        photons, with the event's deposits, tracks and energy budget.
    """
    return next(generate_together([track], seed, medium, settings, **changes))


def generate_together(
    tracks: Sequence[Track],
    seed: int | np.random.SeedSequence,
    medium: str | Material = "water",
    settings: GeneratorSettings | None = None,
    **changes,
) -> Iterator[Photons]:
    """The photons of several primaries as independent events, generated together.

    Every event's particles advance in one stack, so numpy's per-call cost (most of a
    muon's generation time) is paid once per step for all of them: 16 muons of 1 GeV
    take about as many steps as one. The events are as independent and as distributed
    as those of ``generate`` each with its own seed, but they are other events: they
    depend on ``seed`` and on the whole list (the same list and seed give the same
    events). Arguments and units as in ``generate``; input is checked at the call, the
    particles are transported at the first event asked for, and each event's photons
    are made as it is asked for.

    Returns:
        an iterator of :class:`Photons`, one per track, in order.
    """
    tracks = list(tracks)
    for k, track in enumerate(tracks):
        where = "track" if len(tracks) == 1 else f"tracks[{k}]"
        if not isinstance(track, Track):
            raise ConfigError(
                f"{where} must be a photonflow.generator.Track, got {format_value(track)}"
            )
        if np.ndim(track.energy) != 0:
            raise ConfigError(f"{where} is a batch of {np.size(track.energy)} tracks:"
                              " give one Track per event")
    settings = resolve_settings(settings, changes)
    material = resolve_material(medium)
    return _generated(tracks, np.random.default_rng(seed), material, settings)


def _generated(tracks, rng, material, settings) -> Iterator[Photons]:
    """``generate_together`` after its checks."""
    tables = build_tables(
        material, electron_cut_for(material, settings), settings.photon_cut, settings.muon_cut
    )
    results = transport(
        [PARTICLES[track.particle].species for track in tracks],
        np.array([track.position for track in tracks], dtype=np.float64) * CM_PER_M,
        np.array([track.direction for track in tracks], dtype=np.float64),
        [track.energy for track in tracks],
        [track.time for track in tracks],
        material,
        tables,
        settings,
        rng,
    )
    spectrum = cherenkov_spectrum(material, settings.band)
    for result in results:
        cherenkov = cherenkov_photons(rng, spectrum, result.steps, settings.yield_scale)
        deposits = _deposits_in_metres(result.deposits)
        scintillation = scintillation_photons(rng, material, deposits, settings.yield_scale)
        yield _assemble(cherenkov, scintillation, deposits, result)


def _deposits_in_metres(deposits: Deposits) -> Deposits:
    return dataclasses.replace(
        deposits, start=deposits.start / CM_PER_M, end=deposits.end / CM_PER_M
    )


def _assemble(cherenkov: EmissionPhotons, scintillation: EmissionPhotons, deposits, result):
    parts = (cherenkov, scintillation)

    def join(name, dtype):
        return np.concatenate([getattr(p, name) for p in parts]).astype(dtype)

    process = np.concatenate(
        [
            np.full(cherenkov.time.size, Process.CHERENKOV, np.int8),
            np.full(scintillation.time.size, Process.SCINTILLATION, np.int8),
        ]
    )
    tracks = dataclasses.replace(result.tracks, length=result.tracks.length / CM_PER_M)
    return Photons(
        position=join("position", np.float32).reshape(-1, 3),
        direction=join("direction", np.float32).reshape(-1, 3),
        time=join("time", np.float32),
        wavelength=join("wavelength", np.float32),
        process=process,
        parent=join("parent", np.int32),
        deposits=deposits,
        budget=result.budget,
        tracks=tracks,
        steps=dataclasses.replace(result.steps, start=result.steps.start / CM_PER_M,
                                  length=result.steps.length / CM_PER_M),
    )
