"""Generator API: validation of tracks and settings, output layout, reproducibility,
energy conservation, scintillation and muon decay."""

import numpy as np
import pytest

from photonflow.errors import ConfigError
from photonflow.generator import (
    LAB,
    WATER,
    GeneratorSettings,
    Photons,
    Process,
    Track,
    generate,
    water_based_scintillator,
)
from photonflow.generator.constants import ELECTRON_MASS, MUON_MASS
from photonflow.generator.particles import Species

AXIS = (0.0, 0.0, 1.0)


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"particle": "proton"}, "track.particle"),
        ({"direction": (0.0, 0.0, 2.0)}, "track.direction"),
        ({"direction": (1.0, 0.0)}, "track.direction"),
        ({"position": (0.0, float("nan"), 0.0)}, "track.position"),
        ({"energy": -5.0}, "track.energy"),
        ({"energy": 2.0e4}, "track.energy"),
        ({"energy": "lots"}, "track.energy"),
        ({"time": float("inf")}, "track.time"),
    ],
)
def test_track_validation_names_field_and_value(changes, field):
    arguments = {"particle": "mu-", "position": (0, 0, 0), "direction": AXIS, "energy": 100.0}
    arguments.update(changes)
    with pytest.raises(ConfigError) as error:
        Track(**arguments)
    message = str(error.value)
    assert field in message and "\n" not in message


def test_track_normalises_direction_within_tolerance():
    track = Track("e-", [1, 2, 3], (0.0, 0.6, 0.8000001), 10)
    np.testing.assert_array_equal(track.position, [1.0, 2.0, 3.0])
    assert np.linalg.norm(track.direction) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"yield_scale": -1.0}, "yield_scale"),
        ({"band": (600.0, 300.0)}, "band"),
        ({"photon_cut": 0.0}, "photon_cut"),
        ({"step_fraction": 0.9}, "step_fraction"),
        ({"muon_decay": "yes"}, "muon_decay"),
    ],
)
def test_settings_validation(changes, field):
    with pytest.raises(ConfigError, match=field):
        GeneratorSettings(**changes)


def test_unknown_setting_and_medium_are_rejected():
    track = Track("e-", (0, 0, 0), AXIS, 1.0)
    with pytest.raises(ConfigError, match="yeild_scale"):
        generate(track, 1, yeild_scale=0.1)
    with pytest.raises(ConfigError, match="medium"):
        generate(track, 1, medium="heavy water")


def test_output_layout_units_and_band():
    """Shapes, dtypes, unit directions, Cherenkov wavelengths in the band, times after
    the start, photons within the muon's reach (metres)."""
    start = (1.0, -2.0, 3.0)
    photons = generate(Track("mu+", start, AXIS, 300.0, time=5.0), seed=2, yield_scale=0.1)
    assert isinstance(photons, Photons)
    count = len(photons)
    assert count > 1000
    assert photons.position.shape == (count, 3) and photons.position.dtype == np.float32
    assert photons.direction.shape == (count, 3)
    assert photons.time.shape == photons.wavelength.shape == photons.parent.shape == (count,)
    np.testing.assert_allclose(np.linalg.norm(photons.direction, axis=1), 1.0, atol=1e-6)
    assert np.all(photons.process == Process.CHERENKOV)  # water does not scintillate
    assert photons.wavelength.min() >= 300.0 and photons.wavelength.max() <= 600.0
    assert photons.time.min() >= 5.0
    reach = np.linalg.norm(photons.position - np.asarray(start, np.float32), axis=1)
    assert reach.max() < 1.6  # CSDA range 1.29 m plus knock-on electrons and photons
    assert set(np.unique(photons.parent)) <= set(range(photons.tracks.particle.size))


