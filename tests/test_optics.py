"""The shared optics: samplers reproduce their densities, densities integrate to 1."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

from photonflow.sources import DiffuserSource, LaserSource
from photonflow.transport.emission import sample_directions
from photonflow.transport.optics import (
    WATER_RAYLEIGH_ANISOTROPY,
    deflect,
    henyey_greenstein_density,
    lambertian_density,
    lambertian_direction,
    rayleigh_density,
    sample_henyey_greenstein_cos,
    sample_rayleigh_cos,
    specular_direction,
)

N_SAMPLES = 200_000
N_BINS = 40


def sphere_integral(density):
    """Integral over the sphere of a density of cos(theta) alone: 2 pi int_{-1}^{1} f dmu."""
    value, _ = integrate.quad(lambda mu: float(density(mu)), -1.0, 1.0, epsabs=1e-12)
    return 2 * math.pi * value


def chi2_pvalue(cos_samples, density):
    """Pearson chi2 p-value of a histogram of cos(theta) against 2 pi f(mu) dmu."""
    edges = np.linspace(-1.0, 1.0, N_BINS + 1)
    counts, _ = np.histogram(np.asarray(cos_samples, dtype=np.float64), edges)
    probabilities = np.array(
        [
            2 * math.pi * integrate.quad(lambda mu: float(density(mu)), a, b)[0]
            for a, b in zip(edges[:-1], edges[1:], strict=True)
        ]
    )
    expected = probabilities * len(cos_samples)
    keep = expected > 5
    chi2 = np.sum((counts[keep] - expected[keep]) ** 2 / expected[keep])
    return stats.chi2.sf(chi2, keep.sum() - 1)


def uniforms(seed, n=N_SAMPLES):
    return np.random.default_rng(seed).random(n)


@pytest.mark.parametrize("anisotropy", [0.0, WATER_RAYLEIGH_ANISOTROPY, 1.0])
def test_rayleigh_sampler_and_density(anisotropy):
    with jax.enable_x64(True):

        def density(mu):
            return rayleigh_density(jnp.asarray(mu), anisotropy)

        assert sphere_integral(density) == pytest.approx(1.0, rel=1e-10)
        samples = sample_rayleigh_cos(jnp.asarray(uniforms(1)), anisotropy)
        assert chi2_pvalue(samples, density) > 1e-3


@pytest.mark.parametrize("g", [-0.5, 0.0, 0.4, 0.9])
def test_henyey_greenstein_sampler_and_density(g):
    with jax.enable_x64(True):

        def density(mu):
            return henyey_greenstein_density(jnp.asarray(mu), g)

        assert sphere_integral(density) == pytest.approx(1.0, rel=1e-8)
        samples = sample_henyey_greenstein_cos(jnp.asarray(uniforms(2)), g)
        assert chi2_pvalue(samples, density) > 1e-3
        mean_cos = float(np.mean(np.asarray(samples)))
        assert mean_cos == pytest.approx(g, abs=5e-3)  # <cos> = g for Henyey-Greenstein


def test_lambertian_sampler_and_density():
    with jax.enable_x64(True):
        normal = jnp.asarray(np.tile([0.6, 0.0, 0.8], (N_SAMPLES, 1)))
        directions = lambertian_direction(
            normal, jnp.asarray(uniforms(3)), jnp.asarray(uniforms(4))
        )
        cos_out = np.asarray(jnp.sum(directions * normal, axis=-1))
        np.testing.assert_allclose(np.linalg.norm(np.asarray(directions), axis=-1), 1.0, 1e-12)

        def density(mu):
            return lambertian_density(jnp.asarray(mu))

        assert sphere_integral(density) == pytest.approx(1.0, rel=1e-10)
        assert cos_out.min() >= 0
        assert chi2_pvalue(cos_out, density) > 1e-3
        # the azimuth about the normal is uniform: mean of the in-plane part vanishes
        in_plane = np.asarray(directions) - cos_out[:, None] * np.asarray(normal)
        assert np.abs(in_plane.mean(axis=0)).max() < 5e-3


def test_deflect_and_specular_geometry():
    with jax.enable_x64(True):
        rng = np.random.default_rng(5)
        d = rng.normal(size=(1000, 3))
        d = jnp.asarray(d / np.linalg.norm(d, axis=1, keepdims=True))
        cos_t = jnp.asarray(rng.uniform(-1, 1, 1000))
        out = deflect(d, cos_t, jnp.asarray(rng.uniform(0, 2 * np.pi, 1000)))
        np.testing.assert_allclose(np.linalg.norm(np.asarray(out), axis=1), 1.0, atol=1e-12)
        np.testing.assert_allclose(np.sum(np.asarray(out * d), axis=1), np.asarray(cos_t), 1e-10)
        n = jnp.asarray(np.tile([0.0, 0.0, 1.0], (1000, 1)))
        mirrored = np.asarray(specular_direction(d, n))
        np.testing.assert_allclose(mirrored[:, 2], -np.asarray(d)[:, 2])
        np.testing.assert_allclose(mirrored[:, :2], np.asarray(d)[:, :2])


@pytest.mark.parametrize("anisotropy", [-0.7, 0.0, 0.5, 1.0])
def test_diffuser_emission_sampler(anisotropy):
    with jax.enable_x64(True):
        axis = np.array([0.0, 0.6, 0.8])
        source = DiffuserSource(
            position=[0.0, 0, 0], n_photons=1.0, direction=axis, anisotropy=anisotropy
        )
        directions = sample_directions(source, jnp.asarray(uniforms(6)), jnp.asarray(uniforms(7)))
        cos_axis = np.asarray(directions) @ axis

        def density(mu):
            return (1.0 + anisotropy * mu) / (4 * math.pi)

        assert sphere_integral(density) == pytest.approx(1.0, rel=1e-12)
        assert chi2_pvalue(cos_axis, density) > 1e-3
        # the emission density the direct light uses agrees with the sampler
        np.testing.assert_allclose(
            np.asarray(source.emission_density(directions[:5])), density(cos_axis[:5]), 1e-12
        )


def test_laser_emission_sampler():
    with jax.enable_x64(True):
        axis = np.array([1.0, 0.0, 0.0])
        alpha = 0.3
        source = LaserSource(
            position=[0.0, 0, 0], direction=axis, n_photons=1.0, opening_angle=alpha
        )
        directions = sample_directions(source, jnp.asarray(uniforms(8)), jnp.asarray(uniforms(9)))
        cos_axis = np.asarray(directions) @ axis
        assert cos_axis.min() >= math.cos(alpha) - 1e-12
        # uniform in solid angle: cos theta uniform on [cos alpha, 1]
        assert (
            stats.kstest((cos_axis - math.cos(alpha)) / (1 - math.cos(alpha)), "uniform").pvalue
            > 1e-3
        )
