"""Condensed-history transport of particles and all their secondaries (vectorised stacks).

All live charged particles advance one step per iteration, and all live photons make one
interaction, so numpy works on whole stacks; the loop ends when both stacks are empty.

The event's state (records, new particles, tracking cuts, annihilation and muon decay) is
``event_state.py``, the charged step ``charged_steps.py``, the photon interactions
``photon_interactions.py`` and the stacks ``stack.py``; this module joins them
(``_Event``) and runs the loop (``transport``). Internal units: cm, ns, MeV.
"""

from __future__ import annotations

import numpy as np

from .charged_steps import _ChargedSteps
from .event_state import TransportResult
from .materials import Material
from .particles import Species
from .photon_interactions import _PhotonInteractions
from .stack import Stack
from .tables import PhysicsTables


class _Event(_ChargedSteps, _PhotonInteractions):
    """One event under transport: its state (``_EventState``) with the charged steps and
    the photon interactions."""


def transport(
    primary_species,
    position_cm: np.ndarray,
    direction: np.ndarray,
    energy,
    time,
    material: Material,
    tables: PhysicsTables,
    settings,
    rng: np.random.Generator,
) -> list[TransportResult]:
    """Transport primaries to completion, each with its secondaries as one event:
    ``primary_species`` (n,) ``Species`` codes, ``position_cm`` (n, 3) cm, ``direction``
    (n, 3), kinetic ``energy`` (n,) MeV and ``time`` (n,) ns. All events advance together
    (one stack); returns their ``TransportResult``s in order, the same for the same
    primaries and ``rng`` state."""
    species = np.atleast_1d(np.asarray(primary_species, dtype=np.int64))
    position_cm = np.asarray(position_cm, dtype=np.float64).reshape(-1, 3)
    direction = np.asarray(direction, dtype=np.float64).reshape(-1, 3)
    energy = np.atleast_1d(np.asarray(energy, dtype=np.float64))
    time = np.atleast_1d(np.asarray(time, dtype=np.float64))
    event = _Event(material, tables, rng, settings.muon_decay, n_events=species.size)
    for k, code in enumerate(species):
        start = (position_cm[k : k + 1], direction[k : k + 1], energy[k : k + 1],
                 time[k : k + 1], np.array([-1]))
        if code == Species.GAMMA:
            event.spawn_photons(*start, event=k)
        else:
            event.spawn_charged(code, *start, event=k)
    charged_parts, photon_parts = event.drain_new()
    charged = Stack.join(charged_parts) if charged_parts else Stack.empty()
    photons = Stack.join(photon_parts) if photon_parts else Stack.empty()
    while charged.size or photons.size:
        survivors = event.step_charged(charged, settings) if charged.size else Stack.empty()
        if photons.size:
            event.interact_photons(photons)
        charged_parts, photon_parts = event.drain_new()
        charged = Stack.join([survivors, *charged_parts])
        photons = Stack.join(photon_parts) if photon_parts else Stack.empty()
    return event.result(energy)
