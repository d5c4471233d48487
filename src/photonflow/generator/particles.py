"""Particle species known to the generator: codes, masses and charges."""

from __future__ import annotations

import dataclasses
import enum

from .constants import ELECTRON_MASS, MUON_MASS


class Species(enum.IntEnum):
    """Integer codes of the transported species (used in arrays and tables)."""

    ELECTRON = 0
    POSITRON = 1
    MUON_MINUS = 2
    MUON_PLUS = 3
    GAMMA = 4


@dataclasses.dataclass(frozen=True)
class ParticleData:
    """Name, code, rest mass (MeV) and charge (units of e) of a species."""

    name: str
    species: Species
    mass: float
    charge: int


PARTICLES: dict[str, ParticleData] = {
    "e-": ParticleData("e-", Species.ELECTRON, ELECTRON_MASS, -1),
    "e+": ParticleData("e+", Species.POSITRON, ELECTRON_MASS, +1),
    "mu-": ParticleData("mu-", Species.MUON_MINUS, MUON_MASS, -1),
    "mu+": ParticleData("mu+", Species.MUON_PLUS, MUON_MASS, +1),
    "gamma": ParticleData("gamma", Species.GAMMA, 0.0, 0),
}

CHARGED_SPECIES = (Species.ELECTRON, Species.POSITRON, Species.MUON_MINUS, Species.MUON_PLUS)
"""Charged species, in code order: index ``i`` of a charged-particle table is code ``i``."""

SPECIES_MASS = tuple(
    next(p.mass for p in PARTICLES.values() if p.species == s) for s in CHARGED_SPECIES
)
"""Rest mass (MeV) of each charged species, indexed by code."""
