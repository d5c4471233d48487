"""Photon conversion into e+ e- pairs: screened Bethe-Heitler cross section and sampling.

Per atom (Tsai 1974, Born approximation, Thomas-Fermi screening, Coulomb correction),
with x = E+/k the positron's share of the photon energy,

    dsigma/dx = alpha r_e^2 {[x^2 + (1-x)^2] [Z^2 (phi1 - 4/3 ln Z - 4 f) + Z (psi1 - 8/3 ln Z)]
                             + 2/3 x (1-x) [Z^2 (phi2 - 4/3 ln Z - 4 f) + Z (psi2 - 8/3 ln Z)]},

screening variables gamma = 100 m_e / (k x (1-x) Z^(1/3)), epsilon likewise with Z^(2/3).
Complete screening gives the PDG form (A / X0 N_A) [1 - 4/3 x (1 - x)], i.e. sigma = 7/9
/ X0 per g/cm^2 at high energy. Near threshold the Born approximation is only
approximate (pair production there is a few % of the photon cross section in water).
"""

from __future__ import annotations

import numpy as np

from .constants import BREMS_PREFACTOR, ELECTRON_MASS
from .materials import Material
from .rejection import sample_by_rejection
from .screening import element_terms


def pair_weight(material: Material, photon_energy, fraction):
    """dsigma/dx per gram of ``material``, cm^2/g, for photon energy (MeV) and fraction x."""
    photon_energy = np.asarray(photon_energy, dtype=np.float64)
    fraction = np.asarray(fraction, dtype=np.float64)
    product = fraction * (1.0 - fraction)
    reduced = 100.0 * ELECTRON_MASS / (photon_energy * np.maximum(product, 1e-300))
    weight = np.zeros(np.broadcast(photon_energy, fraction).shape)
    for element, atoms in zip(material.elements, material.atoms_per_gram(), strict=True):
        first, difference = element_terms(element.atomic_number, reduced)
        second = first - difference
        term = (1.0 - 2.0 * product) * first + 2.0 / 3.0 * product * second
        weight = weight + atoms * np.maximum(term, 0.0)
    return BREMS_PREFACTOR * weight


def pair_weight_bound(material: Material) -> float:
    """Upper bound of :func:`pair_weight`: its complete-screening value at x -> 0, cm^2/g."""
    return float(pair_weight(material, 1.0e30, 1.0e-12))


def sample_positron_fraction(
    rng: np.random.Generator, material: Material, photon_energy: np.ndarray
) -> np.ndarray:
    """Positron total-energy fractions x = E+/k for photons of ``photon_energy`` (MeV, > 2 m_e).

    Proposes x uniformly on [m/k, 1 - m/k] and accepts with dsigma/dx over its
    complete-screening value at x = 0, an upper bound.
    """
    lowest = ELECTRON_MASS / photon_energy
    bound = pair_weight_bound(material)

    def propose(indices):
        low = lowest[indices]
        x = low + (1.0 - 2.0 * low) * rng.random(indices.size)
        return x, pair_weight(material, photon_energy[indices], x) / bound

    return sample_by_rejection(rng, photon_energy.size, propose)
