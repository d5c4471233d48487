"""Electromagnetic showers in water: Cherenkov-weighted track length and shower maximum.

References: ``shared/reference/physics.md`` section 3 (Radel & Wiebusch Cherenkov-weighted
track length 5.321 m/GeV in ice rescaled to water, 4.84 m/GeV; PDG longitudinal profile
t_max = ln(E0/E_c) + C_e with C_e = -0.5; X0 = 36.08 g/cm^2) and section 2 (341.7
photons/cm at beta = 1 in 300-600 nm).
"""

import math

import numpy as np
import pytest
from scipy import optimize, special

from photonflow.generator import WATER, Track, generate
from photonflow.generator.cherenkov import cherenkov_spectrum
from photonflow.generator.stopping_power import critical_energy

AXIS = (0.0, 0.0, 1.0)
SPECTRUM = cherenkov_spectrum(WATER, (300.0, 600.0))


def cherenkov_weighted_length(photons):
    """Sum over charged steps of length x dN/dx(beta) / dN/dx(1), m."""
    steps = photons.steps
    weights = SPECTRUM.photons_per_cm(steps.beta) / SPECTRUM.photons_per_cm(1.0)
    return float(np.sum(steps.length * weights))


def showers(energy, count, first_seed=100):
    return [
        generate(Track("e-", (0, 0, 0), AXIS, energy), first_seed + i, yield_scale=0.0)
        for i in range(count)
    ]


def test_cherenkov_weighted_track_length_per_gev():
    """Mean Cherenkov-weighted track length of 1 GeV electron showers within 5 % of
    4.84 m/GeV (Radel-Wiebusch, rescaled to water; physics.md section 3), i.e. about
    1.65e5 photons/GeV in 300-600 nm. The shower-to-shower spread is ~1 %, so 8 showers
    give the mean to 0.4 %. The model gives ~4.98 m/GeV (+3 %)."""
    lengths = np.array([cherenkov_weighted_length(p) for p in showers(1000.0, 8)])
    assert lengths.mean() == pytest.approx(4.84, rel=0.05)
    assert lengths.mean() * SPECTRUM.photons_per_cm(1.0) * 100.0 == pytest.approx(1.65e5, rel=0.05)


def shower_maximum(events):
    """Depth of the maximum of a Gamma-function fit to the mean deposit profile, in X0."""
    radiation_length_cm = WATER.radiation_length / WATER.density
    edges = np.linspace(0.0, 15.0, 151)
    profile = np.zeros(edges.size - 1)
    for photons in events:
        depth = photons.deposits.position[:, 2] * 100.0 / radiation_length_cm
        profile += np.histogram(depth, bins=edges, weights=photons.deposits.energy)[0]
    centres = 0.5 * (edges[1:] + edges[:-1])
    profile /= len(events) * np.diff(edges)

    def gamma_profile(t, a, b, total):
        return total * b * (b * t) ** (a - 1) * np.exp(-b * t) / special.gamma(a)

    (a, b, _), _ = optimize.curve_fit(
        gamma_profile,
        centres,
        profile,
        p0=(2.0, 0.5, profile.sum() * 0.1),
        bounds=([1.01, 0.05, 0.0], [20.0, 5.0, 1e5]),
    )
    return (a - 1.0) / b


def test_shower_maximum_follows_pdg_formula():
    """Longitudinal maximum of 1 GeV e- showers against the PDG form
    t_max = ln(E0/E_c) - 0.5 = 2.05 X0 (physics.md section 3) with our Rossi
    E_c = 78.3 MeV, and against Radel-Wiebusch's Geant4 fit for electrons,
    a = 2.01849 + 0.63176 ln(E/GeV), b = 0.63207, t_max = (a - 1)/b = 1.61 X0.

    The PDG form is an approximate fit (here it sits ~0.4 X0 beyond both the Geant4 fit
    and this model), and single shower maxima scatter by ~1 X0, so that the fitted maximum
    of the mean profile of 24 showers carries ~0.15 X0 of statistical error: tolerances
    0.75 X0 (PDG) and 0.4 X0 (Radel-Wiebusch)."""
    maximum = shower_maximum(showers(1000.0, 24))
    assert maximum == pytest.approx(math.log(1000.0 / critical_energy(WATER)) - 0.5, abs=0.75)
    assert maximum == pytest.approx((2.01849 - 1.0) / 0.63207, abs=0.4)


def test_track_length_against_acem_fluka_model():
    """Cherenkov-weighted track length of electron showers at 1, 2 and 5 GeV against the
    ``acem`` package's FLUKA-based parametrisation for water (PDG code 11; lengths in cm):
    the mean within 5 % (the issue's criterion; the model is ~3 % above, like against
    Radel-Wiebusch). The shower-to-shower spread is compared, not matched: FLUKA's
    (2.7 % at 1 GeV, 2.3 % at 5 GeV) includes photonuclear and other hadronic
    fluctuations this generator does not model; ours must be smaller than it and shrink
    with energy, as the purely electromagnetic Geant4 values do (1.09 / 0.77 / 0.49 % at
    1 / 2 / 5 GeV, Radel & Wiebusch, physics.md section 3)."""
    from acem import media, model  # a test dependency (pyproject "test" extra)

    reference = model.Parametrization1D(media.WATER)
    spreads = []
    for energy_gev, count in ((1.0, 6), (2.0, 4), (5.0, 3)):
        lengths = np.array(
            [cherenkov_weighted_length(p) for p in showers(1000.0 * energy_gev, count, 300)]
        )
        fluka = reference.ltot_dist(11, energy_gev)
        fluka_mean_m = fluka.mean() / 100.0
        assert lengths.mean() == pytest.approx(fluka_mean_m, rel=0.05)
        spread = lengths.std(ddof=1) / lengths.mean()
        assert spread < fluka.std() / fluka.mean()
        spreads.append(spread)
    assert spreads[0] > spreads[-1]