def test_same_seed_same_photons_different_seed_different():
    track = Track("e-", (0, 0, 0), AXIS, 200.0)
    first = generate(track, seed=7, yield_scale=0.05)
    again = generate(track, seed=7, yield_scale=0.05)
    other = generate(track, seed=8, yield_scale=0.05)
    for name in ("position", "direction", "time", "wavelength", "process", "parent"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
    np.testing.assert_array_equal(first.deposits.energy, again.deposits.energy)
    assert len(first) != len(other) or not np.array_equal(first.position, other.position)


@pytest.mark.parametrize(
    ("particle", "energy", "decay"),
    [
        ("e-", 500.0, False),
        ("e+", 200.0, False),
        ("gamma", 1000.0, False),
        ("mu-", 400.0, True),
        ("mu+", 200.0, True),
        ("mu-", 2000.0, False),
    ],
)
def test_energy_conservation(particle, energy, decay):
    """deposited + below_cut + escaping = initial + rest mass released, to 1e-6."""
    photons = generate(
        Track(particle, (0, 0, 0), AXIS, energy), seed=5, yield_scale=0.0, muon_decay=decay
    )
    budget = photons.budget
    assert abs(budget.relative_imbalance) < 1e-6
    assert budget.initial == energy
    assert photons.deposits.energy.sum() == pytest.approx(
        budget.deposited + budget.below_cut, rel=1e-9
    )


def test_rest_mass_accounting_of_pairs_and_annihilation():
    """Every positron that annihilates releases 2 m_e, every conversion binds 2 m_e."""
    photons = generate(Track("e+", (0, 0, 0), AXIS, 1000.0), seed=4, yield_scale=0.0)
    positrons = np.sum(photons.tracks.particle == Species.POSITRON)
    conversions = positrons - 1  # every positron but the primary comes from a conversion
    released = 2.0 * ELECTRON_MASS * (positrons - conversions)
    assert photons.budget.rest_mass_released == pytest.approx(released, abs=1e-9)


def test_muon_decay_produces_michel_electron():
    """A stopped mu- decays into an electron of at most 52.3 MeV kinetic energy, later by
    ~2.2 us on average; neutrinos carry the rest (escaping)."""
    photons = generate(
        Track("mu-", (0, 0, 0), AXIS, 150.0), seed=9, yield_scale=0.0, muon_decay=True
    )
    tracks = photons.tracks
    michel = np.flatnonzero(
        (tracks.parent == 0)
        & (tracks.energy > 0)
        & (tracks.particle == Species.ELECTRON)
        & (tracks.energy == tracks.energy[tracks.parent == 0].max())
    )
    assert michel.size == 1
    assert 0.0 < tracks.energy[michel[0]] < 52.83 - ELECTRON_MASS
    assert photons.budget.escaping == pytest.approx(
        MUON_MASS - tracks.energy[michel[0]] - ELECTRON_MASS, rel=1e-12
    )
    assert photons.deposits.end_time.max() > 10.0  # the decay happens long after the stop


def test_scintillation_yield_and_isotropy():
    """LAB (physics.md section 6): 11522 photons/MeV of Birks-quenched deposit, isotropic."""
    scale = 0.01
    photons = generate(
        Track("e-", (0, 0, 0), AXIS, 100.0), seed=1, medium="scintillator", yield_scale=scale
    )
    scintillation = photons.process == Process.SCINTILLATION
    expected = scale * LAB.light_yield * photons.deposits.visible_energy.sum()
    assert abs(scintillation.sum() - expected) < 5.0 * np.sqrt(expected)
    assert np.all(photons.deposits.visible_energy <= photons.deposits.energy)
    assert photons.deposits.visible_energy.sum() > 0.8 * photons.deposits.energy.sum()
    mean_direction = photons.direction[scintillation].astype(np.float64).mean(axis=0)
    assert np.linalg.norm(mean_direction) < 0.03
    assert np.any(photons.process == Process.CHERENKOV)


def test_scintillation_time_profile():
    """LAB e/gamma decay constants 4.93/20.6/190 ns with weights 0.799/0.171/0.030
    (physics.md section 6): mean delay sum(w tau) = 13.16 ns and a fraction
    sum(w exp(-100 ns / tau)) = 0.0190 later than 100 ns. A 3 MeV electron deposits
    within picoseconds and gives ~3e4 photons: statistical errors 0.3 ns and 0.0008."""
    photons = generate(Track("e-", (0, 0, 0), AXIS, 3.0), seed=2, medium="scintillator")
    delay = photons.time[photons.process == Process.SCINTILLATION].astype(np.float64)
    assert delay.size > 20000
    assert delay.mean() == pytest.approx(13.16, abs=1.2)
    assert np.mean(delay > 100.0) == pytest.approx(0.0190, abs=0.003)


def test_birks_quenching_of_a_minimum_ionising_step():
    """A muon step in LAB: visible / deposited = 1 / (1 + kB1 S + kB2 S^2) with
    S = dE / (rho dx) ~ 1.8 MeV cm^2/g, kB1 = 6.5e-3, kB2 = 1.5e-6 (physics.md section 6)."""
    photons = generate(
        Track("mu-", (0, 0, 0), AXIS, 1000.0), seed=1, medium="scintillator", yield_scale=0.0
    )
    deposits = photons.deposits
    segment = np.linalg.norm(deposits.end - deposits.start, axis=1) * 100.0
    first = np.flatnonzero((deposits.track == 0) & (segment > 1.0))[0]
    specific = deposits.energy[first] / (LAB.density * segment[first])
    ratio = deposits.visible_energy[first] / deposits.energy[first]
    assert ratio == pytest.approx(1.0 / (1.0 + 6.5e-3 * specific + 1.5e-6 * specific**2), rel=1e-12)


def test_water_based_scintillator_interpolates():
    pure_water = water_based_scintillator(0.0)
    pure_lab = water_based_scintillator(1.0)
    assert pure_water.z_over_a == pytest.approx(WATER.z_over_a)
    assert pure_water.mean_excitation == pytest.approx(WATER.mean_excitation)
    assert pure_lab.density == pytest.approx(LAB.density)
    assert pure_lab.radiation_length == pytest.approx(LAB.radiation_length)
    wbls = water_based_scintillator(0.05)
    assert wbls.light_yield == pytest.approx(0.05 * LAB.light_yield)
    photons = generate(Track("e-", (0, 0, 0), AXIS, 20.0), seed=1, medium=wbls, yield_scale=0.1)
    assert np.any(photons.process == Process.SCINTILLATION)
    with pytest.raises(ConfigError, match="lab_fraction"):
        water_based_scintillator(1.5)
