"""Muon decay at rest: Michel electron energy spectrum (tree level, massless electron)."""

from __future__ import annotations

import numpy as np

from .constants import ELECTRON_MASS, MUON_MASS
from .rejection import sample_by_rejection

MICHEL_ENDPOINT = (MUON_MASS**2 + ELECTRON_MASS**2) / (2.0 * MUON_MASS)
"""Largest Michel electron total energy, MeV (52.83 MeV)."""


def sample_michel_energy(rng: np.random.Generator, count: int) -> np.ndarray:
    """Total energies (MeV) of ``count`` decay electrons: x = E/E_max with density
    6 x^2 - 4 x^3 on [0, 1] (Michel spectrum, rho = 3/4, radiative corrections and
    polarisation neglected), at least the electron mass."""

    def propose(indices):
        x = rng.random(indices.size)
        return x, x * x * (3.0 - 2.0 * x)

    x = sample_by_rejection(rng, count, propose)
    return np.maximum(x * MICHEL_ENDPOINT, ELECTRON_MASS)
