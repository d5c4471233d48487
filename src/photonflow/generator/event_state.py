"""The state of the events under transport (``transport.py``): ``_EventState`` holds
their records (steps, deposits, tracks, energy budgets) and the particles waiting to be
transported, and creates and ends particles; ``TransportResult`` is what it hands back
for each event. Several independent events share the stacks (every track knows its
event), so that numpy's per-call cost is paid once per step for all of them.

A particle below its tracking cut deposits its residual kinetic energy on the spot;
positrons then annihilate at rest into two back-to-back 0.511 MeV photons; muons decay
into a Michel electron if ``muon_decay`` is set; photons below the photon cut are absorbed
on the spot. Positrons do not annihilate in flight. Internal units: cm, ns, MeV.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .constants import ELECTRON_MASS, MUON_LIFETIME, MUON_MASS
from .decay import sample_michel_energy
from .directions import isotropic
from .materials import Material
from .particles import Species
from .records import Deposits, EnergyBudget, Steps, Tracks, concatenate_rows
from .stack import Stack
from .tables import PhysicsTables


@dataclasses.dataclass(frozen=True)
class TransportResult:
    """Everything transport produces for one event (internal units: cm, ns, MeV)."""

    steps: Steps
    deposits: Deposits
    tracks: Tracks
    budget: EnergyBudget


class _EventState:
    """Mutable accumulator of the records of ``n_events`` events while they are
    transported; the charged steps (``charged_steps.py``) and the photon interactions
    (``photon_interactions.py``) are its subclasses' methods, joined in
    ``transport._Event``. Track ids are global while transporting (``event_of`` maps
    them to events) and per event in the results."""

    def __init__(
        self, material: Material, tables: PhysicsTables, rng: np.random.Generator, muon_decay: bool,
        n_events: int = 1,
    ):
        self.material, self.tables, self.rng, self.muon_decay = material, tables, rng, muon_decay
        self.n_events = n_events
        self._event_of = np.empty(64, dtype=np.int64)
        self.steps: dict[str, list[np.ndarray]] = {f.name: [] for f in dataclasses.fields(Steps)}
        self.deposits: dict[str, list[np.ndarray]] = {
            f.name: [] for f in dataclasses.fields(Deposits)
        }
        self.track_species: list[np.ndarray] = []
        self.track_parent: list[np.ndarray] = []
        self.track_energy: list[np.ndarray] = []
        self.next_track = 0
        self.deposited, self.below_cut, self.escaping, self.rest_mass = (
            np.zeros(n_events) for _ in range(4))
        self.new_charged: list[Stack] = []
        self.new_photons: list[Stack] = []

    # ---- bookkeeping ------------------------------------------------------------------

    @property
    def event_of(self) -> np.ndarray:
        """(tracks,) the event of every track id registered so far."""
        return self._event_of[: self.next_track]

    def per_event(self, track, amount=1.0) -> np.ndarray:
        """(n_events,) sums of ``amount`` (a scalar or one per entry of ``track``, the
        track ids) by event."""
        weights = np.broadcast_to(np.asarray(amount, np.float64), np.shape(track))
        return np.bincount(self.event_of[track], weights, minlength=self.n_events)

    def register(self, species, energy, parent, event=None) -> np.ndarray:
        """Give new tracks consecutive ids and record them, in the event of their
        ``parent`` (a track id), or ``event`` for primaries (``parent`` -1)."""
        count = energy.size
        ids = np.arange(self.next_track, self.next_track + count, dtype=np.int64)
        events = self.event_of[parent] if event is None else np.full(count, event, np.int64)
        if self.next_track + count > self._event_of.size:
            grown = np.empty(2 * (self.next_track + count), dtype=np.int64)
            grown[: self.next_track] = self.event_of
            self._event_of = grown
        self._event_of[self.next_track : self.next_track + count] = events
        self.next_track += count
        self.track_species.append(np.asarray(species, dtype=np.int64))
        self.track_parent.append(np.asarray(parent, dtype=np.int64))
        self.track_energy.append(np.asarray(energy, dtype=np.float64))
        return ids

    def deposit(self, start, end, start_time, end_time, energy, visible, track):
        for name, value in (
            ("start", start),
            ("end", end),
            ("start_time", start_time),
            ("end_time", end_time),
            ("energy", energy),
            ("visible_energy", visible),
            ("track", track),
        ):
            self.deposits[name].append(value)

    def point_deposit(self, position, time, energy, species, track):
        """Residual kinetic energy deposited on the spot (counted as below-cut)."""
        if energy.size == 0:
            return
        code = np.where(species == Species.GAMMA, Species.ELECTRON, species)
        visible = self.tables.charged(self.tables.quenched_energy, code, np.maximum(energy, 1e-9))
        visible = np.where(energy > 0, np.minimum(visible, energy), 0.0)
        self.deposit(position, position, time, time, energy, visible, track)
        self.below_cut += self.per_event(track, energy)

    # ---- creating particles -------------------------------------------------------------

    def spawn_charged(self, species, position, direction, energy, time, parent, event=None):
        """New e-/e+/mu: tracked if above their cut, else deposited (positrons annihilate);
        ``event`` for primaries (``register``)."""
        species = np.asarray(species, dtype=np.int64) * np.ones(energy.size, dtype=np.int64)
        ids = self.register(species, energy, parent, event)
        tracked = energy >= self.tables.stop_energy[species]
        if np.any(tracked):
            self.new_charged.append(
                Stack(
                    species[tracked],
                    position[tracked],
                    direction[tracked],
                    energy[tracked],
                    time[tracked],
                    ids[tracked],
                    np.zeros(int(tracked.sum())),
                )
            )
        self.finish_charged(
            species[~tracked], position[~tracked], energy[~tracked], time[~tracked], ids[~tracked]
        )

    def spawn_photons(self, position, direction, energy, time, parent, event=None):
        """New photons: tracked above the photon cut, else absorbed on the spot; ``event``
        for primaries (``register``)."""
        ids = self.register(np.full(energy.size, Species.GAMMA), energy, parent, event)
        self._continue_photons(position, direction, energy, time, ids)

    def finish_charged(self, species, position, energy, time, track):
        """End charged tracks: residual energy deposited, e+ annihilate, muons may decay."""
        self.point_deposit(position, time, energy, species, track)
        positron = species == Species.POSITRON
        if np.any(positron):
            count = int(positron.sum())
            self.rest_mass += self.per_event(track[positron], 2.0 * ELECTRON_MASS)
            axis = isotropic(self.rng, count)
            where, when = position[positron], time[positron]
            self.spawn_photons(
                np.concatenate([where, where]),
                np.concatenate([axis, -axis]),
                np.full(2 * count, ELECTRON_MASS),
                np.concatenate([when, when]),
                np.concatenate([track[positron], track[positron]]),
            )
        muon = (species == Species.MUON_MINUS) | (species == Species.MUON_PLUS)
        if self.muon_decay and np.any(muon):
            count = int(muon.sum())
            total = sample_michel_energy(self.rng, count)
            self.rest_mass += self.per_event(track[muon], MUON_MASS - ELECTRON_MASS)
            self.escaping += self.per_event(track[muon], MUON_MASS - total)
            lepton = np.where(
                species[muon] == Species.MUON_MINUS, Species.ELECTRON, Species.POSITRON
            )
            decay_time = time[muon] + self.rng.exponential(MUON_LIFETIME, count)
            self.spawn_charged(
                lepton,
                position[muon],
                isotropic(self.rng, count),
                total - ELECTRON_MASS,
                decay_time,
                track[muon],
            )

    def _continue_photons(self, position, direction, energy, time, track):
        """The scattered photon keeps its track id; below the cut it is absorbed."""
        tracked = energy >= self.tables.photon_cut
        if np.any(tracked):
            self.new_photons.append(
                Stack(
                    np.full(int(tracked.sum()), int(Species.GAMMA)),
                    position[tracked],
                    direction[tracked],
                    energy[tracked],
                    time[tracked],
                    track[tracked],
                    np.zeros(int(tracked.sum())),
                )
            )
        self.point_deposit(
            position[~tracked],
            time[~tracked],
            energy[~tracked],
            np.full(int((~tracked).sum()), int(Species.GAMMA)),
            track[~tracked],
        )

    def drain_new(self) -> tuple[list[Stack], list[Stack]]:
        charged, photons = self.new_charged, self.new_photons
        self.new_charged, self.new_photons = [], []
        return charged, photons

    def result(self, initial) -> list[TransportResult]:
        """Each event's ``TransportResult`` (``initial``: (n_events,) the primaries'
        kinetic energies, MeV), its track ids counted from 0 (the primary) in the order
        they were given."""
        steps = Steps(
            start=concatenate_rows(self.steps["start"], 3),
            direction=concatenate_rows(self.steps["direction"], 3),
            length=concatenate_rows(self.steps["length"], None),
            start_time=concatenate_rows(self.steps["start_time"], None),
            end_time=concatenate_rows(self.steps["end_time"], None),
            beta=concatenate_rows(self.steps["beta"], None),
            track=concatenate_rows(self.steps["track"], None, np.int64),
        )
        widths = {"start": 3, "end": 3}
        deposits = Deposits(
            **{
                name: concatenate_rows(
                    chunks, widths.get(name), np.int64 if name == "track" else np.float64
                )
                for name, chunks in self.deposits.items()
            }
        )
        # every track's (particle, parent, energy at creation), by global id
        tracks = (concatenate_rows(self.track_species, None, np.int64),
                  concatenate_rows(self.track_parent, None, np.int64),
                  concatenate_rows(self.track_energy, None))
        event_of = self.event_of
        # rows of each event, in their order: a stable sort by event, cut at the counts
        by_event = {name: _rows_by_event(event_of[records.track], self.n_events)
                    for name, records in (("steps", steps), ("deposits", deposits))}
        by_event["tracks"] = _rows_by_event(event_of, self.n_events)
        # a track's id within its event: its rank among that event's ids
        local = np.empty(event_of.size, dtype=np.int64)
        for rows in by_event["tracks"]:
            local[rows] = np.arange(rows.size)
        initial = np.broadcast_to(np.asarray(initial, np.float64), (self.n_events,))
        return [self._one_event(event, steps, deposits, tracks, local,
                                {name: rows[event] for name, rows in by_event.items()},
                                float(initial[event]))
                for event in range(self.n_events)]

    def _one_event(self, event, steps, deposits, tracks, local, rows, initial
                   ) -> TransportResult:
        """The records of ``event`` (``rows`` of its steps, deposits and ``tracks``, the
        (particle, parent, energy) arrays by global id) with its own track ids
        (``local``)."""
        def select(records, chosen):
            kept = {f.name: getattr(records, f.name)[chosen]
                    for f in dataclasses.fields(records)}
            return type(records)(**{**kept, "track": local[kept["track"]]})

        steps = select(steps, rows["steps"])
        deposits = select(deposits, rows["deposits"])
        species, parent, energy = (x[rows["tracks"]] for x in tracks)
        event_tracks = Tracks(
            particle=species,
            parent=np.where(parent >= 0, local[np.maximum(parent, 0)], -1),
            energy=energy,
            length=np.bincount(steps.track, weights=steps.length, minlength=species.size),
        )
        budget = EnergyBudget(
            initial=initial,
            rest_mass_released=float(self.rest_mass[event]),
            deposited=float(self.deposited[event]),
            below_cut=float(self.below_cut[event]),
            escaping=float(self.escaping[event]),
        )
        return TransportResult(steps=steps, deposits=deposits, tracks=event_tracks, budget=budget)


def _rows_by_event(events: np.ndarray, n_events: int) -> list[np.ndarray]:
    """The row indices of each event (``events``: the event of every row), each in
    increasing order."""
    order = np.argsort(events, kind="stable")
    return np.split(order, np.cumsum(np.bincount(events, minlength=n_events))[:-1])
