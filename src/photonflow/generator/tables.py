"""Physics tables on a logarithmic kinetic-energy grid, built once per material and cuts.

For each charged species (code order of :data:`.particles.CHARGED_SPECIES`) the tables
hold, per cm of the medium: the restricted stopping power (collision below the knock-on
cut plus, for e+-, radiative below the photon cut), the corresponding CSDA range, the
knock-on and bremsstrahlung macroscopic cross sections, the Bohr energy-loss variance and
the Birks-quenched energy of a particle stopping from a given energy. For photons: the
Compton and pair-production macroscopic cross sections. Lookups interpolate linearly in
ln(T) (ranges log-log, so that range and its inverse are exact inverses).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from .bremsstrahlung import bremsstrahlung_weight
from .compton import compton_cross_section
from .constants import ELECTRON_MASS
from .knock_on import electron_knock_on_cross_section, heavy_knock_on_cross_section
from .materials import Material
from .pair_production import pair_weight
from .particles import CHARGED_SPECIES, SPECIES_MASS, Species
from .stopping_power import (
    bohr_variance,
    electron_stopping_power,
    heavy_stopping_power,
    maximum_transfer,
)

GRID_LOW = 1.0e-3  # MeV
GRID_HIGH = 2.0e4  # MeV
POINTS_PER_DECADE = 64
VALIDITY_FLOOR = {
    Species.ELECTRON: 1.0e-3,
    Species.POSITRON: 1.0e-3,
    Species.MUON_MINUS: 1.0,
    Species.MUON_PLUS: 1.0,
}
"""Kinetic energy (MeV) below which a species' stopping power is held constant
(the Bethe formula fails for muons below ~1 MeV; the effect on ranges is < 0.1 mm)."""

_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(48)


def _gauss(low, high):
    """Nodes (..., 48) and weights mapping Gauss-Legendre onto [low, high] (broadcast)."""
    low, high = np.asarray(low)[..., None], np.asarray(high)[..., None]
    half = 0.5 * (high - low)
    return low + half * (_GAUSS_NODES + 1.0), half * _GAUSS_WEIGHTS


@dataclasses.dataclass(frozen=True)
class PhysicsTables:
    """Tabulated transport quantities (see module docstring). Energies MeV, lengths cm.

    Arrays of charged quantities have shape (4, grid); photon quantities (grid,).
    """

    log_energy: np.ndarray
    stopping_power: np.ndarray  # restricted, MeV/cm
    log_range: np.ndarray  # ln(range / cm)
    knock_on: np.ndarray  # 1/cm
    bremsstrahlung: np.ndarray  # 1/cm
    loss_variance: np.ndarray  # MeV^2/cm
    quenched_energy: np.ndarray  # MeV, Birks-quenched energy deposited while stopping
    compton: np.ndarray  # 1/cm
    pair: np.ndarray  # 1/cm
    stop_energy: np.ndarray  # per charged species, MeV
    electron_cut: float
    photon_cut: float

    def _locate(self, energy):
        position = (np.log(energy) - self.log_energy[0]) / (self.log_energy[1] - self.log_energy[0])
        index = np.minimum(np.maximum(position.astype(np.int64), 0), self.log_energy.size - 2)
        return index, np.minimum(np.maximum(position - index, 0.0), 1.0)

    def charged(self, table: np.ndarray, species: np.ndarray, energy: np.ndarray) -> np.ndarray:
        """Interpolate a (4, grid) ``table`` at per-particle ``species`` and ``energy`` (MeV)."""
        index, fraction = self._locate(energy)
        return table[species, index] * (1.0 - fraction) + table[species, index + 1] * fraction

    def photon(self, table: np.ndarray, energy: np.ndarray) -> np.ndarray:
        """Interpolate a (grid,) photon ``table`` at ``energy`` (MeV)."""
        index, fraction = self._locate(energy)
        return table[index] * (1.0 - fraction) + table[index + 1] * fraction

    def range(self, species: np.ndarray, energy: np.ndarray) -> np.ndarray:
        """Restricted CSDA range, cm."""
        return np.exp(self.charged(self.log_range, species, energy))

    def energy_at_range(self, species: np.ndarray, distance: np.ndarray) -> np.ndarray:
        """Kinetic energy (MeV) whose restricted CSDA range is ``distance`` (cm)."""
        result = np.empty(distance.shape)
        log_distance = np.log(np.maximum(distance, 1e-300))
        for code in np.unique(species):
            mask = species == code
            result[mask] = np.exp(
                np.interp(log_distance[mask], self.log_range[code], self.log_energy)
            )
        return result


def _charged_columns(material: Material, species: Species, energy, electron_cut, photon_cut):
    """Restricted stopping power (MeV cm^2/g), knock-on and brems cross sections (cm^2/g),
    Bohr variance (MeV^2 cm^2/g) and total collision stopping power (MeV cm^2/g)."""
    mass = SPECIES_MASS[species]
    evaluated = np.maximum(energy, VALIDITY_FLOOR[species])
    if species in (Species.ELECTRON, Species.POSITRON):
        positron = species == Species.POSITRON
        collision = electron_stopping_power(material, evaluated, positron, electron_cut)
        total_collision = electron_stopping_power(material, evaluated, positron)
        largest = evaluated if positron else 0.5 * evaluated
        knock_on = np.where(
            largest > electron_cut,
            electron_knock_on_cross_section(
                material, np.maximum(energy, electron_cut), positron, electron_cut
            ),
            0.0,
        )
        total_energy = evaluated + ELECTRON_MASS
        soft_top = np.minimum(photon_cut, evaluated)
        nodes, weights = _gauss(0.0, soft_top)
        radiative = np.sum(
            bremsstrahlung_weight(material, total_energy[:, None], nodes) * weights, axis=1
        )
        log_nodes, log_weights = _gauss(
            math.log(photon_cut), np.log(np.maximum(evaluated, photon_cut))
        )
        hard = np.sum(
            bremsstrahlung_weight(material, total_energy[:, None], np.exp(log_nodes)) * log_weights,
            axis=1,
        )
        bremsstrahlung = np.where(evaluated > photon_cut, hard, 0.0)
        upper = np.minimum(electron_cut, largest)
        restricted = collision + radiative
    else:
        restricted = heavy_stopping_power(material, evaluated, mass, electron_cut)
        total_collision = heavy_stopping_power(material, evaluated, mass)
        w_max = maximum_transfer(evaluated, mass)
        knock_on = np.where(
            w_max > electron_cut,
            heavy_knock_on_cross_section(material, evaluated, mass, electron_cut),
            0.0,
        )
        bremsstrahlung = np.zeros_like(energy)
        upper = np.minimum(electron_cut, w_max)
    variance = bohr_variance(material, evaluated, mass, upper)
    return restricted, knock_on, bremsstrahlung, variance, total_collision


def _cumulative_log_integral(energy, integrand):
    """Integral of ``integrand`` dT from 0 to each grid energy (trapezoid in ln T)."""
    values = integrand * energy
    steps = np.diff(np.log(energy))
    inner = np.cumsum(0.5 * steps * (values[1:] + values[:-1]))
    return np.concatenate([[0.0], inner]) + integrand[0] * energy[0]


@functools.lru_cache(maxsize=16)
def build_tables(
    material: Material, electron_cut: float, photon_cut: float, muon_cut: float
) -> PhysicsTables:
    """Tables for ``material`` with knock-on/tracking cut ``electron_cut`` (MeV), photon
    cut ``photon_cut`` (MeV) and muon tracking cut ``muon_cut`` (MeV). Cached."""
    decades = math.log10(GRID_HIGH / GRID_LOW)
    energy = np.logspace(
        math.log10(GRID_LOW), math.log10(GRID_HIGH), int(round(decades * POINTS_PER_DECADE)) + 1
    )
    density = material.density
    kb1, kb2 = material.birks
    rows = [
        _charged_columns(material, s, energy, electron_cut, photon_cut) for s in CHARGED_SPECIES
    ]
    restricted, knock_on, brems, variance, total_collision = (
        np.stack(c) for c in zip(*rows, strict=True)
    )
    ranges = np.stack([_cumulative_log_integral(energy, 1.0 / (density * s)) for s in restricted])
    quench = 1.0 / (1.0 + kb1 * total_collision + kb2 * total_collision**2)
    quenched = np.stack([_cumulative_log_integral(energy, q) for q in quench])
    compton = compton_cross_section(material, energy) * density
    above = energy > 2.0 * ELECTRON_MASS * 1.0001
    pair = np.zeros_like(energy)
    low = ELECTRON_MASS / energy[above]
    nodes, weights = _gauss(low, 1.0 - low)
    pair[above] = np.sum(pair_weight(material, energy[above][:, None], nodes) * weights, axis=1)
    # The Born cross section with fitted screening functions vanishes just above threshold
    # (1.7 MeV in water); zero the first non-zero node too, so that interpolation never
    # selects conversion at an energy where the differential cross section is zero.
    pair[np.argmax(pair > 0)] = 0.0
    stop = np.array([electron_cut, electron_cut, muon_cut, muon_cut])
    return PhysicsTables(
        log_energy=np.log(energy),
        stopping_power=restricted * density,
        log_range=np.log(ranges),
        knock_on=knock_on * density,
        bremsstrahlung=brems * density,
        loss_variance=variance * density,
        quenched_energy=quenched,
        compton=compton,
        pair=pair * density,
        stop_energy=stop,
        electron_cut=electron_cut,
        photon_cut=photon_cut,
    )
