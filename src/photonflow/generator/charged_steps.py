"""The condensed-history step of charged particles (e-, e+, mu): ``_ChargedSteps``, the
part of one event's transport (``transport.py``) that advances all live charged
particles by one step. Internal units: cm, ns, MeV; cross sections 1/cm.

Charged step (class II mixed scheme, as in EGS/Geant4):

1. the continuous step is the smaller of ``step_fraction`` x residual range and
   ``max_step`` (at least ``min_step``); a particle whose residual range beyond its
   tracking cut is shorter stops in this step;
2. the distance to a discrete interaction (knock-on above the electron cut,
   bremsstrahlung above the photon cut) is drawn with the larger of the cross sections
   at the step's start and expected end; at the end point the interaction is accepted
   with probability sigma(T_end) / sigma_used (the "integral" method, exact for
   cross sections monotonic over the step);
3. the mean continuous loss follows from the restricted range table,
   T_end = T(R(T) - s); its fluctuation is a Gamma distribution with that mean and the
   Bohr variance (Gaussian limit for thick steps, skewed and positive for thin ones);
4. the direction changes at the end of the step by multiple scattering (:mod:`.scattering`);
5. secondaries: knock-ons take their direction from two-body kinematics and the
   primary's momentum is reduced accordingly; bremsstrahlung photons follow Tsai's
   angular distribution and the electron keeps its direction.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .bremsstrahlung import sample_emission_polar, sample_photon_energy
from .constants import CM_PER_M, ELECTRON_MASS, MUON_MASS, SPEED_OF_LIGHT
from .directions import rotate, unit
from .event_state import _EventState
from .knock_on import sample_electron_transfer, sample_heavy_transfer
from .particles import SPECIES_MASS, Species
from .scattering import highland_variance_increment, scatter
from .stack import Stack
from .stopping_power import maximum_transfer


class _ChargedSteps(_EventState):
    """One event's state with the condensed-history step of its charged particles."""

    def step_charged(self, stack: Stack, settings) -> Stack:
        """Advance every charged particle by one step; return the survivors."""
        rng, tables, material = self.rng, self.tables, self.material
        species, energy = stack.species, stack.energy
        stop = tables.stop_energy[species]
        mass = np.asarray(SPECIES_MASS)[species]
        residual = tables.range(species, energy)
        stop_range = tables.range(species, stop)
        step = np.clip(
            settings.step_fraction * residual,
            settings.min_step * CM_PER_M,
            settings.max_step * CM_PER_M,
        )
        stopping = residual - step <= stop_range
        step = np.where(stopping, residual - stop_range, step)

        expected_end = np.maximum(
            energy - tables.charged(tables.stopping_power, species, energy) * step, stop
        )
        sigma_start = self._discrete_cross_sections(species, energy)
        sigma_end = self._discrete_cross_sections(species, expected_end)
        sigma_used = np.maximum(sigma_start.sum(axis=0), sigma_end.sum(axis=0))
        with np.errstate(divide="ignore"):
            distance = -np.log(rng.random(energy.size)) / sigma_used
        discrete = distance < step
        step = np.where(discrete, distance, step)
        stopping &= ~discrete

        mean_loss = np.where(
            stopping,
            energy - stop,
            energy - tables.energy_at_range(species, np.maximum(residual - step, 1e-300)),
        )
        mean_loss = np.clip(mean_loss, 0.0, energy)
        variance = tables.charged(tables.loss_variance, species, energy) * step
        loss = np.where(stopping, mean_loss, _fluctuate(rng, mean_loss, variance))
        loss = np.minimum(loss, energy)
        after = energy - loss
        ended = stopping | (after < stop)

        middle = energy - 0.5 * loss
        gamma_mid = 1.0 + middle / mass
        beta_mid = np.sqrt(1.0 - 1.0 / gamma_mid**2)
        end_time = stack.time + step / (beta_mid * SPEED_OF_LIGHT)
        end_position = stack.position + step[:, None] * stack.direction
        self._record_step(stack, step, end_position, end_time, beta_mid, loss)

        momentum_mid = np.sqrt(middle * (middle + 2.0 * mass))
        variance_angle = highland_variance_increment(
            momentum_mid,
            beta_mid**2,
            stack.path,
            step,
            material.radiation_length / material.density,
        )
        direction = stack.direction.copy()
        alive = ~ended
        direction[alive] = scatter(rng, direction[alive], variance_angle[alive])

        moved = Stack(
            species, end_position, direction, after, end_time, stack.track, stack.path + step
        )
        moved = self._interact_charged(moved, discrete & alive, sigma_used)

        ended = ended | (moved.energy < stop)
        self.finish_charged(
            species[ended],
            moved.position[ended],
            moved.energy[ended],
            moved.time[ended],
            moved.track[ended],
        )
        return moved.select(~ended)

    def _interact_charged(
        self, moved: Stack, interacting: np.ndarray, sigma_used: np.ndarray
    ) -> Stack:
        """Apply the discrete interactions drawn for the particles ``interacting`` (a mask
        into ``moved``, the stack at the end of the step): each is accepted with probability
        sigma(T_end) / ``sigma_used`` (1/cm), as a knock-on or a bremsstrahlung in the ratio
        of their cross sections. Return the stack with the primaries' energies and
        directions updated."""
        if np.any(interacting):
            rng, species, after = self.rng, moved.species, moved.energy
            sigma_now = self._discrete_cross_sections(species[interacting], after[interacting])
            accept = rng.random(sigma_now.shape[1]) * sigma_used[interacting] < sigma_now.sum(
                axis=0
            )
            is_knock_on = rng.random(sigma_now.shape[1]) * sigma_now.sum(axis=0) < sigma_now[0]
            which = np.flatnonzero(interacting)
            moved = self._knock_on(moved, which[accept & is_knock_on])
            moved = self._bremsstrahlung(moved, which[accept & ~is_knock_on])
        return moved

    def _discrete_cross_sections(self, species, energy):
        """(2, N) knock-on and bremsstrahlung cross sections, 1/cm, zero below threshold."""
        tables = self.tables
        cut = tables.electron_cut
        mass = np.asarray(SPECIES_MASS)[species]
        largest_transfer = np.where(
            species == Species.ELECTRON,
            0.5 * energy,
            np.where(species == Species.POSITRON, energy, maximum_transfer(energy, mass)),
        )
        knock_on = np.where(
            largest_transfer > cut, tables.charged(tables.knock_on, species, energy), 0.0
        )
        brems = np.where(
            energy > tables.photon_cut, tables.charged(tables.bremsstrahlung, species, energy), 0.0
        )
        return np.stack([knock_on, brems])

    def _record_step(self, stack, step, end_position, end_time, beta, loss):
        for name, value in (
            ("start", stack.position),
            ("direction", stack.direction),
            ("length", step),
            ("start_time", stack.time),
            ("end_time", end_time),
            ("beta", beta),
            ("track", stack.track),
        ):
            self.steps[name].append(value)
        kb1, kb2 = self.material.birks
        with np.errstate(divide="ignore", invalid="ignore"):
            specific = np.where(step > 0, loss / (self.material.density * step), 0.0)
        visible = loss / (1.0 + kb1 * specific + kb2 * specific**2)
        self.deposit(stack.position, end_position, stack.time, end_time, loss, visible, stack.track)
        self.deposited += self.per_event(stack.track, loss)

    def _knock_on(self, stack: Stack, which: np.ndarray) -> Stack:
        """Knock-on electrons from the particles at indices ``which`` of ``stack``."""
        if which.size == 0:
            return stack
        rng, cut = self.rng, self.tables.electron_cut
        species, energy = stack.species[which], stack.energy[which]
        transfer = np.empty(which.size)
        for code in np.unique(species):
            mask = species == code
            if code in (Species.MUON_MINUS, Species.MUON_PLUS):
                transfer[mask] = sample_heavy_transfer(rng, energy[mask], MUON_MASS, cut)
            else:
                transfer[mask] = sample_electron_transfer(
                    rng, energy[mask], code == Species.POSITRON, cut
                )
        mass = np.asarray(SPECIES_MASS)[species]
        momentum = np.sqrt(energy * (energy + 2.0 * mass))
        electron_momentum = np.sqrt(transfer * (transfer + 2.0 * ELECTRON_MASS))
        cos_theta = np.clip(
            transfer * (energy + mass + ELECTRON_MASS) / (momentum * electron_momentum), -1.0, 1.0
        )
        phi = 2.0 * np.pi * rng.random(which.size)
        direction = stack.direction[which]
        electron_direction = rotate(direction, cos_theta, phi)
        remaining = momentum[:, None] * direction - electron_momentum[:, None] * electron_direction
        new_energy = stack.energy.copy()
        new_direction = stack.direction.copy()
        new_energy[which] = energy - transfer
        new_direction[which] = unit(remaining)
        self.spawn_charged(
            Species.ELECTRON,
            stack.position[which],
            electron_direction,
            transfer,
            stack.time[which],
            stack.track[which],
        )
        return dataclasses.replace(stack, energy=new_energy, direction=new_direction)

    def _bremsstrahlung(self, stack: Stack, which: np.ndarray) -> Stack:
        """Bremsstrahlung photons from the e-/e+ at indices ``which`` of ``stack``."""
        if which.size == 0:
            return stack
        rng = self.rng
        energy = stack.energy[which]
        photon_energy = sample_photon_energy(rng, self.material, energy, self.tables.photon_cut)
        cos_theta = sample_emission_polar(rng, energy + ELECTRON_MASS)
        direction = rotate(stack.direction[which], cos_theta, 2.0 * np.pi * rng.random(which.size))
        new_energy = stack.energy.copy()
        new_energy[which] = energy - photon_energy
        self.spawn_photons(
            stack.position[which], direction, photon_energy, stack.time[which], stack.track[which]
        )
        return dataclasses.replace(stack, energy=new_energy)


def _fluctuate(rng: np.random.Generator, mean: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """Gamma-distributed energy losses with the given mean and variance (MeV, MeV^2)."""
    positive = (mean > 0) & (variance > 0)
    shape = np.where(positive, mean * mean / np.where(positive, variance, 1.0), 1.0)
    scale = np.where(positive, variance / np.where(positive, mean, 1.0), 0.0)
    return np.where(positive, rng.gamma(shape, scale), mean)
