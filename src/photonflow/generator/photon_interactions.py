"""Photon interactions: ``_PhotonInteractions``, the part of one event's transport
(``transport.py``) that moves every live photon to its next interaction and applies it.

Photons travel an exponential distance, then Compton-scatter (Klein-Nishina) or convert
(screened Bethe-Heitler); photons below the photon cut are absorbed on the spot
(``event_state.py``). Internal units: cm, ns, MeV; cross sections 1/cm.
"""

from __future__ import annotations

import numpy as np

from .bremsstrahlung import sample_emission_polar
from .compton import sample_energy_fraction
from .constants import ELECTRON_MASS, SPEED_OF_LIGHT
from .directions import rotate, unit
from .event_state import _EventState
from .pair_production import sample_positron_fraction
from .particles import Species
from .stack import Stack


class _PhotonInteractions(_EventState):
    """One event's state with the interactions of its photons."""

    def interact_photons(self, stack: Stack) -> None:
        """Move every photon to its next interaction and apply it; a Compton-scattered
        photon keeps its track id, a converted one ends."""
        rng, tables = self.rng, self.tables
        energy = stack.energy
        compton = tables.photon(tables.compton, energy)
        pair = tables.photon(tables.pair, energy)
        total = compton + pair
        distance = -np.log(rng.random(energy.size)) / total
        position = stack.position + distance[:, None] * stack.direction
        time = stack.time + distance / SPEED_OF_LIGHT
        converts = rng.random(energy.size) * total < pair

        scatters = ~converts
        if np.any(scatters):
            k = energy[scatters]
            fraction = sample_energy_fraction(rng, k)
            kappa = k / ELECTRON_MASS
            cos_theta = np.clip(1.0 - (1.0 - fraction) / (kappa * fraction), -1.0, 1.0)
            old_direction = stack.direction[scatters]
            direction = rotate(old_direction, cos_theta, 2.0 * np.pi * rng.random(k.size))
            scattered = fraction * k
            electron = k[:, None] * old_direction - scattered[:, None] * direction
            where, when, track = position[scatters], time[scatters], stack.track[scatters]
            self.spawn_charged(Species.ELECTRON, where, unit(electron), k - scattered, when, track)
            self._continue_photons(where, direction, scattered, when, track)

        if np.any(converts):
            k = energy[converts]
            self.rest_mass -= self.per_event(stack.track[converts], 2.0 * ELECTRON_MASS)
            positron_share = sample_positron_fraction(rng, self.material, k)
            totals = np.concatenate([positron_share * k, (1.0 - positron_share) * k])
            cos_theta = sample_emission_polar(rng, totals)
            phi = 2.0 * np.pi * rng.random(k.size)
            axis = np.concatenate([stack.direction[converts]] * 2)
            direction = rotate(axis, cos_theta, np.concatenate([phi, phi + np.pi]))
            species = np.concatenate(
                [np.full(k.size, int(Species.POSITRON)), np.full(k.size, int(Species.ELECTRON))]
            )
            where = np.concatenate([position[converts]] * 2)
            when = np.concatenate([time[converts]] * 2)
            parent = np.concatenate([stack.track[converts]] * 2)
            self.spawn_charged(species, where, direction, totals - ELECTRON_MASS, when, parent)
