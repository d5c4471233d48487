"""The specular probes' widened discs (``specular_probes.specular_probes`` with
``smoothing`` > 1): the same mirrored light, with less noise, and no disc widened across
the edge of its wall face (``sensor_arrays.face_reach_for``)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from photonflow.errors import ConfigError
from photonflow.geometry import preset_detector
from photonflow.geometry.sensor_arrays import (
    FACE_TOLERANCE,
    WIDEST_DISC,
    Sensors,
    face_reach_for,
    sensors_for,
)
from photonflow.params import default_params
from photonflow.transport.expected import expected_function
from photonflow.transport.optics import TransportConfig
from photonflow.transport.rays import Probes
from photonflow.transport.specular_probes import specular_probes

KEYS = 32
PROBES = 8192


def test_face_reach_stops_at_the_rim_of_a_cylinder():
    """A barrel disc's widened disc ends before the cap (room H/2 - |z|), a cap disc's
    before the barrel (room R - rho), up to the rim test's tolerance and its 0.25-radius
    steps; with room to spare every disc gets the full WIDEST_DISC."""
    detector = preset_detector("SK")
    shape = detector.shape
    positions = np.asarray(detector.sensor_positions)
    radius = np.asarray(detector.sensor_radius) * np.ones(len(positions))
    rho = np.hypot(positions[:, 0], positions[:, 1])
    on_barrel = np.abs(np.asarray(detector.sensor_normals)[:, 2]) < 0.5
    room = np.where(on_barrel, shape.height / 2 - np.abs(positions[:, 2]), shape.radius - rho)
    reach = face_reach_for(detector)
    widest = WIDEST_DISC
    step = (widest - 1.0) / 8
    # the 16 rim points reach at least cos(pi / 16) of the disc's extent toward the rim
    assert np.all(reach * radius * math.cos(math.pi / 16) <= room + FACE_TOLERANCE + 1e-9)
    roomy = room > widest * radius + FACE_TOLERANCE
    assert np.all(reach[roomy] == widest)
    tight = ~roomy & (room > radius)
    assert tight.sum() > 100  # SK's top and bottom rows and its caps' outer rings
    assert np.all(reach[tight] * radius[tight] >= room[tight] - (step + 0.05) * radius[tight])


def _mirrored_light(smoothing, keys=KEYS, bare=False, name="TOY_CYLINDER"):
    """Light of order-1 probes (random vertices in the detector ``name``, isotropic
    directions, 1 / PROBES photons each) mirrored into each sensor, (keys, N); ``bare``:
    sensors without lookup grids (every disc tested)."""
    detector = preset_detector(name)
    shape = detector.shape
    sensors = sensors_for(detector)
    if bare:
        sensors = Sensors(sensors.positions, sensors.normals, sensors.radius)
    params = default_params(detector)
    reference = jnp.zeros(sensors.n)

    @jax.jit
    def light(key):
        k_rho, k_phi, k_z, k_dir = jax.random.split(key, 4)
        rho = 0.9 * shape.radius * jnp.sqrt(jax.random.uniform(k_rho, (PROBES,)))
        phi = 2 * math.pi * jax.random.uniform(k_phi, (PROBES,))
        z = 0.45 * shape.height * jax.random.uniform(k_z, (PROBES,), minval=-1, maxval=1)
        directions = jax.random.normal(k_dir, (PROBES, 3))
        probes = Probes(
            origins=jnp.stack([rho * jnp.cos(phi), rho * jnp.sin(phi), z], axis=-1),
            directions=directions / jnp.linalg.norm(directions, axis=-1, keepdims=True),
            weight=jnp.full(PROBES, 1.0 / PROBES),
            time=jnp.zeros(PROBES),
            order=jnp.ones(PROBES, jnp.int32),
        )
        charge, _, _ = specular_probes(params, shape, sensors, reference, probes, 2, True,
                                       smoothing)
        return charge[1]

    return np.stack([np.asarray(light(jax.random.key(k))) for k in range(keys)])


def test_widened_discs_keep_the_mirrored_light_and_cut_its_noise():
    """The same probes counted on the physical discs and on discs widened 3.5x: the mean
    light agrees (in total and in each tenth of the sensors by height, paired differences
    within 4 standard errors + 1 %), and the per-sensor variance over keys falls by more than 3x
    (~12x for sparse hits)."""
    disc = _mirrored_light(1.0)
    wide = _mirrored_light(WIDEST_DISC)
    assert disc.sum(axis=1).mean() > 0
    difference = wide - disc
    total = difference.sum(axis=1)
    light = disc.sum(axis=1).mean()
    assert abs(total.mean()) < 4 * total.std(ddof=1) / math.sqrt(KEYS) + 0.005 * light
    # groups by height (not by the noisy light itself, whose low fluctuations would
    # regress upward in the difference)
    heights = np.asarray(preset_detector("TOY_CYLINDER").sensor_positions)[:, 2]
    for group in np.array_split(np.argsort(heights, kind="stable"), 10):
        share = difference[:, group].sum(axis=1)
        error = share.std(ddof=1) / math.sqrt(KEYS)
        assert abs(share.mean()) < 4 * error + 0.01 * disc[:, group].sum(axis=1).mean()
    assert wide.var(axis=0, ddof=1).sum() < disc.var(axis=0, ddof=1).sum() / 3


def test_a_disc_wider_than_the_near_grid_reaches_is_a_config_error():
    """Discs are looked up within NEAR_RADII radii of the mirrored ray's wall point: a
    wider widening would lose light silently, so it is refused with one line naming
    the field."""
    detector = preset_detector("TOY_CYLINDER")
    for value in (0.5, WIDEST_DISC + 0.5):
        with pytest.raises(ConfigError, match=r"^config\.specular_smoothing = .*between 1"):
            expected_function(detector, config=TransportConfig(specular_smoothing=value))


def test_the_grid_lookup_finds_every_disc_a_mirrored_ray_crosses():
    """On the physical discs, candidates from the near grid around the wall point give
    the light of testing every disc."""
    grid = _mirrored_light(1.0, keys=2)
    every = _mirrored_light(1.0, keys=2, bare=True)
    assert grid.sum() > 0
    np.testing.assert_allclose(grid, every, rtol=1e-5, atol=1e-12)


def test_discs_in_front_of_the_wall_are_found_where_the_ray_crosses_their_layer():
    """IWCD's mPMTs stand 0.19-0.25 m in front of the wall (``Sensors.standoff``): looked
    up around the wall point alone, a mirrored ray crossing a disc at 40 degrees or more
    from the wall's normal was missed (the expected light of a 1 GeV muon fell 3.2 %
    short of the sampled mode's, and the grid found 30 % of the light of testing every
    disc); looked up where the ray crosses the sensors' layer, the grid finds more than
    95 % of it (96 %: rays grazing the wall cross the layer along a long stretch)."""
    grid = _mirrored_light(1.0, keys=1, name="IWCD").sum()
    every = _mirrored_light(1.0, keys=1, bare=True, name="IWCD").sum()
    assert every > 0
    assert 0.95 * every < grid <= every * (1 + 1e-5)
