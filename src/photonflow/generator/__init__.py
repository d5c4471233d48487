"""Stochastic particle-level light generator (pure numpy): muons, electrons, positrons and
photons in water, LAB scintillator and water-based scintillator, from the Cherenkov
threshold to 5 GeV, with condensed-history transport and Cherenkov/scintillation emission.

Units: positions m, times ns, energies MeV (kinetic), wavelengths nm. See
``docs/generator.md`` for the physics models, the energy accounting and the validation.
"""

from .generate import Photons, Process, generate, generate_together
from .materials import LAB, WATER, Material, refractive_index, water_based_scintillator
from .records import Deposits, EnergyBudget, Steps, Tracks
from .settings import GeneratorSettings
from .track import Track, stack_tracks

__all__ = [
    "LAB",
    "WATER",
    "Deposits",
    "EnergyBudget",
    "GeneratorSettings",
    "Material",
    "Photons",
    "Process",
    "Steps",
    "Track",
    "Tracks",
    "generate",
    "generate_together",
    "refractive_index",
    "stack_tracks",
    "water_based_scintillator",
]
