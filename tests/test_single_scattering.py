"""Single scattering of the expected mode against an independent volume integral.

Light scattered exactly once, from an isotropic source of N photons at s to sensor j
(QE q, efficiency e_j, acceptance A, total attenuation rate mu, Rayleigh rate mu_R and
phase function p), integrated from the sensor's side:

    Q_j = N q e_j mu_R int_disc dA int_{cos > 0} dw cos A(cos)
          int_0^T(y, w) dt exp(-mu t) p(turn) exp(-mu R) / (4 pi R^2),

y a point on the disc, w a direction into the detector, x = y + t w the scattering
point, R = |x - s| and turn the angle between (x - s) and -w. Every point of the disc
and its own incidence angle are integrated, so this checks the expected mode's rays and
next-event estimate (the vertex proposal, the disc solid angle near and far, the
acceptance taken at the disc centre) by a different route: Monte Carlo over (y, w, t)
with y uniform on the disc, w cosine-weighted and t uniform on [0, T].
"""

import math

import jax
import numpy as np

import photonflow as pf
from photonflow.sources import IsotropicSource
from photonflow.transport.indirect import indirect_light
from photonflow.transport.optics import TransportConfig

PHOTONS = 1e6
SAMPLES = 200_000  # per sensor
KEYS = 8
CONFIG = TransportConfig(n_bounces=1, n_rays=1 << 14)


def _exit_distance(origin, direction, radius, half_height):
    """Distance (m) from points inside a cylinder along unit directions to its wall."""
    a = direction[:, 0] ** 2 + direction[:, 1] ** 2
    b = origin[:, 0] * direction[:, 0] + origin[:, 1] * direction[:, 1]
    c = origin[:, 0] ** 2 + origin[:, 1] ** 2 - radius**2
    safe_a = np.maximum(a, 1e-12)
    side = np.where(a > 1e-12, (-b + np.sqrt(np.maximum(b * b - a * c, 0.0))) / safe_a, np.inf)
    up = direction[:, 2] > 0
    height = np.where(up, half_height - origin[:, 2], -half_height - origin[:, 2])
    safe_z = np.where(direction[:, 2] == 0, 1.0, direction[:, 2])
    cap = np.where(direction[:, 2] == 0, np.inf, height / safe_z)
    return np.maximum(np.minimum(side, cap), 0.0)


