"""Knock-on (delta-ray) electrons above a kinetic-energy cut: cross sections and sampling.

Free-electron cross sections per unit energy transfer (PDG 'Passage of particles through
matter'; Moller and Bhabha as in ICRU 37 / Geant4's Moller-Bhabha model), with
C = 2 pi r_e^2 m_e c^2 n_el / beta^2:

- spin-1/2 heavy particle (muon): dsigma/dW = C / W^2 [1 - beta^2 W / W_max + W^2 / (2 E^2)];
- electron (Moller), eps = W/T in [cut/T, 1/2]:
  dsigma/deps = C / T [1/eps^2 + 1/(1-eps)^2 + ((gamma-1)/gamma)^2
                       - (2 gamma - 1)/gamma^2 / (eps (1-eps))];
- positron (Bhabha), eps in [cut/T, 1]:
  dsigma/deps = C beta^2 / T [1/(beta^2 eps^2) - B1/eps + B2 - B3 eps + B4 eps^2].

Macroscopic cross sections are returned per gram (cm^2/g); energies in MeV.
"""

from __future__ import annotations

import numpy as np

from .constants import BETHE_K, ELECTRON_MASS
from .materials import Material
from .rejection import sample_by_rejection
from .stopping_power import kinematics, maximum_transfer


def _bhabha_coefficients(gamma):
    y = 1.0 / (1.0 + gamma)
    y12 = 1.0 - 2.0 * y
    b1 = 2.0 - y * y
    b2 = y12 * (3.0 + y * y)
    b4 = y12**3
    b3 = b4 + y12 * y12
    return b1, b2, b3, b4


def heavy_knock_on_cross_section(material: Material, kinetic_energy, mass, cut: float):
    """Cross section per gram (cm^2/g) for knock-ons above ``cut`` from a muon-like particle."""
    gamma, beta_sq, _ = kinematics(kinetic_energy, mass)
    w_max = maximum_transfer(kinetic_energy, mass)
    total_energy = gamma * mass
    upper = np.maximum(w_max, cut)
    integral = (
        (1.0 / cut - 1.0 / upper)
        - beta_sq / upper * np.log(upper / cut)
        + (upper - cut) / (2.0 * total_energy * total_energy)
    )
    return 0.5 * BETHE_K * material.z_over_a / beta_sq * integral


def electron_knock_on_cross_section(material: Material, kinetic_energy, positron: bool, cut: float):
    """Moller (e-) or Bhabha (e+) cross section per gram (cm^2/g) for knock-ons above ``cut``."""
    energy = np.asarray(kinetic_energy, dtype=np.float64)
    gamma, beta_sq, _ = kinematics(energy, ELECTRON_MASS)
    x_max = 1.0 if positron else 0.5
    x_min = np.minimum(cut / energy, x_max)
    if positron:
        b1, b2, b3, b4 = _bhabha_coefficients(gamma)
        integral = (x_max - x_min) * (
            1.0 / (beta_sq * x_min * x_max)
            + b2
            - 0.5 * b3 * (x_min + x_max)
            + b4 * (x_min * x_min + x_min * x_max + x_max * x_max) / 3.0
        ) - b1 * np.log(x_max / x_min)
        integral = integral * beta_sq
    else:
        gg = (2.0 * gamma - 1.0) / (gamma * gamma)
        integral = (x_max - x_min) * (
            1.0 - gg + 1.0 / (x_min * x_max) + 1.0 / ((1.0 - x_min) * (1.0 - x_max))
        ) - gg * np.log(x_max * (1.0 - x_min) / (x_min * (1.0 - x_max)))
    return 0.5 * BETHE_K * material.z_over_a / (beta_sq * energy) * np.maximum(integral, 0.0)


def sample_heavy_transfer(rng, kinetic_energy: np.ndarray, mass: float, cut: float) -> np.ndarray:
    """Knock-on kinetic energies (MeV) in [cut, W_max] from muon-like particles."""
    gamma, beta_sq, _ = kinematics(kinetic_energy, mass)
    w_max = maximum_transfer(kinetic_energy, mass)
    half_inverse_e_sq = 0.5 / (gamma * mass) ** 2
    bound = 1.0 + w_max * w_max * half_inverse_e_sq

    def propose(indices):
        inverse = 1.0 / cut - rng.random(indices.size) * (1.0 / cut - 1.0 / w_max[indices])
        w = 1.0 / inverse
        value = 1.0 - beta_sq[indices] * w / w_max[indices] + w * w * half_inverse_e_sq[indices]
        return w, value / bound[indices]

    return sample_by_rejection(rng, kinetic_energy.size, propose)


def sample_electron_transfer(rng, kinetic_energy: np.ndarray, positron: bool, cut: float):
    """Knock-on kinetic energies (MeV) from electrons (Moller) or positrons (Bhabha) above ``cut``.

    Proposes eps from 1/eps^2 and accepts with the remaining factor of the cross section.
    """
    gamma, beta_sq, _ = kinematics(kinetic_energy, ELECTRON_MASS)
    x_min = cut / kinetic_energy
    x_max = 1.0 if positron else 0.5
    if positron:
        b1, b2, b3, b4 = _bhabha_coefficients(gamma)
    else:
        gg = (2.0 * gamma - 1.0) / (gamma * gamma)

    def propose(indices):
        low = x_min[indices]
        eps = 1.0 / (1.0 / low - rng.random(indices.size) * (1.0 / low - 1.0 / x_max))
        if positron:
            poly = eps * (
                b1[indices] - eps * (b2[indices] - eps * (b3[indices] - eps * b4[indices]))
            )
            acceptance = 1.0 - beta_sq[indices] * poly
        else:
            g = gg[indices]
            ratio = eps / (1.0 - eps)
            acceptance = (1.0 + ratio * ratio + (1.0 - g) * eps * eps - g * ratio) / 2.25
        return eps, acceptance

    return sample_by_rejection(rng, kinetic_energy.size, propose) * kinetic_energy
