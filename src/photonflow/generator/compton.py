"""Compton scattering on free electrons: Klein-Nishina cross section and sampling.

Atomic binding (Doppler broadening, incoherent scattering function) is neglected; it
matters only well below the default 0.1 MeV photon cut in water.
"""

from __future__ import annotations

import numpy as np

from .constants import COMPTON_PREFACTOR, ELECTRON_MASS
from .materials import Material
from .rejection import sample_by_rejection


def compton_cross_section(material: Material, photon_energy):
    """Klein-Nishina cross section per gram of ``material``, cm^2/g, at ``photon_energy`` (MeV)."""
    kappa = np.asarray(photon_energy, dtype=np.float64) / ELECTRON_MASS
    one_2k = 1.0 + 2.0 * kappa
    log_term = np.log(one_2k)
    per_electron = (
        2.0
        * COMPTON_PREFACTOR
        * (
            (1.0 + kappa) / kappa**2 * (2.0 * (1.0 + kappa) / one_2k - log_term / kappa)
            + log_term / (2.0 * kappa)
            - (1.0 + 3.0 * kappa) / one_2k**2
        )
    )
    return material.electrons_per_gram() * per_electron


def sample_energy_fraction(rng: np.random.Generator, photon_energy: np.ndarray) -> np.ndarray:
    """Scattered-photon energy fractions eps = k'/k for photons of ``photon_energy`` (MeV).

    Butcher and Messel (1960) method: eps is drawn from the mixture of 1/eps and eps on
    [1/(1 + 2 kappa), 1] and accepted with 1 - eps sin^2(theta) / (1 + eps^2).
    """
    kappa = photon_energy / ELECTRON_MASS
    lowest = 1.0 / (1.0 + 2.0 * kappa)
    weight_inverse = -np.log(lowest)
    weight_linear = 0.5 * (1.0 - lowest * lowest)

    def propose(indices):
        low, w1, w2 = lowest[indices], weight_inverse[indices], weight_linear[indices]
        use_inverse = rng.random(indices.size) * (w1 + w2) < w1
        u = rng.random(indices.size)
        eps = np.where(use_inverse, low**u, np.sqrt(low * low + (1.0 - low * low) * u))
        t = (1.0 - eps) / (kappa[indices] * eps)
        sin_sq = t * (2.0 - t)
        return eps, 1.0 - eps * sin_sq / (1.0 + eps * eps)

    return sample_by_rejection(rng, photon_energy.size, propose)
