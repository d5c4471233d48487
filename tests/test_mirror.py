"""First-order specular (mirror) light by quadrature, against independent methods."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from photonflow.geometry import preset_detector
from photonflow.geometry.sensor_arrays import Sensors, sensor_grid_for, sensors_for
from photonflow.params import default_params
from photonflow.response.detection import acceptance_at_cos
from photonflow.sources import IsotropicSource
from photonflow.transport import rays
from photonflow.transport.emission import sample_directions
from photonflow.transport.expected import expected_jit
from photonflow.transport.mirror import FOCUSING_LIMIT, mirror_light, mirror_paths
from photonflow.transport.mirror_cover import _ellipses_covered
from photonflow.transport.mirror_geometry import circle_reflections, focusing_ratio
from photonflow.transport.optics import TransportConfig, specular_direction

pytestmark = pytest.mark.compile_bound

#: ``mirror_paths`` compiled (the shape static): 1.7 s instead of 12.6 s op by op.
jitted_mirror_paths = jax.jit(mirror_paths, static_argnums=0)


def test_circle_reflections_are_the_stationary_points_of_the_path_length():
    """Against a brute-force scan of |a - P| + |P - b| over 400,000 azimuths (float64)."""
    rng = np.random.default_rng(3)
    radius = 1.7
    with jax.enable_x64(True):
        for _ in range(20):
            a = rng.uniform(-1, 1, 2) * radius * 0.7
            b = rng.uniform(-1, 1, 2) * radius * 0.7
            psi, found = circle_reflections(
                (jnp.array([a[0]]), jnp.array([a[1]])), (jnp.array([b[0]]), jnp.array([b[1]])),
                radius,
            )
            roots = np.sort(np.mod(np.asarray(psi)[0][np.asarray(found)[0]], 2 * np.pi))
            grid = np.linspace(0, 2 * np.pi, 400_001)
            wall = radius * np.stack([np.cos(grid), np.sin(grid)], 1)
            length = np.linalg.norm(wall - a, axis=1) + np.linalg.norm(wall - b, axis=1)
            step = np.diff(length)
            brute = grid[1:-1][np.sign(step[:-1]) != np.sign(step[1:])]
            assert len(roots) == len(brute)
            np.testing.assert_allclose(roots, brute, atol=2e-5)


def test_ellipse_under_discs_matches_a_dense_point_count():
    """The covered fraction of wall patches (ellipses) under two discs against 200,000
    points spread uniformly over each ellipse (float64): within 0.01 each, 0.003 on
    average, for ellipses from small to twice the discs' size, at any orientation."""
    rng = np.random.default_rng(11)
    centres = np.array([[0.0, 0.0, 0.0], [2.05, 0.3, 0.0]])
    radius = np.array([1.0, 0.8])
    n_ellipses = 40
    middle = np.column_stack([rng.uniform(-1.5, 3.2, n_ellipses),
                              rng.uniform(-1.4, 1.6, n_ellipses), np.zeros(n_ellipses)])
    spans = np.zeros((n_ellipses, 2, 3))
    spans[:, :, :2] = rng.normal(0.0, 0.6, (n_ellipses, 2, 2))
    with jax.enable_x64(True):
        discs = (
            jnp.ones((n_ellipses, 2), bool),
            tuple(jnp.broadcast_to(jnp.asarray(centres[:, k]), (n_ellipses, 2)) for k in range(3)),
            tuple(jnp.broadcast_to(jnp.asarray(v), (n_ellipses, 2)) for v in (0.0, 0.0, 1.0)),
            jnp.broadcast_to(jnp.asarray(radius), (n_ellipses, 2)),
        )
        fraction = np.asarray(_ellipses_covered(discs, jnp.asarray(middle), jnp.asarray(spans)))
    count = 200_000
    r = np.sqrt(rng.uniform(size=count))
    phi = rng.uniform(0, 2 * np.pi, count)
    unit = np.column_stack([r * np.cos(phi), r * np.sin(phi)])
    reference = []
    for m, s in zip(middle, spans, strict=True):
        points = m + unit @ s
        inside = np.zeros(count, bool)
        for c, rad in zip(centres, radius, strict=True):
            inside |= np.sum((points - c) ** 2, axis=1) < rad**2
        reference.append(inside.mean())
    error = np.abs(fraction - np.array(reference))
    assert 0.1 < np.mean(reference) < 0.9
    assert error.max() < 0.01, error.max()
    assert error.mean() < 0.003, error.mean()


