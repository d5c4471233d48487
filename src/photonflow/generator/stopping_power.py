"""Collision stopping powers: Bethe-Bloch for muons, Moller/Bhabha for electrons.

All functions take kinetic energies in MeV (arrays) and return mass stopping powers in
MeV cm^2/g. "Restricted" means energy transfers below ``cut`` (MeV) only; transfers
above the cut are produced as explicit knock-on electrons (:mod:`.knock_on`). Pass
``cut=inf`` for the total (unrestricted) collision stopping power.

Formulas: PDG Review of Particle Physics, "Passage of particles through matter" (Bethe
equation with W_max, density effect and restricted form; the spin-1/2 term W^2/(2E^2)
of the free-electron cross section integrated up to the cut), and for electrons and
positrons the Rohrlich-Carlson / Berger-Seltzer restricted forms (ICRU Report 37).
Shell, Barkas and Bloch corrections and the muon's radiative losses (below 0.6 % of
dE/dx up to 5 GeV in water) are not included.
"""

from __future__ import annotations

import math

import numpy as np

from .constants import BETHE_K, ELECTRON_MASS, EV_PER_MEV
from .materials import Material, density_effect


def kinematics(kinetic_energy, mass):
    """(gamma, beta^2, (beta gamma)^2) for ``kinetic_energy`` (MeV) and ``mass`` (MeV)."""
    gamma = 1.0 + np.asarray(kinetic_energy, dtype=np.float64) / mass
    beta_gamma_sq = gamma * gamma - 1.0
    return gamma, beta_gamma_sq / (gamma * gamma), beta_gamma_sq


def maximum_transfer(kinetic_energy, mass):
    """Largest kinetic energy (MeV) a heavy charged particle gives a free electron."""
    gamma, _, beta_gamma_sq = kinematics(kinetic_energy, mass)
    ratio = ELECTRON_MASS / mass
    return 2.0 * ELECTRON_MASS * beta_gamma_sq / (1.0 + 2.0 * gamma * ratio + ratio * ratio)


def heavy_stopping_power(material: Material, kinetic_energy, mass, cut=np.inf):
    """Restricted Bethe-Bloch stopping power of a singly charged spin-1/2 particle, MeV cm^2/g.

    Args:
        material: the medium.
        kinetic_energy: MeV.
        mass: rest mass, MeV (e.g. the muon's).
        cut: largest energy transfer included, MeV (inf: total collision loss).
    """
    gamma, beta_sq, beta_gamma_sq = kinematics(kinetic_energy, mass)
    w_max = maximum_transfer(kinetic_energy, mass)
    upper = np.minimum(cut, w_max)
    mean_excitation = material.mean_excitation / EV_PER_MEV
    total_energy = gamma * mass
    bracket = (
        0.5 * np.log(2.0 * ELECTRON_MASS * beta_gamma_sq * upper / mean_excitation**2)
        - 0.5 * beta_sq * (1.0 + upper / w_max)
        - 0.5 * density_effect(material, np.sqrt(beta_gamma_sq))
        + upper * upper / (8.0 * total_energy * total_energy)
    )
    return BETHE_K * material.z_over_a / beta_sq * bracket


def electron_stopping_power(material: Material, kinetic_energy, positron: bool, cut=np.inf):
    """Restricted collision stopping power of an electron (Moller) or positron (Bhabha).

    Args:
        material: the medium.
        kinetic_energy: MeV.
        positron: True for e+, False for e-.
        cut: largest energy transfer included, MeV (the knock-on production cut).

    Returns:
        MeV cm^2/g.
    """
    energy = np.asarray(kinetic_energy, dtype=np.float64)
    tau = energy / ELECTRON_MASS
    gamma, beta_sq, beta_gamma_sq = kinematics(energy, ELECTRON_MASS)
    excitation_sq = (material.mean_excitation / EV_PER_MEV / ELECTRON_MASS) ** 2
    largest = energy if positron else 0.5 * energy
    d = np.minimum(cut, largest) / ELECTRON_MASS
    common = np.log(2.0 * (tau + 2.0) / excitation_sq)
    if positron:
        y = 1.0 / (1.0 + gamma)
        d2 = 0.5 * d * d
        d3 = d2 * d / 1.5
        d4 = d3 * d * 0.75
        bracket = (
            common
            + np.log(tau * d)
            - beta_sq
            / tau
            * (tau + 2.0 * d - y * (3.0 * d2 + y * (d - d3 + y * (d2 - tau * d3 + d4))))
        )
    else:
        bracket = (
            common
            - 1.0
            - beta_sq
            + np.log((tau - d) * d)
            + tau / (tau - d)
            + (0.5 * d * d + (2.0 * tau + 1.0) * np.log1p(-d / tau)) / (gamma * gamma)
        )
    bracket = bracket - density_effect(material, np.sqrt(beta_gamma_sq))
    return 0.5 * BETHE_K * material.z_over_a / beta_sq * np.maximum(bracket, 0.0)


def bohr_variance(material: Material, kinetic_energy, mass, upper):
    """Energy-loss variance per unit mass thickness, MeV^2 cm^2/g (Bohr, transfers <= upper).

    sigma^2 = (K/2) <Z/A> upper (1 - beta^2/2) / beta^2 for a singly charged particle.
    """
    _, beta_sq, _ = kinematics(kinetic_energy, mass)
    return 0.5 * BETHE_K * material.z_over_a * upper * (1.0 - 0.5 * beta_sq) / beta_sq


def critical_energy(material: Material, positron: bool = False) -> float:
    """Electron (or positron) critical energy E_c in Rossi's definition, MeV.

    E_c is the kinetic energy at which the collision loss per radiation length equals the
    particle's energy: S_col(E_c) X0 = E_c (PDG, 'Passage of particles through matter').
    Solved by bisection between 1 MeV and 10 GeV.
    """
    low, high = 1.0, 1.0e4

    def excess(energy: float) -> float:
        loss = float(electron_stopping_power(material, energy, positron))
        return loss * material.radiation_length - energy

    for _ in range(100):
        middle = math.sqrt(low * high)
        if excess(middle) > 0:
            low = middle
        else:
            high = middle
    return math.sqrt(low * high)
