"""Thomas-Fermi screening functions and the Coulomb correction for Bethe-Heitler processes.

Tsai, Rev. Mod. Phys. 46 (1974) 815, writes the screened Bethe-Heitler bremsstrahlung and
pair-production cross sections with screening functions phi1, phi2 (nuclear field) and
psi1, psi2 (atomic-electron field) of the screening variables gamma = 100 m_e k /
(E E' Z^(1/3)) and epsilon = 100 m_e k / (E E' Z^(2/3)). The fits used here are the
Butcher-Messel-style approximations of the Thomas-Fermi functions as used in EGS and
Geant4; at gamma = epsilon = 0 (complete screening) they give phi1 = 20.863,
psi1 = 28.340 and phi1 - phi2 = psi1 - psi2 = 2/3, i.e. Tsai's radiation logarithms
ln(184.15 Z^-1/3) and ln(1194 Z^-2/3) that define X0.
"""

from __future__ import annotations

import math

import numpy as np

from .constants import FINE_STRUCTURE


def screening_functions(gamma, epsilon):
    """(phi1, phi1 - phi2, psi1, psi1 - psi2) at screening variables ``gamma``, ``epsilon``."""
    gamma_sq, epsilon_sq = gamma * gamma, epsilon * epsilon
    phi1 = (
        16.863
        - 2.0 * np.log1p(0.311877 * gamma_sq)
        + 2.4 * np.exp(-0.9 * gamma)
        + 1.6 * np.exp(-1.5 * gamma)
    )
    phi_difference = 2.0 / (3.0 * (1.0 + 6.5 * gamma + 6.0 * gamma_sq))
    psi1 = (
        24.34
        - 2.0 * np.log1p(13.111641 * epsilon_sq)
        + 2.8 * np.exp(-8.0 * epsilon)
        + 1.2 * np.exp(-29.2 * epsilon)
    )
    psi_difference = 2.0 / (3.0 * (1.0 + 40.0 * epsilon + 400.0 * epsilon_sq))
    return phi1, phi_difference, psi1, psi_difference


def coulomb_correction(atomic_number: int) -> float:
    """Davies-Bethe-Maximon Coulomb correction f(Z) (PDG, 'Passage of particles through matter')."""
    a_sq = (FINE_STRUCTURE * atomic_number) ** 2
    return a_sq * (
        1.0 / (1.0 + a_sq) + 0.20206 - 0.0369 * a_sq + 0.0083 * a_sq**2 - 0.002 * a_sq**3
    )


def element_terms(atomic_number: int, reduced):
    """The screened Bethe-Heitler terms of one element shared by bremsstrahlung and pair
    production, at the reduced momentum transfer ``reduced`` (100 m_e k / (E E') or
    100 m_e / (k x (1 - x))): (Z^2 (phi1 - 4/3 ln Z - 4 f_c) + Z (psi1 - 8/3 ln Z),
    Z^2 (phi1 - phi2) + Z (psi1 - psi2))."""
    z = atomic_number
    ln_z = math.log(z)
    phi1, phi_diff, psi1, psi_diff = screening_functions(
        reduced / z ** (1.0 / 3.0), reduced / z ** (2.0 / 3.0)
    )
    first = z * z * (phi1 - 4.0 / 3.0 * ln_z - 4.0 * coulomb_correction(z)) + z * (
        psi1 - 8.0 / 3.0 * ln_z
    )
    return first, z * z * phi_diff + z * psi_diff
