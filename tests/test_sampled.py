"""Sampled (Monte Carlo) mode: bookkeeping, reproducibility, analytic rungs, samplers."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from photonflow.errors import ConfigError
from photonflow.geometry import preset_detector
from photonflow.geometry.shapes import xyz
from photonflow.params import default_params
from photonflow.sources import DiffuserSource, IsotropicSource, LaserSource
from photonflow.transport import direct_light
from photonflow.transport.emission import sample_directions
from photonflow.transport.optics import (
    SPEED_OF_LIGHT,
    TransportConfig,
    deflect,
    deflect_xyz,
    dome_normal,
    dome_normal_xyz,
    lambertian_density,
    lambertian_direction,
    rayleigh_density,
    sample_rayleigh_cos,
    specular_direction,
    specular_direction_xyz,
)
from photonflow.transport.photon_loop import _alive_lanes, _wall_response
from photonflow.transport.pseudo_data import sample, sample_events
from photonflow.transport.sampled import sample_photons

pytestmark = pytest.mark.compile_bound

SPHERE = preset_detector("TOY_SPHERE")
CYLINDER = preset_detector("TOY_CYLINDER")
RADIUS = SPHERE.shape.radius
CONFIG = TransportConfig(batch_size=1 << 16)


def black(detector, **changes):
    """No scattering, black walls and sensor glass, plus changes."""
    params = default_params(detector).replace(
        scattering_length=math.inf, wall_reflectivity=0.0, sensor_reflectivity=0.0
    )
    return params.replace(**changes)


def within(observed, expected, n, sigmas=5.0):
    """|observed - expected| within ``sigmas`` binomial errors of a fraction of n trials."""
    error = math.sqrt(max(expected * (1 - expected), 1e-12) / n)
    return abs(observed - expected) < sigmas * error


def bookkeeping_holds(tally):
    return (
        tally.detected + tally.absorbed + tally.lost == tally.emitted
        and tally.n_pe.sum() == tally.detected == tally.photon_sensor.size
    )


@pytest.fixture(scope="module")
def centre_run():
    """Absorption only, black walls, QE 1, flat acceptance, source at the centre."""
    params = black(
        SPHERE, absorption_length=5.0, quantum_efficiency=1.0,
        angular_acceptance=np.ones(10, np.float32),
    )
    source = IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=1e6)
    return params, source, sample_photons(SPHERE, params, source, 0, config=CONFIG)


def test_absorption_only_fractions_match_analytic(centre_run):
    params, source, tally = centre_run
    n = tally.emitted
    survive = math.exp(-RADIUS / 5.0)
    assert bookkeeping_holds(tally)
    assert tally.lost == 0 and tally.absorbed_sensor == 0
    assert within(tally.absorbed_bulk / n, 1 - survive, n)
    mu, _ = direct_light(SPHERE, params, source)
    seen = float(mu.sum()) / n / survive  # sum of Omega_j / 4 pi
    assert within(tally.detected / n, survive * seen, n)
    assert within(tally.absorbed_wall / n, survive * (1 - seen), n)


def test_unscattered_arrival_times_are_distance_over_group_velocity(centre_run):
    params, _, tally = centre_run
    distance = tally.photon_time * SPEED_OF_LIGHT / float(params.group_index)
    disc_radius = float(SPHERE.sensor_radius[0])
    assert distance.min() > RADIUS * (1 - 1e-6)
    assert distance.max() < math.hypot(RADIUS, disc_radius) * (1 + 1e-6)


def chi2_per_ndf(n_pe, mu):
    used = mu > 5
    return float(np.sum((n_pe[used] - mu[used]) ** 2 / mu[used])) / int(used.sum())


def test_sampled_mean_agrees_with_direct_light(centre_run):
    params, source, tally = centre_run
    mu, _ = direct_light(SPHERE, params, source)
    assert 0.8 < chi2_per_ndf(tally.n_pe, np.asarray(mu, np.float64)) < 1.25
    # off-centre, realistic QE, acceptance curve and per-sensor efficiencies
    rng = np.random.default_rng(3)
    params = black(SPHERE, absorption_length=4.0,
                   efficiency=rng.uniform(0.7, 1.3, SPHERE.n_sensors).astype(np.float32))
    source = IsotropicSource(position=[0.7, -0.4, 0.5], n_photons=1e6)
    tally = sample_photons(SPHERE, params, source, 1, config=CONFIG)
    light, _ = direct_light(SPHERE, params, source)  # a sensor of efficiency 1
    mu = np.asarray(light, np.float64) * np.asarray(params.efficiency, np.float64)
    assert 0.8 < chi2_per_ndf(tally.n_pe, mu) < 1.25


def test_scattered_photons_are_capped_with_no_bounces():
    params = black(SPHERE, absorption_length=math.inf, scattering_length=3.0)
    source = IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=2e5)
    config = TransportConfig(n_bounces=0, batch_size=1 << 16)
    tally = sample_photons(SPHERE, params, source, 2, config=config)
    n = tally.emitted
    assert bookkeeping_holds(tally) and tally.absorbed_bulk == 0
    unscattered = math.exp(-RADIUS / 3.0)
    reached_wall = tally.detected + tally.absorbed_wall + tally.absorbed_sensor
    assert within(reached_wall / n, unscattered, n)
    assert tally.capped == n - reached_wall


def test_mirror_walls_conserve_photons_until_the_cap():
    params = default_params(CYLINDER).replace(
        absorption_length=math.inf, scattering_length=math.inf, wall_reflectivity=1.0,
        wall_specular_fraction=0.5, sensor_reflectivity=1.0, quantum_efficiency=0.0,
    )
    source = IsotropicSource(position=[0.3, 0.2, -0.5], n_photons=5e4)
    config = TransportConfig(n_bounces=6, batch_size=1 << 16)
    tally = sample_photons(CYLINDER, params, source, 3, config=config)
    assert tally.capped == tally.emitted
    assert tally.detected == tally.absorbed == tally.escaped == 0


@pytest.fixture(scope="module")
def water_runs():
    params = default_params(CYLINDER).replace(absorption_length=20.0, scattering_length=8.0,
                                              wall_reflectivity=0.3)
    source = IsotropicSource(position=[0.5, 0.0, 0.3], n_photons=3e5)
    return [
        sample_photons(CYLINDER, params, source, 4, config=TransportConfig(batch_size=b))
        for b in (1 << 10, 1 << 14)
    ]


def test_bookkeeping_is_exact(water_runs):
    for tally in water_runs:
        assert bookkeeping_holds(tally)
        assert tally.absorbed_bulk > 0 and tally.absorbed_wall > 0 and tally.capped > 0
        assert tally.absorbed_sensor > 0 and tally.escaped == 0


def test_batch_size_does_not_change_statistics(water_runs):
    small, large = water_runs
    n = small.emitted
    for name in ("detected", "absorbed_bulk", "absorbed_wall", "absorbed_sensor", "capped"):
        a, b = getattr(small, name) / n, getattr(large, name) / n
        p = 0.5 * (a + b)
        assert abs(a - b) < 5 * math.sqrt(2 * p * (1 - p) / n), name
    both = small.n_pe + large.n_pe
    used = both > 0
    chi2 = np.sum((small.n_pe[used] - large.n_pe[used]) ** 2 / both[used]) / used.sum()
    assert 0.7 < chi2 < 1.4
    assert not np.array_equal(small.n_pe, large.n_pe)


def test_open_medium_photons_escape():
    detector = preset_detector("ICECUBE_MINI")
    params = default_params(detector).replace(absorption_length=100.0, scattering_length=50.0)
    source = IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=1e4)
    tally = sample_photons(detector, params, source, 5, config=CONFIG)
    assert bookkeeping_holds(tally)
    assert tally.escaped > 0 and tally.absorbed_wall == 0


def test_same_seed_same_events_different_seed_differs():
    params = default_params(CYLINDER)
    source = IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=2e4, pulse_width=1.0)
    a, b, c = (sample(CYLINDER, params, source, seed, config=CONFIG) for seed in (9, 9, 10))
    np.testing.assert_array_equal(a.sensor_ids, b.sensor_ids)
    np.testing.assert_array_equal(a.charge, b.charge)
    np.testing.assert_array_equal(a.time, b.time)
    assert a.truth.seed == 9 and a.truth.source_kind == "isotropic"
    assert not np.array_equal(a.charge, c.charge) or not np.array_equal(a.time, c.time)
    first = list(sample_events(CYLINDER, params, source, 9, 3, config=CONFIG))
    again = list(sample_events(CYLINDER, params, source, 9, 3, config=CONFIG))
    np.testing.assert_array_equal(first[0].time, a.time)
    for x, y in zip(first, again, strict=True):
        np.testing.assert_array_equal(x.charge, y.charge)
    assert not np.array_equal(first[1].charge, first[2].charge)


@pytest.mark.parametrize(
    "change",
    [
        {"source": IsotropicSource(position=[0.0, 0.0, 5.0], n_photons=100.0)},
        {"source": IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=0.0)},
        {"source": IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=0.3)},
        {"params": {"absorption_length": math.nan}},
        {"config": TransportConfig(n_bounces=-1)},
    ],
)
def test_bad_input_raises_one_line_config_error(change):
    source = change.get("source", IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=100.0))
    params = default_params(SPHERE).replace(**change.get("params", {}))
    with pytest.raises(ConfigError) as error:
        sample(SPHERE, params, source, 0, config=change.get("config", CONFIG))
    assert "\n" not in str(error.value)


# ---- sampled angles against their densities ------------------------------------------


def histogram_chi2_per_ndf(values, density_cdf, bins=40, low=-1.0):
    """chi2/ndf of a histogram of values in [low, 1] against a CDF."""
    edges = np.linspace(low, 1.0, bins + 1)
    counts, _ = np.histogram(values, edges)
    expected = values.size * np.diff(density_cdf(edges))
    return float(np.sum((counts - expected) ** 2 / expected)) / bins


def test_rayleigh_angles_follow_their_density():
    a = 0.835
    u = jax.random.uniform(jax.random.PRNGKey(0), (400_000,))
    cos = np.asarray(sample_rayleigh_cos(u, a), np.float64)
    norm = 2 * math.pi / (4 * math.pi * (1 + a / 3))
    assert abs(float(rayleigh_density(jnp.float32(0.0), a)) * 4 * math.pi * (1 + a / 3) - 1) < 1e-6

    def cdf(x):
        return norm * (x + 1 + a * (x**3 + 1) / 3)

    assert histogram_chi2_per_ndf(cos, cdf) < 2.0


def test_lambertian_angles_follow_their_density():
    keys = jax.random.split(jax.random.PRNGKey(1))
    u1, u2 = (jax.random.uniform(k, (400_000,)) for k in keys)
    normal = jnp.broadcast_to(jnp.array([0.0, 0.0, -1.0]), (400_000, 3))
    cos = -np.asarray(lambertian_direction(normal, u1, u2)[:, 2], np.float64)
    assert cos.min() >= 0
    assert float(lambertian_density(jnp.float32(1.0))) == pytest.approx(1 / math.pi)

    def cdf(x):
        return np.clip(x, 0, 1) ** 2  # density 2 cos in cos for cos in [0, 1]

    assert histogram_chi2_per_ndf(cos, cdf, low=0.0) < 2.0


@pytest.mark.parametrize("kind", ["isotropic", "laser", "diffuser"])
def test_emission_directions_follow_the_source_density(kind):
    axis = np.array([0.6, 0.0, 0.8])
    source = {
        "isotropic": IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=1.0),
        "laser": LaserSource(position=[0.0, 0.0, 0.0], direction=axis, n_photons=1.0,
                             opening_angle=0.5),
        "diffuser": DiffuserSource(position=[0.0, 0.0, 0.0], n_photons=1.0, direction=axis,
                                   anisotropy=0.6),
    }[kind]
    keys = jax.random.split(jax.random.PRNGKey(2))
    u1, u2 = (jax.random.uniform(k, (400_000,)) for k in keys)
    directions = np.asarray(sample_directions(source, u1, u2), np.float64)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-5)
    ref = np.array([0.0, 0.0, 1.0]) if kind == "isotropic" else axis
    cos = directions @ ref
    cut = math.cos(0.5)

    def cdf(x):
        if kind == "isotropic":
            return (x + 1) / 2
        if kind == "laser":
            return np.clip((x - cut) / (1 - cut), 0, 1)
        return ((x + 1) + 0.6 * (x**2 - 1) / 2) / 2

    low = cut if kind == "laser" else -1.0
    assert cos.min() >= low - 1e-5
    assert histogram_chi2_per_ndf(np.clip(cos, low, 1.0), cdf, low=low) < 2.0
    # the azimuth about the axis is uniform: the mean transverse component vanishes
    transverse = directions - cos[:, None] * ref
    assert np.all(np.abs(transverse.mean(axis=0)) < 5 / math.sqrt(cos.size))


# ---- the building blocks of a step ----------------------------------------------------


def unit_vectors(rng, n):
    v = rng.normal(size=(n, 3))
    return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)


def test_component_wise_directions_equal_the_vector_ones():
    rng = np.random.default_rng(4)
    n = 20_000
    d, normal = unit_vectors(rng, n), unit_vectors(rng, n)
    d[:100] = [0.0, 0.0, 1.0]  # along the helper-axis switch
    cos_t = rng.uniform(-1, 1, n).astype(np.float32)
    phi = rng.uniform(0, 2 * math.pi, n).astype(np.float32)
    radius = rng.uniform(0.1, 0.3, n).astype(np.float32)
    offset = (0.2 * rng.normal(size=(n, 3))).astype(np.float32)
    pairs = [
        (deflect(d, cos_t, phi), deflect_xyz(xyz(d), cos_t, phi)),
        (specular_direction(d, normal), specular_direction_xyz(xyz(d), xyz(normal))),
        (dome_normal(offset, normal, radius), dome_normal_xyz(xyz(offset), xyz(normal), radius)),
    ]
    for vectors, components in pairs:
        np.testing.assert_allclose(np.stack(components, -1), vectors, atol=2e-5)


def test_alive_lanes_are_the_nonzero_indices():
    alive = jnp.asarray(np.random.default_rng(5).uniform(size=1000) < 0.3)
    lanes, count = _alive_lanes(alive, 1024)
    expected = np.flatnonzero(np.asarray(alive))
    assert int(count) == expected.size
    np.testing.assert_array_equal(lanes[: expected.size], expected)
    assert np.all(np.asarray(lanes[expected.size :]) == 1000)


def test_wall_reflections_split_into_specular_and_lambertian_fractions():
    params = default_params(CYLINDER).replace(wall_reflectivity=0.3, wall_specular_fraction=0.25)
    u = (jnp.arange(100_000, dtype=jnp.float32) + 0.5) / 100_000
    reflected, specular = (np.asarray(x) for x in _wall_response(u, params))
    assert reflected.mean() == pytest.approx(0.3, abs=1e-4)
    assert specular[reflected].mean() == pytest.approx(0.25, abs=1e-3)
    assert not np.any(specular & ~reflected)