def _landing(shape, source, alpha, tau, plane_point, plane_normal):
    """Where the ray (azimuth alpha, slope tau) from ``source`` lands on a plane after one
    specular reflection off the wall (numpy, float64)."""
    d = np.array([np.cos(alpha), np.sin(alpha), tau])
    d = d / np.linalg.norm(d)
    t = float(shape.ray_exit(jnp.asarray(source)[None], jnp.asarray(d)[None])[0])
    wall = source + t * d
    normal = np.asarray(shape.inward_normal(jnp.asarray(wall)[None]))[0]
    out = d - 2 * (d @ normal) * normal
    s = ((plane_point - wall) @ plane_normal) / (out @ plane_normal)
    return wall + s * out, wall, out


@pytest.mark.parametrize("name", ["TOY_CYLINDER", "TOY_SPHERE"])
def test_focusing_ratio_is_the_ray_tube_jacobian(name):
    """The ray-tube area per steradian, focusing x L^2, against finite differences of the
    landing point of reflected rays (float64): the curved-mirror equations are exact."""
    shape = preset_detector(name).shape
    source = np.array([0.4, -0.3, 0.5])
    rng = np.random.default_rng(5)
    with jax.enable_x64(True):
        for _ in range(6):
            alpha, tau = rng.uniform(0, 2 * np.pi), rng.uniform(-0.4, 0.4)
            plane_normal = np.array([0.3, -0.2, 0.9])
            plane_normal /= np.linalg.norm(plane_normal)
            x0, wall, out = _landing(shape, source, alpha, tau, source, plane_normal)
            x0, wall, out = _landing(shape, source, alpha, tau, wall + 1.3 * out, out)
            e = 1e-6
            xa = _landing(shape, source, alpha + e, tau, x0, out)[0]
            xt = _landing(shape, source, alpha, tau + e, x0, out)[0]
            cross = np.cross((xa - x0) / e, (xt - x0) / e)
            # solid angle of the (alpha, tau) cell: dalpha dtau / (1 + tau^2)^1.5
            area_per_sr = np.linalg.norm(cross) * (1 + tau * tau) ** 1.5
            length = np.linalg.norm(wall - source) + np.linalg.norm(x0 - wall)
            ratio = float(
                focusing_ratio(shape, jnp.asarray(source), jnp.asarray(wall), jnp.asarray(x0))
            )
            np.testing.assert_allclose(ratio * length**2, area_per_sr, rtol=1e-5)


def _ray_estimate(detector, params, source, n_rays, key):
    """First-order mirror light by photon rays (float64): emitted, traced to the wall,
    mirrored where no sensor covers it, traced again; paths focused below
    ``FOCUSING_LIMIT`` are left out, as ``mirror_light`` leaves them to the rays."""
    dtype = jnp.float64
    positions = jnp.asarray(detector.sensor_positions, dtype)
    normals = jnp.asarray(detector.sensor_normals, dtype)
    sensors = Sensors(positions, normals, jnp.asarray(detector.sensor_radius, dtype),
                      grid=sensor_grid_for(detector))
    trace = functools.partial(rays.trace, detector.shape, sensors)
    u = jax.random.uniform(key, (2, n_rays), dtype=dtype)
    directions = sample_directions(source, u[0], u[1])
    origins = jnp.broadcast_to(source.position, (n_rays, 3))
    t_first, _, on_sensor, alive = trace(origins, directions)
    wall = origins + t_first[:, None] * directions
    out = specular_direction(directions, detector.shape.inward_normal(wall))
    t_second, index, hit, alive_second = trace(wall, out)
    landing = wall + t_second[:, None] * out
    kept = focusing_ratio(detector.shape, source.position, wall, landing) >= FOCUSING_LIMIT
    counts = alive & ~on_sensor & alive_second & hit & kept
    cos_in = -jnp.sum(out * normals[index], axis=-1)
    light = (
        source.n_photons / n_rays * params.wall_reflectivity * params.wall_specular_fraction
        * jnp.exp(-(t_first + t_second) / params.absorption_length)
        * params.quantum_efficiency
        * acceptance_at_cos(params.angular_acceptance, cos_in)
    )
    return jnp.zeros(detector.n_sensors, dtype).at[index].add(jnp.where(counts, light, 0.0))


