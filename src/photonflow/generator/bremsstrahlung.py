"""Electron and positron bremsstrahlung: screened Bethe-Heitler cross section and sampling.

The differential cross section per atom (Tsai 1974, eq. 3.9, Born approximation with
Thomas-Fermi screening and the Coulomb correction f(Z)) is

    k dsigma/dk = alpha r_e^2 {(4/3 - 4/3 y + y^2) [Z^2 (phi1 - 4/3 ln Z - 4 f)
                                                    + Z (psi1 - 8/3 ln Z)]
                               + 2/3 (1 - y) [Z^2 (phi1 - phi2) + Z (psi1 - psi2)]},

y = k / E (E the total energy). In complete screening it reduces to the PDG form whose
integral defines X0. Positrons use the electron cross section. LPM and dielectric
suppression are negligible below 10 GeV in water and are not modelled.
"""

from __future__ import annotations

import numpy as np

from .constants import BREMS_PREFACTOR, ELECTRON_MASS
from .materials import Material
from .rejection import sample_by_rejection
from .screening import element_terms


def bremsstrahlung_weight(material: Material, total_energy, photon_energy):
    """k dsigma/dk per gram of ``material``, cm^2/g (the photon-energy weighted spectrum).

    Args:
        material: the medium.
        total_energy: electron total energy E, MeV (array, broadcast with photon_energy).
        photon_energy: photon energy k, MeV (0 < k < E - m_e).
    """
    total_energy = np.asarray(total_energy, dtype=np.float64)
    photon_energy = np.asarray(photon_energy, dtype=np.float64)
    y = photon_energy / total_energy
    final_energy = np.maximum(total_energy - photon_energy, ELECTRON_MASS)
    reduced = 100.0 * ELECTRON_MASS * photon_energy / (total_energy * final_energy)
    weight = np.zeros(np.broadcast(total_energy, photon_energy).shape)
    for element, atoms in zip(material.elements, material.atoms_per_gram(), strict=True):
        main, extra = element_terms(element.atomic_number, reduced)
        term = (4.0 / 3.0 - 4.0 / 3.0 * y + y * y) * main + 2.0 / 3.0 * (1.0 - y) * extra
        weight = weight + atoms * np.maximum(term, 0.0)
    return BREMS_PREFACTOR * weight


def bremsstrahlung_weight_bound(material: Material) -> float:
    """Upper bound of :func:`bremsstrahlung_weight` over E and k (its y -> 0 limit), cm^2/g."""
    return float(bremsstrahlung_weight(material, 1.0e12, 1.0e-6))


def sample_photon_energy(
    rng: np.random.Generator, material: Material, kinetic_energy: np.ndarray, cut: float
) -> np.ndarray:
    """Bremsstrahlung photon energies (MeV) above ``cut`` (MeV) for electrons of ``kinetic_energy``.

    Proposes from dk/k on [cut, T] and accepts with weight(k) / bound.
    """
    total_energy = kinetic_energy + ELECTRON_MASS
    log_span = np.log(kinetic_energy / cut)
    bound = bremsstrahlung_weight_bound(material)

    def propose(indices):
        k = cut * np.exp(log_span[indices] * rng.random(indices.size))
        return k, bremsstrahlung_weight(material, total_energy[indices], k) / bound

    return sample_by_rejection(rng, kinetic_energy.size, propose)


def sample_emission_polar(rng: np.random.Generator, total_energy: np.ndarray) -> np.ndarray:
    """Cosines of the emission angle of a bremsstrahlung photon or pair lepton.

    Tsai's angular distribution in the form used by Geant4's "modified Tsai" sampler:
    u = theta E / m_e is a mixture of Gamma(2) variates with scales 1.6 (weight 1/4) and
    1.6/3 (weight 3/4), truncated at u <= 2 E / m_e; cos theta = 1 - 2 u^2 / u_max^2.

    Args:
        total_energy: total energy of the emitting (or emitted) particle, MeV.
    """
    u_max = 2.0 * total_energy / ELECTRON_MASS

    def propose(indices):
        scale = np.where(rng.random(indices.size) < 0.25, 1.6, 1.6 / 3.0)
        u = -np.log(rng.random(indices.size) * rng.random(indices.size)) * scale
        return u, (u <= u_max[indices]).astype(np.float64)

    u = sample_by_rejection(rng, total_energy.size, propose)
    return 1.0 - 2.0 * u * u / (u_max * u_max)
