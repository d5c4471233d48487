"""Simulated muons in water: mean ranges, Cherenkov yield, cone angle and thresholds.

References: ``shared/reference/physics.md`` sections 2 and 3 (PUMAS muon table in PDG
format; Frank-Tamm yield and Cherenkov thresholds with the WCSim n(lambda)).
"""

import numpy as np
import pytest

from photonflow.generator import WATER, Process, Track, generate, refractive_index
from photonflow.generator.cherenkov import cherenkov_spectrum

AXIS = (0.0, 0.0, 1.0)


def primary_path_lengths(energy, count, first_seed):
    """Path length (m) of the primary muon in ``count`` events (transport only)."""
    return np.array(
        [
            generate(
                Track("mu-", (0, 0, 0), AXIS, energy), first_seed + i, yield_scale=0.0
            ).tracks.length[0]
            for i in range(count)
        ]
    )


@pytest.mark.parametrize(
    ("energy", "csda", "count"), [(100.0, 31.23, 40), (300.0, 129.1, 20), (1000.0, 473.2, 10)]
)
def test_mean_simulated_range_matches_csda_table(energy, csda, count):
    """Mean path length of stopping muons within 3 % of the CSDA range of the PUMAS table
    (physics.md section 3). Range straggling is ~2.5 % per muon (knock-ons and the Bohr
    fluctuations of the continuous loss), so the means carry <= 0.7 % statistical error."""
    lengths = primary_path_lengths(energy, count, first_seed=11)
    assert lengths.mean() * 100.0 == pytest.approx(csda, rel=0.03)


def test_muon_cherenkov_yield_and_angle():
    """A 1 GeV muon's own photons: count per cm equals the Frank-Tamm yield at its speed
    (341.7/cm at beta = 1, physics.md section 2, scaled by the speed dependence) within
    Poisson error, and each photon sits on its cone cos(theta) = 1/(n(lambda) beta)."""
    photons = generate(Track("mu-", (0, 0, 0), AXIS, 1000.0), seed=3)
    steps = photons.steps
    spectrum = cherenkov_spectrum(WATER, (300.0, 600.0))
    own = steps.track == 0
    expected = np.sum(100.0 * steps.length[own] * spectrum.photons_per_cm(steps.beta[own]))
    emitted = np.sum((photons.parent == 0) & (photons.process == Process.CHERENKOV))
    assert abs(emitted - expected) < 4.0 * np.sqrt(expected)
    # the first metre: beta > 0.994, so the yield is within 2 % of the beta = 1 value
    first = own & (steps.start[:, 2] < 1.0)
    per_cm = np.sum(steps.length[first] * spectrum.photons_per_cm(steps.beta[first])) / np.sum(
        steps.length[first]
    )
    assert per_cm == pytest.approx(341.7, rel=0.02)
    # cone: compare with the emitting step's direction
    step_of_photon = np.flatnonzero(own)[:1]  # first step of the muon, exactly along z
    mask = (photons.parent == 0) & (photons.position[:, 2] < steps.length[step_of_photon[0]])
    cos_theta = photons.direction[mask, 2].astype(np.float64)
    beta = steps.beta[step_of_photon[0]]
    index = refractive_index(WATER, photons.wavelength[mask].astype(np.float64))
    np.testing.assert_allclose(cos_theta, 1.0 / (index * beta), atol=1e-5)


def test_cherenkov_threshold_in_simulation():
    """Muon threshold at 300 nm (n = 1.3594): T = 50.3 MeV [physics.md section 2 formula].
    A 45 MeV muon emits no light itself (its knock-on electrons may); a 70 MeV muon does.
    Electrons below the 0.243 MeV threshold emit nothing."""
    below = generate(Track("mu-", (0, 0, 0), AXIS, 45.0), seed=1)
    assert not np.any(below.parent == 0)
    above = generate(Track("mu-", (0, 0, 0), AXIS, 70.0), seed=1)
    assert np.sum(above.parent == 0) > 100
    slow = generate(Track("e-", (0, 0, 0), AXIS, 0.2), seed=1)
    assert len(slow) == 0
