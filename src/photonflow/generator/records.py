"""Per-event records filled during transport: steps, energy deposits, tracks, energy ledger.

Internal units: cm, ns, MeV. Record arrays are accumulated as lists of chunks during
transport and concatenated once at the end.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class Steps:
    """Straight charged-particle steps (the Cherenkov emitters).

    Lengths are in cm inside transport and in m in :class:`~.generate.Photons`; times ns.
    """

    start: np.ndarray  # (N, 3)
    direction: np.ndarray  # (N, 3)
    length: np.ndarray
    start_time: np.ndarray  # ns
    end_time: np.ndarray  # ns
    beta: np.ndarray  # mid-step speed / c
    track: np.ndarray  # track id


@dataclasses.dataclass(frozen=True)
class Deposits:
    """Local energy deposits of one event (for scintillation and calorimetry).

    A deposit is either the continuous loss along a charged step (a segment from ``start``
    to ``end``) or a point deposit (``start`` == ``end``): the residual kinetic energy of a
    particle that fell below its tracking cut, or a photon below the photon cut.

    Attributes:
        start: (K, 3) segment start, m.
        end: (K, 3) segment end, m.
        start_time: ns.
        end_time: ns.
        energy: deposited energy, MeV.
        visible_energy: Birks-quenched energy, MeV (equals ``energy`` for kB = 0).
        track: id of the depositing track.
    """

    start: np.ndarray
    end: np.ndarray
    start_time: np.ndarray
    end_time: np.ndarray
    energy: np.ndarray
    visible_energy: np.ndarray
    track: np.ndarray

    @property
    def position(self) -> np.ndarray:
        """Deposit mid-points (K, 3), m."""
        return 0.5 * (self.start + self.end)


@dataclasses.dataclass(frozen=True)
class Tracks:
    """Every particle of the event, indexed by track id (the primary is 0).

    Attributes:
        particle: species code (:class:`.particles.Species`).
        parent: parent track id (-1 for the primary).
        energy: kinetic energy at creation, MeV.
        length: charged path length travelled, m (0 for photons).
    """

    particle: np.ndarray
    parent: np.ndarray
    energy: np.ndarray
    length: np.ndarray


@dataclasses.dataclass(frozen=True)
class EnergyBudget:
    """Energy bookkeeping of one event, MeV.

    Conservation reads ``deposited + below_cut + escaping = initial + rest_mass_released``:

    - initial: the primary's kinetic energy;
    - rest_mass_released: rest energy turned into kinetic or photon energy: +2 m_e per
      positron annihilation, -2 m_e per pair conversion, +(m_mu - m_e) per muon decay;
    - deposited: continuous energy loss along charged steps (restricted ionisation and
      sub-cut bremsstrahlung, deposited locally);
    - below_cut: residual kinetic energy of charged particles at their tracking cut, and
      photons below the photon cut (deposited locally);
    - escaping: energy leaving the event (neutrinos from muon decay; the medium is
      infinite, so nothing else escapes).
    """

    initial: float
    rest_mass_released: float
    deposited: float
    below_cut: float
    escaping: float

    @property
    def imbalance(self) -> float:
        """deposited + below_cut + escaping - (initial + rest_mass_released), MeV."""
        return (
            self.deposited + self.below_cut + self.escaping - self.initial - self.rest_mass_released
        )

    @property
    def relative_imbalance(self) -> float:
        """:attr:`imbalance` over (initial + rest_mass_released)."""
        return self.imbalance / (self.initial + self.rest_mass_released)


def concatenate_rows(chunks: list[np.ndarray], width: int | None, dtype=np.float64) -> np.ndarray:
    """Concatenate record chunks, returning an empty (0,) or (0, width) array if none."""
    if chunks:
        return np.concatenate(chunks)
    return np.empty((0,) if width is None else (0, width), dtype=dtype)
