"""Condensed-history transport of a particle and all its secondaries (vectorised stacks).

All live charged particles advance one step per iteration, and all live photons make one
interaction, so numpy works on whole stacks; the loop ends when both stacks are empty.

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

A particle below its tracking cut deposits its residual kinetic energy on the spot;
positrons then annihilate at rest into two back-to-back 0.511 MeV photons; muons decay
into a Michel electron if ``muon_decay`` is set. Photons travel an exponential distance,
then Compton-scatter (Klein-Nishina) or convert (screened Bethe-Heitler); photons below
the photon cut are absorbed on the spot. Positrons do not annihilate in flight.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .bremsstrahlung import sample_emission_polar, sample_photon_energy
from .compton import sample_energy_fraction
from .constants import CM_PER_M, ELECTRON_MASS, MUON_LIFETIME, MUON_MASS, SPEED_OF_LIGHT
from .decay import sample_michel_energy
from .directions import isotropic, rotate, unit
from .knock_on import sample_electron_transfer, sample_heavy_transfer
from .materials import Material
from .pair_production import sample_positron_fraction
from .particles import SPECIES_MASS, Species
from .records import Deposits, EnergyBudget, Steps, Tracks, concatenate_rows
from .scattering import highland_variance_increment, scatter
from .stopping_power import maximum_transfer
from .tables import PhysicsTables


@dataclasses.dataclass(frozen=True)
class Stack:
    """Live particles of one kind (struct of arrays; cm, ns, MeV)."""

    species: np.ndarray
    position: np.ndarray
    direction: np.ndarray
    energy: np.ndarray
    time: np.ndarray
    track: np.ndarray
    path: np.ndarray

    @property
    def size(self) -> int:
        return self.energy.size

    def select(self, mask: np.ndarray) -> Stack:
        return Stack(*(getattr(self, f.name)[mask] for f in dataclasses.fields(self)))

    @staticmethod
    def join(stacks: list[Stack]) -> Stack:
        return Stack(
            *(
                np.concatenate([getattr(s, f.name) for s in stacks])
                for f in dataclasses.fields(Stack)
            )
        )

    @staticmethod
    def empty() -> Stack:
        return Stack(
            np.empty(0, np.int64),
            np.empty((0, 3)),
            np.empty((0, 3)),
            np.empty(0),
            np.empty(0),
            np.empty(0, np.int64),
            np.empty(0),
        )


@dataclasses.dataclass(frozen=True)
class TransportResult:
    """Everything transport produces for one event (internal units: cm, ns, MeV)."""

    steps: Steps
    deposits: Deposits
    tracks: Tracks
    budget: EnergyBudget


class _Event:
    """Mutable accumulator of one event's records while it is transported."""

    def __init__(
        self, material: Material, tables: PhysicsTables, rng: np.random.Generator, muon_decay: bool
    ):
        self.material, self.tables, self.rng, self.muon_decay = material, tables, rng, muon_decay
        self.steps: dict[str, list[np.ndarray]] = {f.name: [] for f in dataclasses.fields(Steps)}
        self.deposits: dict[str, list[np.ndarray]] = {
            f.name: [] for f in dataclasses.fields(Deposits)
        }
        self.track_species: list[np.ndarray] = []
        self.track_parent: list[np.ndarray] = []
        self.track_energy: list[np.ndarray] = []
        self.next_track = 0
        self.deposited = self.below_cut = self.escaping = self.rest_mass = 0.0
        self.new_charged: list[Stack] = []
        self.new_photons: list[Stack] = []

    # ---- bookkeeping ------------------------------------------------------------------

    def register(self, species, energy, parent) -> np.ndarray:
        """Give new tracks consecutive ids and record them."""
        count = energy.size
        ids = np.arange(self.next_track, self.next_track + count, dtype=np.int64)
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
        self.below_cut += float(np.sum(energy))

    # ---- creating particles -------------------------------------------------------------

    def spawn_charged(self, species, position, direction, energy, time, parent):
        """New e-/e+/mu: tracked if above their cut, else deposited (positrons annihilate)."""
        species = np.asarray(species, dtype=np.int64) * np.ones(energy.size, dtype=np.int64)
        ids = self.register(species, energy, parent)
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

    def spawn_photons(self, position, direction, energy, time, parent):
        """New photons: tracked above the photon cut, else absorbed on the spot."""
        ids = self.register(np.full(energy.size, Species.GAMMA), energy, parent)
        self._continue_photons(position, direction, energy, time, ids)

    def finish_charged(self, species, position, energy, time, track):
        """End charged tracks: residual energy deposited, e+ annihilate, muons may decay."""
        self.point_deposit(position, time, energy, species, track)
        positron = species == Species.POSITRON
        if np.any(positron):
            count = int(positron.sum())
            self.rest_mass += 2.0 * ELECTRON_MASS * count
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
            self.rest_mass += (MUON_MASS - ELECTRON_MASS) * count
            self.escaping += float(np.sum(MUON_MASS - total))
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

    # ---- transport ----------------------------------------------------------------------

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
        interacting = discrete & alive
        if np.any(interacting):
            sigma_now = self._discrete_cross_sections(species[interacting], after[interacting])
            accept = rng.random(sigma_now.shape[1]) * sigma_used[interacting] < sigma_now.sum(
                axis=0
            )
            is_knock_on = rng.random(sigma_now.shape[1]) * sigma_now.sum(axis=0) < sigma_now[0]
            which = np.flatnonzero(interacting)
            moved = self._knock_on(moved, which[accept & is_knock_on])
            moved = self._bremsstrahlung(moved, which[accept & ~is_knock_on])

        ended = ended | (moved.energy < stop)
        self.finish_charged(
            species[ended],
            moved.position[ended],
            moved.energy[ended],
            moved.time[ended],
            moved.track[ended],
        )
        return moved.select(~ended)

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
        self.deposited += float(np.sum(loss))

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
            self.rest_mass -= 2.0 * ELECTRON_MASS * k.size
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

    def result(self, initial: float) -> TransportResult:
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
        species = concatenate_rows(self.track_species, None, np.int64)
        length = np.bincount(steps.track, weights=steps.length, minlength=species.size)
        tracks = Tracks(
            particle=species,
            parent=concatenate_rows(self.track_parent, None, np.int64),
            energy=concatenate_rows(self.track_energy, None),
            length=length,
        )
        budget = EnergyBudget(
            initial=initial,
            rest_mass_released=self.rest_mass,
            deposited=self.deposited,
            below_cut=self.below_cut,
            escaping=self.escaping,
        )
        return TransportResult(steps=steps, deposits=deposits, tracks=tracks, budget=budget)


def _fluctuate(rng: np.random.Generator, mean: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """Gamma-distributed energy losses with the given mean and variance (MeV, MeV^2)."""
    positive = (mean > 0) & (variance > 0)
    shape = np.where(positive, mean * mean / np.where(positive, variance, 1.0), 1.0)
    scale = np.where(positive, variance / np.where(positive, mean, 1.0), 0.0)
    return np.where(positive, rng.gamma(shape, scale), mean)


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
