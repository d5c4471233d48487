"""Direct light by quadrature: solid angles, the analytic sphere rung, times, gradients."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

from photonflow.errors import ConfigError
from photonflow.geometry import preset_detector
from photonflow.params import default_params
from photonflow.pytree import replace
from photonflow.sources import DiffuserSource, IsotropicSource, LaserSource, check_source
from photonflow.transport import SPEED_OF_LIGHT, direct_light, direct_light_jit, disc_solid_angle

pytestmark = pytest.mark.compile_bound

# ---- references independent of the implementation ------------------------------------


def on_axis_solid_angle(height, radius):
    """2 pi (1 - h / sqrt(h^2 + r^2)), sr."""
    return 2 * math.pi * (1 - height / math.hypot(height, radius))


def reference_solid_angle(point, centre, normal, radius):
    """Omega by adaptive quadrature over the azimuth phi about the foot of the perpendicular:
    integral of h / sqrt(h^2 + rho_near^2) - h / sqrt(h^2 + rho_far^2) dphi (numpy/scipy)."""
    point, centre, normal = (np.asarray(x, dtype=np.float64) for x in (point, centre, normal))
    q = point - centre
    h = abs(q @ normal)
    offset = np.linalg.norm(q - (q @ normal) * normal)  # foot of perpendicular to centre, m

    def g(rho):
        return h / math.sqrt(h * h + rho * rho)

    if offset < radius:
        # phi from the direction foot -> centre; chord from the foot to the rim
        def far(phi):
            return offset * math.cos(phi) + math.sqrt(radius**2 - (offset * math.sin(phi)) ** 2)

        value, _ = integrate.quad(lambda phi: 1 - g(far(phi)), 0, 2 * math.pi, epsabs=1e-13)
        return value

    # substitution sin(phi) = (r / s) sin(psi) removes the square-root end points
    def integrand(psi):
        phi = math.asin(radius / offset * math.sin(psi))
        half = radius * math.cos(psi)
        near, far = offset * math.cos(phi) - half, offset * math.cos(phi) + half
        jacobian = radius * math.cos(psi) / (offset * math.cos(phi))
        return (g(near) - g(far)) * jacobian

    value, _ = integrate.quad(integrand, -math.pi / 2, math.pi / 2, epsabs=1e-13)
    return value


def monte_carlo_solid_angle(point, centre, normal, radius, n, rng):
    """Omega and its standard error: uniform directions in the cone around the disc, hits."""
    point, centre, normal = (np.asarray(x, dtype=np.float64) for x in (point, centre, normal))
    to_centre = centre - point
    distance = np.linalg.norm(to_centre)
    axis = to_centre / distance
    cos_max = math.sqrt(1 - (radius / distance) ** 2)  # the disc lies inside this cone
    cos_t = 1 - rng.random(n) * (1 - cos_max)
    phi = rng.random(n) * 2 * math.pi
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    sin_t = np.sqrt(1 - cos_t**2)
    dirs = (
        cos_t[:, None] * axis
        + (sin_t * np.cos(phi))[:, None] * u
        + (sin_t * np.sin(phi))[:, None] * v
    )
    t = (to_centre @ normal) / (dirs @ normal)
    miss = t[:, None] * dirs - to_centre
    hit = (t > 0) & (np.sum(miss * miss, axis=1) <= radius**2)
    cone = 2 * math.pi * (1 - cos_max)
    fraction = hit.mean()
    return cone * fraction, cone * math.sqrt(fraction * (1 - fraction) / n)


# ---- solid angle ------------------------------------------------------------------------


@pytest.mark.parametrize("height", [0.01, 0.1, 0.3, 1.0, 5.0, 40.0])
def test_solid_angle_on_axis(height):
    with jax.enable_x64(True):
        for normal in ([0.0, 0, 1], [0.0, 0, -1], [0.6, 0, 0.8]):
            n = np.array(normal)
            point = np.array([1.0, -2.0, 3.0])
            got = disc_solid_angle(point + height * n, point, n, 0.254)
            assert float(got) == pytest.approx(on_axis_solid_angle(height, 0.254), rel=1e-10)


OFF_AXIS = [
    # (point, centre, normal, radius): foot inside, on the rim's projection, outside, grazing
    ([0.1, 0.05, 0.3], [0, 0, 0], [0, 0, 1], 0.25),
    ([0.25, 0.0, 0.2], [0, 0, 0], [0, 0, 1], 0.25),
    ([0.6, -0.4, 0.3], [0, 0, 0], [0, 0, 1], 0.25),
    ([1.5, 0.2, 0.1], [0, 0, 0], [0, 0, 1], 0.25),
    ([3.0, 2.0, -1.0], [1.0, 1.5, 0.5], [0.48, 0.6, -0.64], 0.1),
]


@pytest.mark.parametrize("case", OFF_AXIS)
def test_solid_angle_off_axis_exact_and_monte_carlo(case):
    point, centre, normal, radius = case
    normal = np.array(normal) / np.linalg.norm(normal)
    with jax.enable_x64(True):
        got = float(
            disc_solid_angle(
                jnp.array(point, float), jnp.array(centre, float), jnp.array(normal), radius
            )
        )
    assert got == pytest.approx(reference_solid_angle(point, centre, normal, radius), rel=1e-8)
    mc, error = monte_carlo_solid_angle(
        point, centre, normal, radius, 1_000_000, np.random.default_rng(1)
    )
    assert abs(got - mc) < 4 * error


def test_solid_angle_far_field_and_float32():
    radius, distance = 0.254, 30.0
    for theta in (0.0, 0.5, 1.0, 1.4):
        normal = np.array([math.sin(theta), 0.0, math.cos(theta)])
        centre = np.array([17.0, -9.0, 12.0])
        point = centre + np.array([0, 0, distance])
        far = math.pi * radius**2 * math.cos(theta) / distance**2
        with jax.enable_x64(True):
            exact = float(disc_solid_angle(point, centre, normal, radius))
        assert exact == pytest.approx(far, rel=2 * (radius / distance) ** 2)
        single = float(
            disc_solid_angle(
                jnp.asarray(point, jnp.float32), centre.astype(np.float32), normal, radius
            )
        )
        assert single == pytest.approx(exact, rel=1e-5)


def test_solid_angle_vectorised_and_differentiable():
    with jax.enable_x64(True):
        centres = jnp.array([[0.0, 0, 0], [1.0, 0, 0], [0, 2.0, 0]])
        normals = jnp.array([[0.0, 0, 1], [0.0, 0, 1], [0.0, 0.6, 0.8]])
        point = jnp.array([0.3, 0.2, 1.0])
        values = disc_solid_angle(point, centres, normals, jnp.array([0.2, 0.3, 0.1]))
        assert values.shape == (3,)
        grad = jax.grad(lambda p: jnp.sum(disc_solid_angle(p, centres, normals, 0.2)))(point)
        step = 1e-6
        for k in range(3):
            e = jnp.zeros(3).at[k].set(step)
            fd = (
                jnp.sum(disc_solid_angle(point + e, centres, normals, 0.2))
                - jnp.sum(disc_solid_angle(point - e, centres, normals, 0.2))
            ) / (2 * step)
            assert float(grad[k]) == pytest.approx(float(fd), rel=1e-6, abs=1e-12)


# ---- the analytic rung: sphere, source at the centre, absorption only ---------------------


def absorption_only(detector, absorption_length=30.0):
    return default_params(detector).replace(
        absorption_length=absorption_length,
        scattering_length=jnp.inf,
        mie_length=jnp.inf,
        angular_acceptance=jnp.ones(10),
    )


@pytest.mark.parametrize("name", ["TOY_SPHERE", "JUNO"])
def test_centre_of_sphere_absorption_only(name):
    detector = preset_detector(name)
    params = absorption_only(detector)
    n_photons = 1.0e7
    source = IsotropicSource(position=[0, 0, 0], n_photons=n_photons)
    mu, time = direct_light(detector, params, source)
    distance = np.linalg.norm(detector.sensor_positions, axis=1)
    omega = 2 * np.pi * (1 - distance / np.hypot(distance, detector.sensor_radius))
    qe = float(params.quantum_efficiency)
    expected = n_photons * omega / (4 * np.pi) * qe * np.exp(-distance / 30.0)
    np.testing.assert_allclose(np.asarray(mu), expected, rtol=5e-3)
    group_index = float(params.group_index)
    np.testing.assert_allclose(np.asarray(time), distance * group_index / SPEED_OF_LIGHT, atol=0.01)
    # normal incidence on every sensor: the gradient is finite (no arccos / norm at zero)
    sk_like = default_params(detector)
    grad = jax.grad(
        lambda p: jnp.sum(direct_light(detector, sk_like, replace(source, position=p))[0])
    )(jnp.zeros(3))
    assert np.isfinite(np.asarray(grad)).all()


@pytest.mark.parametrize("name", ["TOY_SPHERE", "JUNO"])
def test_off_centre_against_exact_solid_angles(name):
    detector = preset_detector(name)
    radius = detector.shape.radius
    params = absorption_only(detector).replace(time_offset=np.linspace(-2, 2, detector.n_sensors))
    position = np.array([0.3, -0.45, 0.6]) * radius
    source = IsotropicSource(position=position, n_photons=1.0e8, time=5.0)
    mu, time = direct_light(detector, params, source)
    offset = detector.sensor_positions - position
    distance = np.linalg.norm(offset, axis=1)
    cos_incidence = -np.sum(offset * detector.sensor_normals, axis=1) / distance
    assert (cos_incidence > 0).all()  # every sensor of a sphere sees an inside point
    rng = np.random.default_rng(7)
    check = rng.choice(detector.n_sensors, 40, replace=False)
    omega = np.array(
        [
            reference_solid_angle(
                position,
                detector.sensor_positions[j],
                detector.sensor_normals[j],
                detector.sensor_radius[j],
            )
            for j in check
        ]
    )
    # the reference itself against Monte Carlo on the nearest and the farthest sensor
    for k in (np.argmin(distance[check]), np.argmax(distance[check])):
        j = check[k]
        mc, error = monte_carlo_solid_angle(
            position,
            detector.sensor_positions[j],
            detector.sensor_normals[j],
            detector.sensor_radius[j],
            400_000,
            rng,
        )
        assert abs(omega[k] - mc) < 4 * error
    expected = (
        1.0e8
        * omega
        / (4 * np.pi)
        * float(params.quantum_efficiency)
        * np.exp(-distance[check] / 30.0)
    )
    np.testing.assert_allclose(np.asarray(mu)[check], expected, rtol=5e-3)
    # the transport's light comes before the sensor response: no time offset yet
    expected_time = 5.0 + distance * float(params.group_index) / SPEED_OF_LIGHT
    np.testing.assert_allclose(np.asarray(time), expected_time, atol=0.01)


def test_sensors_facing_away_get_no_light_and_acceptance_applies():
    detector = preset_detector("TOY_CYLINDER")
    params = absorption_only(detector)
    source = IsotropicSource(position=[0.5, 0.2, -0.3], n_photons=1e6)
    mu, _ = direct_light(detector, params, source)
    assert (np.asarray(mu) > 0).all()
    # a point above the top cap (outside; no check here): the top cap's sensors face away
    outside = IsotropicSource(position=[0, 0, 3.0], n_photons=1e6)
    mu_out, _ = direct_light(detector, params, outside)
    top = detector.sensor_normals[:, 2] < -0.5
    assert np.all(np.asarray(mu_out)[top] == 0)
    # halving the acceptance everywhere halves mu
    half, _ = direct_light(detector, params.replace(angular_acceptance=0.5 * jnp.ones(10)), source)
    np.testing.assert_allclose(np.asarray(half), 0.5 * np.asarray(mu), rtol=1e-6)


def test_emission_densities_are_normalised():
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(400_000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    axis = np.array([0.0, 0.6, 0.8])
    sources = [
        IsotropicSource(position=[0, 0, 0], n_photons=1.0),
        LaserSource(position=[0, 0, 0], direction=axis, n_photons=1.0, opening_angle=0.7),
        DiffuserSource(position=[0, 0, 0], n_photons=1.0, direction=axis, anisotropy=0.6),
    ]
    for source in sources:
        mean = float(jnp.mean(source.emission_density(jnp.asarray(dirs, jnp.float32))))
        assert 4 * np.pi * mean == pytest.approx(1.0, rel=0.02)
    laser = sources[1]
    inside = float(laser.emission_density(jnp.asarray(axis, jnp.float32)))
    assert inside == pytest.approx(1 / (2 * np.pi * (1 - np.cos(0.7))), rel=1e-6)
    assert float(laser.emission_density(jnp.asarray(-axis, jnp.float32))) == 0.0


# ---- jit: no recompilation ---------------------------------------------------------------


def test_no_recompilation_when_values_change():
    detector = preset_detector("TOY_SPHERE")
    params = default_params(detector)
    source = IsotropicSource(position=[0.1, 0.2, 0.3], n_photons=1e6)
    direct_light(detector, params, source)
    size = direct_light_jit._cache_size()
    moved = replace(
        detector,
        sensor_positions=detector.sensor_positions * 0.99,
        sensor_radius=detector.sensor_radius * 1.1,
    )
    direct_light(moved, params.replace(absorption_length=12.0, efficiency=0.9), source)
    moved_source = replace(
        source, position=jnp.array([0.0, 0.5, 0.1]), time=jnp.array(3.0), n_photons=2e6
    )
    direct_light(detector, params, moved_source)
    assert direct_light_jit._cache_size() == size


# ---- gradients: autodiff vs central finite differences (float64) -------------------------


def objective_for(detector, params, weights_mu, weights_t):
    def objective(p, source):
        mu, time = direct_light(detector, p, source)
        return jnp.sum(weights_mu * mu) + jnp.sum(weights_t * time)

    return objective


def assert_gradients(objective, params, source, param_entries, source_entries, step=1e-6):
    """Compare autodiff with central differences for (field, index) entries."""
    grad_params, grad_source = jax.grad(objective, argnums=(0, 1))(params, source)

    def check(tree, grad_tree, entries, rebuild):
        for name, index in entries:
            value = getattr(tree, name)
            flat = jnp.ravel(value)
            i = 0 if index is None else index
            h = step * max(1.0, abs(float(flat[i])))

            def shifted(delta, flat=flat, i=i, name=name, value=value):
                new = flat.at[i].add(delta).reshape(value.shape)
                return float(rebuild(tree, name, new))

            fd = (shifted(h) - shifted(-h)) / (2 * h)
            ad = float(jnp.ravel(getattr(grad_tree, name))[i])
            assert ad == pytest.approx(fd, rel=1e-2, abs=1e-6 * (1 + abs(fd))), (name, index)

    check(
        params,
        grad_params,
        param_entries,
        lambda tree, name, new: objective(replace(tree, **{name: new}), source),
    )
    check(
        source,
        grad_source,
        source_entries,
        lambda tree, name, new: objective(params, replace(tree, **{name: new})),
    )


PARAM_ENTRIES = [
    ("absorption_length", None),
    ("scattering_length", None),
    ("mie_length", None),
    ("quantum_efficiency", None),
    ("group_index", None),
    ("angular_acceptance", 0),
    ("angular_acceptance", 2),
    ("angular_acceptance", 4),
    ("angular_acceptance", 5),
]


@pytest.fixture
def gradient_setup():
    with jax.enable_x64(True):
        detector = preset_detector("TOY_SPHERE")
        rng = np.random.default_rng(11)
        params = default_params(detector).replace(mie_length=40.0, scattering_length=25.0)
        weights_mu = jnp.asarray(rng.random(detector.n_sensors))
        weights_t = jnp.asarray(rng.random(detector.n_sensors))
        objective = objective_for(detector, params, weights_mu, weights_t)
        yield detector, params, objective


def test_gradients_isotropic(gradient_setup):
    detector, params, objective = gradient_setup
    with jax.enable_x64(True):
        source = IsotropicSource(
            position=[1.0, -0.8, 1.1], n_photons=1e5, time=2.0, pulse_width=1.0
        )
        grad_params, _ = jax.grad(objective, argnums=(0, 1))(params, source)
        # incidences reach past 50 degrees (|p| / R = 0.84), so every entry checked matters
        assert float(jnp.abs(grad_params.angular_acceptance[5])) > 0
        assert_gradients(
            objective,
            params,
            source,
            PARAM_ENTRIES,
            [
                ("position", 0),
                ("position", 1),
                ("position", 2),
                ("n_photons", None),
                ("time", None),
                ("pulse_width", None),
            ],
        )


def test_gradients_laser(gradient_setup):
    detector, params, objective = gradient_setup
    with jax.enable_x64(True):
        direction = np.array([0.3, 0.2, 0.9])
        source = LaserSource(
            position=[0.2, 0.1, -0.4],
            direction=direction / np.linalg.norm(direction),
            n_photons=1e5,
            opening_angle=0.6,
            time=1.0,
        )
        mu, _ = direct_light(detector, params, source)
        assert 5 < int(jnp.sum(mu > 0)) < detector.n_sensors
        assert_gradients(
            objective,
            params,
            source,
            PARAM_ENTRIES[:3],
            [
                ("position", 0),
                ("position", 2),
                ("direction", 0),
                ("direction", 1),
                ("opening_angle", None),
                ("n_photons", None),
                ("time", None),
            ],
            step=1e-7,
        )


def test_gradients_diffuser(gradient_setup):
    detector, params, objective = gradient_setup
    with jax.enable_x64(True):
        source = DiffuserSource(
            position=[-0.3, 0.4, 0.2],
            n_photons=1e5,
            direction=[0.0, 0.6, 0.8],
            anisotropy=0.4,
            time=-1.0,
        )
        assert_gradients(
            objective,
            params,
            source,
            PARAM_ENTRIES[:5],
            [
                ("position", 1),
                ("direction", 0),
                ("direction", 2),
                ("anisotropy", None),
                ("n_photons", None),
                ("time", None),
            ],
        )


# ---- bad sources -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("source", "message"),
    [
        (
            IsotropicSource(position=[0, 0, 2.5], n_photons=1e6),
            "source.position = [0.0, 0.0, 2.5]: outside the sphere 4.00 m diameter by 0.5 m",
        ),
        (IsotropicSource(position=[0, 0, 0], n_photons=0.0), "source.n_photons = 0: must be > 0"),
        (IsotropicSource(position=[0, 0, 0], n_photons=-5.0), "source.n_photons = -5: must be > 0"),
        (
            IsotropicSource(position=[0, float("nan"), 0], n_photons=1.0),
            "source.position = [0.0, nan, 0.0]: is NaN",
        ),
        (
            IsotropicSource(position=[0, 0, 0], n_photons=1.0, time=float("nan")),
            "source.time = nan: is NaN",
        ),
        (
            LaserSource(
                position=[0, 0, 0], direction=[0, 0, 2.0], n_photons=1.0, opening_angle=0.1
            ),
            "source.direction = [0.0, 0.0, 2.0]: not a unit vector (length 2)",
        ),
        (
            LaserSource(
                position=[0, 0, 0], direction=[0, 0, 1.0], n_photons=1.0, opening_angle=0.0
            ),
            "source.opening_angle = 0: must be in (0, pi] rad",
        ),
        (
            DiffuserSource(
                position=[0, 0, 0], n_photons=1.0, direction=[1.0, 0, 0], anisotropy=1.5
            ),
            "source.anisotropy = 1.5: must be in [-1, 1]",
        ),
        (
            DiffuserSource(
                position=[0, 0, 0], n_photons=1.0, direction=[1.0, 0, 0], pulse_width=-1.0
            ),
            "source.pulse_width = -1: must be >= 0 ns",
        ),
    ],
)
def test_bad_sources(source, message):
    detector = preset_detector("TOY_SPHERE")
    with pytest.raises(ConfigError) as info:
        check_source(source, detector)
    assert str(info.value) == message
    assert "\n" not in str(info.value)


def test_good_sources_pass():
    detector = preset_detector("TOY_CYLINDER")
    source = DiffuserSource(position=[0.5, 0, 1.0], n_photons=1e6, direction=[0, 0, 1.0])
    assert check_source(source, detector) is source
