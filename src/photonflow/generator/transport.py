"""Condensed-history transport of a particle and all its secondaries (vectorised stacks).

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
    primary_species: Species,
    position_cm: np.ndarray,
    direction: np.ndarray,
    energy: float,
    time: float,
    material: Material,
    tables: PhysicsTables,
    settings,
    rng: np.random.Generator,
) -> TransportResult:
    """Transport one primary (kinetic ``energy`` MeV, position cm, time ns) to completion."""
    event = _Event(material, tables, rng, settings.muon_decay)
    start = (
        np.asarray([position_cm], dtype=np.float64),
        np.asarray([direction], dtype=np.float64),
        np.array([energy]),
        np.array([time]),
        np.array([-1]),
    )
    if primary_species == Species.GAMMA:
        event.spawn_photons(*start)
    else:
        event.spawn_charged(primary_species, *start)
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
