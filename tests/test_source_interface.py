"""Sources by method (issue 23 item 4): the transport asks a source only for its axis,
inverse CDF, angular density and disc fractions, so a new source class plugs into both
modes without a change to the transport."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import photonflow as pf
from photonflow.pytree import pytree_dataclass
from photonflow.sources import DiffuserSource, IsotropicSource, LaserSource, PointSource
from photonflow.transport.emission import sample_directions

pytestmark = pytest.mark.compile_bound


@pytree_dataclass
class Hemisphere:
    """A source of this test only: uniform over the hemisphere about ``direction``, its
    disc fractions borrowed from a laser of opening angle pi / 2 (the same density)."""

    position: jax.Array
    direction: jax.Array
    n_photons: jax.Array
    time: jax.Array
    pulse_width: jax.Array

    def _laser(self):
        return LaserSource(position=self.position, direction=self.direction,
                           n_photons=self.n_photons, opening_angle=jnp.float32(math.pi / 2),
                           time=self.time, pulse_width=self.pulse_width)

    def axis(self, dtype=None):
        direction = jnp.asarray(self.direction, dtype)
        return direction / jnp.sqrt(jnp.sum(direction * direction))

    def sample_cos(self, u):
        return 1.0 - jnp.asarray(u)  # cos theta uniform in (0, 1]

    def emission_density(self, unit_directions):
        inside = jnp.sum(jnp.asarray(unit_directions) * self.axis(), axis=-1) >= 0
        return jnp.where(inside, 1.0 / (2.0 * math.pi), 0.0)

    def disc_fraction(self, centre, normal, radius):
        return self._laser().disc_fraction(centre, normal, radius)


def _hemisphere():
    return Hemisphere(position=jnp.array([0.2, -0.1, 0.3]), direction=jnp.array([0.0, 0.6, 0.8]),
                      n_photons=jnp.float32(1e5), time=jnp.float32(0.0),
                      pulse_width=jnp.float32(0.0))


def test_the_calibration_sources_are_point_sources():
    sources = [
        IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=1.0),
        LaserSource(position=[0.0, 0.0, 0.0], direction=[0.0, 0.0, 1.0], n_photons=1.0,
                    opening_angle=0.1),
        DiffuserSource(position=[0.0, 0.0, 0.0], direction=[1.0, 0.0, 0.0], n_photons=1.0,
                       anisotropy=0.5),
    ]
    assert all(isinstance(source, PointSource) for source in sources)
    assert not isinstance(object(), PointSource)


def test_a_new_source_class_samples_its_own_density():
    """Directions drawn through the interface follow the new source's density: all in the
    hemisphere, cos theta uniform (mean 1/2, variance 1/12 within 5 sigma)."""
    source = _hemisphere()
    u = jax.random.uniform(jax.random.key(0), (2, 100_000))
    cos_theta = np.asarray(sample_directions(source, u[0], u[1]) @ source.axis())
    assert cos_theta.min() >= -1e-6
    n = cos_theta.size
    assert abs(cos_theta.mean() - 0.5) < 5 * math.sqrt(1 / 12 / n)
    assert abs(cos_theta.var() - 1 / 12) < 5 * math.sqrt(1 / 180 / n)


def test_a_new_source_class_plugs_into_both_modes():
    """The expected mode of the new class equals that of the laser with the same density
    (charge and times), and its sampled events agree with that expectation (chi2 per
    degree of freedom of the total charge per sensor over a few events)."""
    detector = pf.load_detector("TOY_SPHERE")
    params = pf.default_params(detector)
    source = _hemisphere()
    new = pf.expected(detector, params, source)
    laser = pf.expected(detector, params, source._laser())
    np.testing.assert_allclose(new.charge, laser.charge, rtol=2e-3, atol=1e-3)
    np.testing.assert_allclose(new.time_mean, laser.time_mean, atol=0.05)
    events = list(pf.sample_events(detector, params, source, seed=5, n_events=4))
    observed = np.zeros(detector.n_sensors)
    for event in events:
        observed[event.sensor_ids] += event.charge
    assert observed.sum() > 0
    total = 4 * np.asarray(new.charge, np.float64)
    # within 3 % in total (dark noise and the single-p.e. mean are second order here)
    assert abs(observed.sum() / total.sum() - 1) < 0.03
