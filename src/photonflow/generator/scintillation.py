"""Scintillation photons from energy deposits: Birks-quenched yield, isotropic, multi-exponential.

The number of photons of a deposit is Poisson with mean yield_scale x light_yield x
visible energy, where the visible energy is Birks-quenched,
dL/dE = 1 / (1 + kB1 dE/dx + kB2 (dE/dx)^2) (dE/dx in MeV cm^2/g; see :mod:`.transport`
and :mod:`.tables`). Photons are emitted uniformly along the deposit's segment at a
time uniform between its start and end times, isotropically, delayed by one of the
exponential decay components (chosen with the component weights; rise time neglected),
with a Gaussian emission spectrum of the material.
"""

from __future__ import annotations

import numpy as np

from .cherenkov import EmissionPhotons
from .directions import isotropic
from .materials import Material
from .records import Deposits


def scintillation_photons(
    rng: np.random.Generator, material: Material, deposits: Deposits, yield_scale: float
) -> EmissionPhotons:
    """Scintillation photons of all ``deposits`` (positions m, times ns, wavelengths nm)."""
    if material.light_yield <= 0.0 or yield_scale == 0.0:
        return EmissionPhotons(np.empty((0, 3)), np.empty((0, 3)), np.empty(0), np.empty(0),
                               np.empty(0, np.int64))
    counts = rng.poisson(yield_scale * material.light_yield * deposits.visible_energy)
    owner = np.repeat(np.arange(counts.size), counts)
    fraction = rng.random(owner.size)
    start, end = deposits.start[owner], deposits.end[owner]
    position = start + fraction[:, None] * (end - start)
    start_time, end_time = deposits.start_time[owner], deposits.end_time[owner]
    weights = np.asarray(material.decay_weights) / np.sum(material.decay_weights)
    component = rng.choice(len(material.decay_times), size=owner.size, p=weights)
    delay = rng.exponential(1.0, owner.size) * np.asarray(material.decay_times)[component]
    time = start_time + fraction * (end_time - start_time) + delay
    wavelength = material.emission_peak + material.emission_width * rng.standard_normal(owner.size)
    return EmissionPhotons(
        position=position,
        direction=isotropic(rng, owner.size),
        time=time,
        wavelength=wavelength,
        parent=deposits.track[owner],
    )