def _adjoint_single_scatter(detector, params, anisotropy, source, sensor, rng):
    """(Q_j p.e., its Monte Carlo error) of the module docstring's integral."""
    centre = np.asarray(detector.sensor_positions, np.float64)[sensor]
    normal = np.asarray(detector.sensor_normals, np.float64)[sensor]
    radius = float(np.asarray(detector.sensor_radius)[sensor])
    helper = np.array([0.0, 0.0, 1.0]) if abs(normal[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(normal, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    u = rng.random((5, SAMPLES))
    rho, phi = radius * np.sqrt(u[0]), 2 * math.pi * u[1]
    y = centre + (rho * np.cos(phi))[:, None] * e1 + (rho * np.sin(phi))[:, None] * e2
    cos_w, azimuth = np.sqrt(u[2]), 2 * math.pi * u[3]
    sin_w = np.sqrt(1.0 - u[2])
    w = (cos_w[:, None] * normal + (sin_w * np.cos(azimuth))[:, None] * e1
         + (sin_w * np.sin(azimuth))[:, None] * e2)
    reach = _exit_distance(y + 1e-9 * w, w, detector.shape.radius, 0.5 * detector.shape.height)
    t = u[4] * reach
    x = y + t[:, None] * w
    from_source = x - np.asarray(source.position, np.float64)
    r = np.linalg.norm(from_source, axis=1)
    cos_turn = -np.sum(from_source * w, axis=1) / r
    phase = (1 + anisotropy * cos_turn**2) / (4 * math.pi * (1 + anisotropy / 3))
    table = np.asarray(params.angular_acceptance, np.float64)
    node_cos = np.cos(np.radians(10.0 * np.arange(10)))
    acceptance = np.interp(cos_w, node_cos[::-1], table[::-1])
    rate = 1 / float(params.absorption_length) + 1 / float(params.scattering_length)
    # pdfs: 1 / (pi r^2) on the disc, cos / pi over w, 1 / T along t
    values = (math.pi * radius**2 * math.pi * acceptance * reach * np.exp(-rate * t) * phase
              * np.exp(-rate * r) / (4 * math.pi * r**2))
    scale = (source.n_photons * float(params.quantum_efficiency)
             * float(params.efficiency[sensor]) / float(params.scattering_length))
    return scale * values.mean(), scale * values.std() / math.sqrt(SAMPLES)


def test_single_scattering_matches_an_adjoint_volume_integral():
    """On the toy cylinder (walls and glass black, one vertex), per band of sensors by
    height, within 4 sigma of both estimates' errors plus 1 %, and in total within
    4 sigma plus 0.5 %."""
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector).replace(
        absorption_length=25.0, scattering_length=8.0, wall_reflectivity=0.0,
        sensor_reflectivity=0.0)
    source = IsotropicSource(position=[0.4, -0.3, 0.7], n_photons=PHOTONS)
    charges = np.stack([
        np.asarray(indirect_light(detector, params, source, config=CONFIG,
                                  key=jax.random.key(40 + k)).charge[0], np.float64)
        for k in range(KEYS)
    ])
    rng = np.random.default_rng(7)
    integral = np.array([
        _adjoint_single_scatter(detector, params, CONFIG.rayleigh_anisotropy, source, j, rng)
        for j in range(detector.n_sensors)
    ])
    order = np.argsort(np.asarray(detector.sensor_positions)[:, 2], kind="stable")
    for band in [*np.array_split(order, 8), order]:
        rays = charges[:, band].sum(axis=1)
        expected, ray_error = rays.mean(), rays.std(ddof=1) / math.sqrt(KEYS)
        value = integral[band, 0].sum()
        error = math.hypot(ray_error, math.sqrt(np.sum(integral[band, 1] ** 2)))
        tolerance = 0.005 if band is order else 0.01
        assert value > 0
        assert abs(expected - value) < 4 * error + tolerance * value, (expected, value, error)


def test_the_indirect_light_splits_by_the_kind_of_its_last_vertex():
    """``IndirectLight.kind_*``: with black walls and glass all one-vertex light was last
    scattered in the bulk; with no scattering (a 10^9 m length) and reflecting walls none
    was; and with both, the two parts add up to the order's light and its mean time."""
    detector = pf.load_detector("TOY_CYLINDER")
    base = pf.default_params(detector)
    source = IsotropicSource(position=[0.4, -0.3, 0.7], n_photons=PHOTONS)

    def light(**changes):
        result = indirect_light(detector, base.replace(**changes), source, config=CONFIG,
                                key=jax.random.key(3))
        return jax.tree.map(lambda x: np.asarray(x, np.float64), result)

    def assert_all_in(part, other, result):
        np.testing.assert_allclose(result.kind_charge[part, 0], result.charge[0], rtol=1e-4)
        assert np.all(result.kind_charge[other, 0] <= 1e-6 * result.charge[0])
        lit = result.charge[0] > 1e-3 * result.charge[0].max()
        np.testing.assert_allclose(result.kind_time_mean[part, 0][lit],
                                   result.time_mean[0][lit], atol=1e-3)

    assert_all_in(0, 1, light(scattering_length=8.0, wall_reflectivity=0.0,
                              sensor_reflectivity=0.0))
    assert_all_in(1, 0, light(scattering_length=1e9, mie_length=1e9, wall_reflectivity=0.3))
    both = light(scattering_length=8.0, wall_reflectivity=0.3)
    shares = both.kind_charge[:, 0] / both.charge[0]
    assert np.all(shares.min(axis=0) > 0.01)  # both kinds light every sensor here
    np.testing.assert_allclose(shares.sum(axis=0), 1.0, rtol=1e-4)
    np.testing.assert_allclose(np.sum(both.kind_charge[:, 0] * both.kind_time_mean[:, 0], 0),
                               both.charge[0] * both.time_mean[0], rtol=1e-4)