@pytest.mark.parametrize("name", ["TOY_CYLINDER", "TOY_SPHERE"])
def test_mirror_light_agrees_with_mirrored_rays(name):
    """Quadrature against 4 x 2^20 mirrored photon rays: the total within 4 sigma and 1 %,
    and every tenth of the sensors (ordered by height) within 5 sigma."""
    detector = preset_detector(name)
    with jax.enable_x64(True):
        params = default_params(detector).replace(
            scattering_length=jnp.inf, wall_reflectivity=0.3, wall_specular_fraction=0.8
        )
        source = IsotropicSource(position=[0.3, -0.2, 0.5], n_photons=1e6)
        source = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), source)
        paths = jitted_mirror_paths(detector.shape, sensors_for(detector, jnp.float64), source)
        quad = np.asarray(
            jax.jit(mirror_light)(params, paths, source, jnp.zeros(detector.n_sensors))[0]
        )
        estimate = jax.jit(lambda key: _ray_estimate(detector, params, source, 1 << 20, key))
        rays = np.stack([np.asarray(estimate(jax.random.key(k))) for k in range(4)])
    mean = rays.mean(axis=0)
    error = rays.std(axis=0, ddof=1) / 2.0
    total_error = np.sqrt(np.sum(error**2))
    assert quad.sum() > 0.05 * mean.sum() > 0
    assert abs(quad.sum() - mean.sum()) < max(4 * total_error, 0.0) + 0.01 * mean.sum()
    order = np.argsort(np.asarray(detector.sensor_positions)[:, 2], kind="stable")
    for group in np.array_split(order, 10):
        band_error = np.sqrt(np.sum(error[group] ** 2))
        if mean[group].sum() > 0:
            assert abs(quad[group].sum() - mean[group].sum()) < 5 * band_error + 1e-3 * mean.sum()


def test_mirror_paths_computed_once_give_the_same_prediction():
    """The expected mode with a source's mirror paths passed in (a calibration run computes
    them once) equals the one that computes them itself, in value and in the derivative
    along the wall reflectivity, the absorption length and one efficiency together
    (float64, so that only rounding can differ); and the paths carry light."""
    detector = preset_detector("TOY_CYLINDER")
    with jax.enable_x64(True):
        params = default_params(detector).replace(
            wall_reflectivity=0.3, wall_specular_fraction=0.8)
        source = IsotropicSource(position=[0.3, -0.2, 0.5], n_photons=1e6)
        source = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), source)
        sensors = sensors_for(detector, jnp.float64)
        config = TransportConfig(n_bounces=1, n_rays=64)
        paths = jitted_mirror_paths(detector.shape, sensors, source)
        assert float(jnp.sum(paths.weight)) > 0

        def charge(values, mirror):
            wall, absorption, efficiency = values
            changed = params.replace(wall_reflectivity=wall, absorption_length=absorption,
                                     efficiency=params.efficiency.at[3].set(efficiency))
            return expected_jit(sensors, changed, source, jax.random.key(2), mirror,
                                shape=detector.shape, config=config).charge

        at = tuple(jnp.float64(v) for v in (0.3, float(params.absorption_length), 1.0))
        along = tuple(jnp.float64(v) for v in (1.0, -50.0, 0.5))
        inside, inside_slope = jax.jvp(lambda v: charge(v, None), (at,), (along,))
        given, given_slope = jax.jvp(lambda v: charge(v, paths), (at,), (along,))
        inside, inside_slope, given, given_slope = (
            np.asarray(x) for x in (inside, inside_slope, given, given_slope))
    assert np.sum(np.abs(inside_slope)) > 0
    np.testing.assert_allclose(given, inside, rtol=1e-9)
    np.testing.assert_allclose(given_slope, inside_slope, rtol=1e-9,
                               atol=1e-12 * np.max(np.abs(inside_slope)))
