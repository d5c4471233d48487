"""Ray-sensor-disc intersections: hand cases, hypothesis rays, no misses in float32."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from photonflow.geometry import detector_ray_hits, disc_hit_distance, preset_detector


def _disc(radius=0.25):
    return jnp.array([0.0, 0.0, 10.0]), jnp.array([0.0, 0.0, -1.0]), jnp.asarray(radius)


def test_head_on_hit_distance():
    centre, normal, radius = _disc()
    t = disc_hit_distance(jnp.zeros(3), jnp.array([0.0, 0.0, 1.0]), centre, normal, radius)
    assert float(t) == pytest.approx(10.0)


@pytest.mark.parametrize(("offset", "hit"), [(0.99, True), (1.01, False)])
def test_edge_of_disc(offset, hit):
    centre, normal, radius = _disc(0.25)
    origin = jnp.array([0.25 * offset, 0.0, 0.0])
    t = disc_hit_distance(origin, jnp.array([0.0, 0.0, 1.0]), centre, normal, radius)
    assert bool(jnp.isfinite(t)) is hit


def test_back_face_and_behind_origin_do_not_hit():
    centre, normal, radius = _disc()
    # Travelling along the normal: hits the back of the sensor.
    assert (
        float(
            disc_hit_distance(
                jnp.array([0, 0, 20.0]), jnp.array([0, 0, -1.0]), centre, normal, radius
            )
        )
        == math.inf
    )
    # Disc behind the origin.
    assert (
        float(
            disc_hit_distance(
                jnp.array([0, 0, 11.0]), jnp.array([0, 0, 1.0]), centre, normal, radius
            )
        )
        == math.inf
    )


def test_oblique_hit_hand_computed():
    """Ray at 45 degrees from (-10, 0, 0) reaches the plane z = 10 at x = 0: t = 10 sqrt 2."""
    centre, normal, radius = _disc()
    direction = jnp.array([1.0, 0.0, 1.0]) / math.sqrt(2)
    t = disc_hit_distance(jnp.array([-10.0, 0.0, 0.0]), direction, centre, normal, radius)
    assert float(t) == pytest.approx(10 * math.sqrt(2), rel=1e-6)


@given(
    r=st.floats(0.0, 0.98),
    phi=st.floats(0, 2 * math.pi),
    theta=st.floats(0, 1.4),
    azimuth=st.floats(0, 2 * math.pi),
    distance=st.floats(0.5, 60),
)
def test_rays_aimed_inside_disc_hit_at_their_distance(r, phi, theta, azimuth, distance):
    """A ray aimed at any point of the disc from the front hits at exactly that distance."""
    with jax.enable_x64(True):
        centre, normal, radius = (jnp.asarray(a, jnp.float64) for a in _disc(0.254))
        target = centre + 0.254 * r * jnp.array([math.cos(phi), math.sin(phi), 0.0])
        direction = jnp.array(
            [
                math.sin(theta) * math.cos(azimuth),
                math.sin(theta) * math.sin(azimuth),
                math.cos(theta),
            ]
        )
        origin = target - distance * direction
        t = disc_hit_distance(origin, direction, centre, normal, radius)
        assert float(t) == pytest.approx(distance, rel=1e-9)


def _far_side_rays(detector, rng, n, aim_fraction):
    """Rays from the opposite side of the detector aimed at points of sensor discs."""
    index = rng.choice(detector.n_sensors, size=n, replace=False)
    centres = detector.sensor_positions[index]
    normals = detector.sensor_normals[index]
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, [[0, 0, 1.0]], [[1.0, 0, 0]])
    e1 = np.cross(normals, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(normals, e1)
    phi = rng.uniform(0, 2 * np.pi, n)
    radius = detector.sensor_radius[index][:, None] * aim_fraction
    targets = centres + radius * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    if detector.shape.has_walls:
        origins = -0.97 * centres  # mirror point: the far side of the tank
        origins[:, 2] = -0.97 * centres[:, 2]
    else:
        # From 300 m below and 300 m aside (45 degrees), so that the ray does not pass
        # through the sensors hung below the target on the same string.
        azimuth = rng.uniform(0, 2 * np.pi, n)
        aside = np.stack([np.cos(azimuth), np.sin(azimuth), np.zeros(n)], axis=1)
        origins = targets + 300.0 * normals + 300.0 * aside
    directions = targets - origins
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return index, origins, directions


@pytest.mark.parametrize("name", ["HK", "SK", "JUNO", "ICECUBE_MINI"])
@pytest.mark.parametrize("aim_fraction", [0.0, 0.95])
def test_far_side_rays_never_miss_in_float32(name, aim_fraction):
    """Rays across the largest presets (HK: 65 m; ICECUBE_MINI: 400 m lever arm) aimed
    at a sensor centre, or 95 % of its radius off-centre, hit that sensor in float32."""
    detector = preset_detector(name)
    rng = np.random.default_rng(11)
    index, origins, directions = _far_side_rays(detector, rng, 400, aim_fraction)
    hit, distance = detector_ray_hits(
        detector, jnp.asarray(origins, jnp.float32), jnp.asarray(directions, jnp.float32)
    )
    assert distance.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(hit), index)
    expected = (
        np.linalg.norm(detector.sensor_positions[index] - origins, axis=1)
        if aim_fraction == 0
        else None
    )
    if expected is not None:
        np.testing.assert_allclose(np.asarray(distance), expected, rtol=1e-5)


def test_nearest_of_two_discs_wins_and_miss_is_minus_one():
    detector = preset_detector("TOY_CYLINDER")
    centre = detector.sensor_positions[0]
    inward = detector.sensor_normals[0]
    origins = jnp.asarray([centre + 1.0 * inward, [0.0, 0.0, 0.0]], jnp.float32)
    directions = jnp.asarray([-inward, [0.0, 0.0, 0.0]], jnp.float32)
    # Second ray has zero direction: it cannot hit anything.
    hit, distance = detector_ray_hits(detector, origins, directions)
    assert int(hit[0]) == 0 and float(distance[0]) == pytest.approx(1.0, rel=1e-6)
    assert int(hit[1]) == -1 and float(distance[1]) == math.inf
