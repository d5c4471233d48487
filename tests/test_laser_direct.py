"""Direct light of sources with a non-uniform emission density: exact over the disc.

The emission-weighted solid angle (the sources' ``disc_fraction``) against independent
float64 area integrals over the disc; a laser's total direct light in a sphere against
ray casting; smoothness and gradients across the laser cone's edge; the isotropic
source unchanged.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

from photonflow.geometry import preset_detector
from photonflow.geometry.solid_angle import disc_cone_solid_angle, disc_cosine_moment
from photonflow.params import default_params
from photonflow.pytree import replace
from photonflow.response.detection import acceptance_at_cos
from photonflow.sources import DiffuserSource, IsotropicSource, LaserSource
from photonflow.transport import direct_light, direct_light_jit, disc_solid_angle

pytestmark = pytest.mark.compile_bound

# ---- float64 references: integrals over the disc's area, independent of the rim forms ------


def disc_basis(normal):
    """Two unit vectors spanning the disc's plane (numpy)."""
    helper = np.array([1.0, 0, 0]) if abs(normal[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


def reference_cone_solid_angle(point, axis, opening_angle, centre, normal, radius):
    """Omega(disc image n cone), sr, by integration over the disc in polar coordinates
    (s, psi) about its centre: dOmega = h s ds dpsi / |Q + s e(psi)|^3 (h the point's
    height over the plane, Q = centre - point). Along each radial line the cone's edge is
    a root of a quadratic in s and the s integral is closed form; adaptive quadrature in
    psi (64 sub-intervals, so that narrow psi ranges are not skipped)."""
    p, c, n, a = (np.asarray(x, dtype=np.float64) for x in (point, centre, normal, axis))
    n, a = n / np.linalg.norm(n), a / np.linalg.norm(a)
    q = c - p
    h, qq, qa = abs(q @ n), q @ q, q @ a
    u, v = disc_basis(n)
    k = math.cos(opening_angle)

    def radial(psi):
        e = math.cos(psi) * u + math.sin(psi) * v
        b, ea = q @ e, e @ a

        def antiderivative(s):  # of s / (s^2 + 2 b s + |Q|^2)^(3/2)
            return -(b * s + qq) / ((qq - b * b) * math.sqrt(s * s + 2 * b * s + qq))

        cuts = [0.0, radius]
        for root in np.roots([ea * ea - k * k, 2 * (qa * ea - k * k * b), qa * qa - k * k * qq]):
            if abs(root.imag) < 1e-12 and 0 < root.real < radius:
                cuts.append(root.real)
        cuts.sort()
        total = 0.0
        for s1, s2 in zip(cuts[:-1], cuts[1:], strict=False):
            w = q + 0.5 * (s1 + s2) * e
            if w @ a >= k * math.sqrt(w @ w):
                total += h * (antiderivative(s2) - antiderivative(s1))
        return total

    breaks = np.linspace(0, 2 * math.pi, 65)[1:-1]
    value, _ = integrate.quad(
        radial, 0, 2 * math.pi, points=breaks, epsabs=1e-16, epsrel=1e-12, limit=2000
    )
    return value


def reference_weighted_solid_angle(point, centre, normal, radius, density):
    """integral over the disc of density(unit direction) dOmega (nested adaptive quadrature)."""
    p, c, n = (np.asarray(x, dtype=np.float64) for x in (point, centre, normal))
    n = n / np.linalg.norm(n)
    q = c - p
    h = abs(q @ n)
    u, v = disc_basis(n)

    def integrand(s, psi):
        w = q + s * (math.cos(psi) * u + math.sin(psi) * v)
        d = math.sqrt(w @ w)
        return density(w / d) * h * s / d**3

    value, _ = integrate.dblquad(integrand, 0, 2 * math.pi, 0, radius, epsabs=1e-16, epsrel=1e-11)
    return value


def float64_tree(tree):
    """A pytree with every leaf cast to float64 (inside ``jax.enable_x64``)."""
    return jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), tree)


def disc_at(point, axis, angle, distance, tilt, rng):
    """A disc centre at ``angle`` (rad) from ``axis`` seen from ``point``, and a unit normal
    facing the point, tilted by ~``tilt`` rad in a random direction."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    u, v = disc_basis(axis)
    phi = rng.uniform(0, 2 * math.pi)
    direction = math.cos(angle) * axis + math.sin(angle) * (math.cos(phi) * u + math.sin(phi) * v)
    kick = rng.normal(size=3)
    normal = -direction + tilt * kick / np.linalg.norm(kick)
    return np.asarray(point) + distance * direction, normal / np.linalg.norm(normal)


# ---- (1) emission-weighted solid angle against the area integrals -------------------------

#: (opening angle rad, distance m, radius m, centre angle in units of (alpha, rho)):
#: rho = arcsin(r / d) bounds the disc's angular radius; the centre sits at
#: alpha + x rho from the axis (x < -1 fully inside, |x| < 1 on the edge, x > 1 outside).
CONE_CASES = (
    [(0.05, 20.0, 0.25, x) for x in (-3.0, -1.2, -0.8, -0.5, 0.0, 0.5, 0.9, 1.2, 3.0)]
    + [(0.05, 3.0, 0.25, x) for x in (-0.6, 0.0, 0.7)]
    + [(0.6, 3.0, 0.25, x) for x in (-2.0, -0.5, 0.0, 0.6, 2.0)]
    + [(1.2, 2.0, 0.3, x) for x in (-0.4, 0.3)]
    + [
        (2.5, 2.0, 0.3, x)
        for x in (-0.7, 0.0, 0.8)  # a cone wider than a hemisphere
    ]
    + [
        # a pencil beam narrower than the disc: axis inside the disc, grazing its rim, outside
        (0.02, 2.0, 0.25, x)
        for x in (-0.2, 0.84, 1.1)
    ]
)


@pytest.mark.parametrize("case", CONE_CASES)
def test_cone_solid_angle_against_area_integration(case):
    """Tolerance 3e-8 Omega: the composite Gauss rule's error measured on these and 300
    scan points through both tangencies is <= 1.1e-8 Omega (typically 1e-10); the
    reference is good to ~1e-12. Evaluating the density at the disc centre (the former
    method) errs by up to 100 % of Omega on the edge."""
    alpha, distance, radius, x = case
    rng = np.random.default_rng(abs(hash(case)) % 2**32)
    point, axis = np.array([0.3, -0.2, 0.1]), np.array([0.2, -0.5, 0.8])
    rho = math.asin(radius / distance)
    centre, normal = disc_at(point, axis, abs(alpha + x * rho), distance, 0.5, rng)
    with jax.enable_x64(True):
        got = float(disc_cone_solid_angle(point, axis, alpha, centre, normal, radius))
        omega = float(disc_solid_angle(point, centre, normal, radius))
    expected = reference_cone_solid_angle(point, axis, alpha, centre, normal, radius)
    assert abs(got - expected) <= 3e-8 * omega
    if x < -1 and alpha > rho:
        assert got == pytest.approx(omega, rel=1e-12)  # fully inside: exactly Omega
    if x > 1 and alpha > rho:
        assert got == 0.0  # fully outside: exactly zero


@pytest.mark.parametrize("distance", [0.5, 2.0, 10.0])
def test_cone_on_axis_is_exact(distance):
    """A face-on disc centred on the axis: Omega(R n K) = 2 pi (1 - cos min(alpha, rho)),
    rho = atan(r / d); both the cone inside the disc and the disc inside the cone."""
    with jax.enable_x64(True):
        for alpha in (0.01, 0.05, 0.3, 1.5, math.pi):
            point = np.array([1.0, 2.0, -1.0])
            axis = np.array([0.6, 0.0, 0.8])
            got = float(
                disc_cone_solid_angle(point, axis, alpha, point + distance * axis, axis, 0.25)
            )
            rho = math.atan(0.25 / distance)
            expected = 2 * math.pi * (1 - math.cos(min(alpha, rho)))
            assert got == pytest.approx(expected, rel=1e-10)


@pytest.mark.parametrize("distance", [0.6, 2.0, 10.0])
def test_diffuser_against_area_integration(distance):
    """(Omega + a M) / 4 pi against the nested quadrature of (1 + a cos theta) / 4 pi (to
    1e-10 relative: both are exact; the former centre evaluation errs by ~(r/d)^2)."""
    rng = np.random.default_rng(int(distance * 10))
    point, axis = np.array([0.1, 0.2, -0.3]), np.array([0.0, 0.6, 0.8])
    for anisotropy in (0.7, -1.0):
        centre, normal = disc_at(point, axis, rng.uniform(0.3, 2.5), distance, 0.5, rng)
        with jax.enable_x64(True):
            source = DiffuserSource(
                position=point, n_photons=1.0, direction=axis, anisotropy=anisotropy
            )
            got = float(source.disc_fraction(centre, normal, 0.25))

        def density(w, anisotropy=anisotropy):
            return (1 + anisotropy * (w @ axis)) / (4 * math.pi)

        expected = reference_weighted_solid_angle(point, centre, normal, 0.25, density)
        assert got == pytest.approx(expected, rel=1e-10)


def test_cosine_moment_float32_far_away():
    """At SK distances (40 m, r = 0.25 m) the float32 cosine moment keeps ~1e-6 of Omega
    (measured 2e-7: the O(r/d) terms that cancel around the rim are removed analytically)."""
    rng = np.random.default_rng(5)
    point = np.array([3.0, -2.0, 15.0])
    for _ in range(20):
        axis = rng.normal(size=3)
        centre, normal = disc_at(point, axis, rng.uniform(0, math.pi), 40.0, 0.3, rng)
        args = (point, axis / np.linalg.norm(axis), centre, normal, 0.25)
        with jax.enable_x64(True):
            exact = float(disc_cosine_moment(*args))
            omega = float(disc_solid_angle(point, centre, normal, 0.25))
        single = float(disc_cosine_moment(*(np.asarray(a, np.float32) for a in args)))
        assert abs(single - exact) <= 2e-6 * omega


def test_cone_float32_far_away():
    """float32 at 40 m, r = 0.25 m (rho = 6e-3 rad), narrow and wide cones: discs inside keep
    1e-6 of Omega (measured 3e-7), discs on the edge 3e-5 (measured 8e-6; a float32
    direction is only good to ~1e-7 rad, and the edge moves the light by Omega per rho)."""
    rng = np.random.default_rng(8)
    point = np.array([3.0, -2.0, 15.0])
    axis = np.array([0.3, 0.1, -0.95]) / np.linalg.norm([0.3, 0.1, -0.95])
    rho = math.asin(0.25 / 40)
    for alpha in (0.05, 0.6):
        for x in np.linspace(-2, 2, 25):
            centre, normal = disc_at(point, axis, alpha + x * rho, 40.0, 0.3, rng)
            args = (point, axis, alpha, centre, normal, 0.25)
            with jax.enable_x64(True):
                exact = float(disc_cone_solid_angle(*args))
                omega = float(disc_solid_angle(point, centre, normal, 0.25))
            single = float(disc_cone_solid_angle(*(np.asarray(a, np.float32) for a in args)))
            assert abs(single - exact) <= (1e-6 if x < -1 else 3e-5) * omega


# ---- (2) total direct light of a laser in a sphere of sensors ------------------------------


def cone_directions(axis, alpha, n, rng):
    """n directions uniform in the cone of half-angle alpha about axis."""
    cos_t = 1 - rng.random(n) * (1 - math.cos(alpha))
    phi = rng.random(n) * 2 * math.pi
    sin_t = np.sqrt(1 - cos_t**2)
    u, v = disc_basis(axis)
    return (
        cos_t[:, None] * axis
        + (sin_t * np.cos(phi))[:, None] * u
        + (sin_t * np.sin(phi))[:, None] * v
    )


def flat_absorption_free(detector):
    return default_params(detector).replace(
        absorption_length=jnp.inf,
        scattering_length=jnp.inf,
        mie_length=jnp.inf,
        quantum_efficiency=1.0,
        angular_acceptance=jnp.ones(10),
    )


@pytest.mark.parametrize(("position", "alpha"), [([0, 0, 0], 0.3), ([0.4, -0.3, 0.5], 0.12)])
def test_laser_total_in_sphere_against_ray_casting(position, alpha):
    """Sum over sensors of mu / N (QE 1, flat acceptance, no attenuation) is the fraction of
    the cone's photons that cross a disc: 2e6 rays cast into the cone (brute force against
    every disc, each disc counted) give it to ~3e-4 absolute; the agreement must be within
    4 sigma. The former centre evaluation misses it by many sigma (asserted, to show the
    test has the power to fail)."""
    detector = preset_detector("TOY_SPHERE")
    params = flat_absorption_free(detector)
    axis = np.array([0.3, 0.5, 0.81])
    axis /= np.linalg.norm(axis)
    with jax.enable_x64(True):
        params = float64_tree(params)
        source = LaserSource(position=position, direction=axis, n_photons=1.0, opening_angle=alpha)
        mu, _ = direct_light(detector, params, source)
        total = float(jnp.sum(mu))
        centres = np.asarray(detector.sensor_positions, np.float64)
        normals = np.asarray(detector.sensor_normals, np.float64)
        radii = np.asarray(detector.sensor_radius, np.float64)
        omega = np.asarray(disc_solid_angle(source.position, centres, normals, radii))
        offset = centres - np.asarray(position, np.float64)
        distance = np.linalg.norm(offset, axis=1)
        density = source.emission_density(jnp.asarray(offset / distance[:, None]))
        centre_evaluated = float(np.sum(omega * np.asarray(density)))
    near = np.nonzero(offset @ axis / distance > math.cos(alpha + 0.2))[0]
    assert 2 <= len(near) < 60
    hits = 0
    rng = np.random.default_rng(2)
    for _ in range(20):
        rays = cone_directions(axis, alpha, 100_000, rng)
        to_centre = offset[near]
        t = (to_centre * normals[near]).sum(1) / (rays @ normals[near].T)  # (rays, near)
        miss = t[..., None] * rays[:, None] - to_centre
        hits += int(((t > 0) & (np.sum(miss * miss, axis=-1) <= radii[near] ** 2)).sum())
    fraction = hits / 2_000_000
    sigma = math.sqrt(fraction * (1 - fraction) / 2_000_000)
    assert abs(total - fraction) < 4 * sigma
    # all cone photons that reach no disc are accounted for: the sum stays below 1
    assert 0.05 < total < 1.0
    assert abs(centre_evaluated - fraction) > 6 * sigma


# ---- (3) smoothness across the cone's edge and gradients -------------------------------


def test_scan_of_laser_direction_across_a_sensor_edge_is_smooth():
    """A narrow laser (alpha = 0.05 rad, about one sensor's angular radius) from the centre of
    the toy sphere, turned in 50 steps from a sensor's centre to 0.2 rad away: the sensor's
    mu falls from the full cone to zero continuously, over ~24 steps (largest step 5 % of
    the full value). A jump of J shows as a second difference ~J; the smooth curve's
    largest second difference is 1.4 % (at the tangencies, where the overlap grows as a
    power 3/2), so 3 % leaves room while an all-or-nothing step (100 %) or a jump of a
    tenth of the light fails."""
    detector = preset_detector("TOY_SPHERE")
    params = flat_absorption_free(detector)
    j = 17
    target = np.array(detector.sensor_positions[j], np.float64)
    target /= np.linalg.norm(target)
    sideways = np.cross(target, [0.0, 0.0, 1.0])
    sideways /= np.linalg.norm(sideways)
    angles = np.linspace(0.0, 0.2, 50)
    with jax.enable_x64(True):
        params = float64_tree(params)

        def sensor_mu(angle):
            direction = jnp.cos(angle) * target + jnp.sin(angle) * sideways
            source = float64_tree(
                LaserSource(
                    position=[0, 0, 0], direction=direction, n_photons=1.0, opening_angle=0.05
                )
            )
            return direct_light(detector, params, source)[0][j]

        mu = np.asarray(jax.vmap(sensor_mu)(jnp.asarray(angles)))
    full = mu[0]
    assert full > 0
    assert mu[-1] == 0.0
    assert np.all(np.diff(mu) <= 1e-15)  # monotone as the cone moves off the sensor
    assert 10 <= np.sum((mu > 1e-6 * full) & (mu < (1 - 1e-6) * full)) <= 40  # partial light
    assert np.max(np.abs(np.diff(mu, 2))) < 0.03 * full


def relative_gradient_check(objective, tree, entries, step=1e-7):
    """Autodiff against central finite differences (float64) for (field, index) entries,
    within 1 % (or 1e-6 of the objective's scale for near-zero derivatives)."""
    grad = jax.grad(objective)(tree)
    scale = abs(float(objective(tree)))
    for name, index in entries:
        value = jnp.ravel(getattr(tree, name))
        h = step * max(1.0, abs(float(value[index])))

        def shifted(delta, name=name, index=index, value=value):
            new = value.at[index].add(delta).reshape(jnp.shape(getattr(tree, name)))
            return float(objective(replace(tree, **{name: new})))

        fd = (shifted(h) - shifted(-h)) / (2 * h)
        ad = float(jnp.ravel(getattr(grad, name))[index])
        assert ad == pytest.approx(fd, rel=1e-2, abs=1e-6 * scale), (name, index, ad, fd)


@pytest.mark.parametrize("alpha", [0.08, 0.3])
def test_laser_gradients_on_the_cone_edge(alpha):
    """Weighted sum of mu over the toy sphere, the laser aimed between two neighbouring
    sensors so that at least two straddle the cone's edge: autodiff == central differences
    within 1 % for direction, opening angle, position and n_photons. (With the density at
    the disc centre the direction derivative was zero.)"""
    detector = preset_detector("TOY_SPHERE")
    rng = np.random.default_rng(4)
    weights = rng.random(detector.n_sensors)
    position = np.array([0.2, 0.1, -0.3])
    centres = np.asarray(detector.sensor_positions, np.float64)
    gaps = np.linalg.norm(centres - centres[17], axis=1)
    gaps[17] = np.inf
    axis = 0.5 * (centres[17] + centres[np.argmin(gaps)]) - position
    with jax.enable_x64(True):
        params = float64_tree(default_params(detector))
        source = LaserSource(
            position=position,
            direction=axis / np.linalg.norm(axis),
            n_photons=1e5,
            opening_angle=alpha,
            time=1.0,
        )
        discs = (centres, detector.sensor_normals, detector.sensor_radius)
        fraction = np.asarray(source.disc_fraction(*discs))
        full = np.asarray(disc_solid_angle(position, *discs)) / (
            2 * math.pi * (1 - math.cos(alpha))
        )
        assert int(np.sum((fraction > 0.01 * full) & (fraction < 0.99 * full))) >= 2

        def objective(source):
            return jnp.sum(weights * direct_light(detector, params, source)[0])

        relative_gradient_check(
            objective,
            source,
            [("direction", 0), ("direction", 1), ("direction", 2), ("opening_angle", 0)]
            + [("position", 0), ("position", 2), ("n_photons", 0)],
        )


def test_opening_angle_derivative_is_the_edge_inside_the_disc():
    """d Omega(R n K) / d alpha = sin(alpha) x (azimuth of the cone's edge circle that lies in
    the disc's image), the latter counted on 2e5 points of the circle (to ~1e-5 rad):
    autodiff through the rim quadrature against this geometric identity, 1e-3."""
    rng = np.random.default_rng(9)
    point, axis, alpha = np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.3
    centre, normal = disc_at(point, axis, alpha + 0.02, 2.0, 0.4, rng)
    with jax.enable_x64(True):
        derivative = float(
            jax.grad(lambda a: disc_cone_solid_angle(point, axis, a, centre, normal, 0.25))(alpha)
        )
    phi = (np.arange(200_000) + 0.5) * (2 * math.pi / 200_000)
    rays = np.stack(
        [
            math.sin(alpha) * np.cos(phi),
            math.sin(alpha) * np.sin(phi),
            np.full_like(phi, math.cos(alpha)),
        ],
        axis=1,
    )
    t = ((centre - point) @ normal) / (rays @ normal)
    miss = t[:, None] * rays - (centre - point)
    inside = (t > 0) & (np.sum(miss * miss, axis=1) <= 0.25**2)
    edge_azimuth = inside.mean() * 2 * math.pi
    assert edge_azimuth > 0.05
    assert derivative == pytest.approx(math.sin(alpha) * edge_azimuth, rel=1e-3)


def test_finite_gradients_on_the_axis_and_facing_away():
    """A laser aimed exactly at a sensor's centre (the disc on the axis), and one outside the
    toy cylinder above its top cap (whose sensors face away and get mu = 0): every source
    and Params gradient is finite."""
    for name, position, target in [
        ("TOY_SPHERE", [0.0, 0.0, 0.0], None),
        ("TOY_CYLINDER", [0.0, 0.0, 3.0], np.array([0.0, 0.0, -1.0])),
    ]:
        detector = preset_detector(name)
        params = default_params(detector)
        if target is None:
            target = np.asarray(detector.sensor_positions[5]) - np.asarray(position)
            target /= np.linalg.norm(target)
        source = LaserSource(position=position, direction=target, n_photons=1e6, opening_angle=0.5)
        mu, _ = direct_light(detector, params, source)
        assert float(jnp.sum(mu)) > 0

        def objective(params, source, detector=detector):
            mu, time = direct_light(detector, params, source)
            return jnp.sum(mu) + 1e-3 * jnp.sum(time)

        grads = jax.grad(objective, argnums=(0, 1))(params, source)
        for leaf in jax.tree.leaves(grads):
            assert np.isfinite(np.asarray(leaf)).all()
        if name == "TOY_CYLINDER":
            top = np.asarray(detector.sensor_normals[:, 2]) < -0.5
            assert np.all(np.asarray(mu)[top] == 0)


def test_no_recompilation_when_laser_values_change():
    detector = preset_detector("TOY_SPHERE")
    params = default_params(detector)
    source = LaserSource(
        position=[0.1, 0.2, 0.3], direction=[0, 0, 1.0], n_photons=1e6, opening_angle=0.1
    )
    direct_light(detector, params, source)
    size = direct_light_jit._cache_size()
    moved = replace(
        source,
        position=jnp.array([0.0, -0.5, 0.1]),
        direction=jnp.array([0.6, 0.0, 0.8]),
        opening_angle=jnp.array(0.7),
        n_photons=2e6,
    )
    direct_light(detector, params, moved)
    assert direct_light_jit._cache_size() == size


# ---- (4) the isotropic source is unchanged -------------------------------------------------


@pytest.mark.parametrize("x64", [True, False])
def test_isotropic_direct_light_unchanged(x64):
    """mu = N Omega / (4 pi) QE eff A exp(-d / L) exactly as before (same ``disc_solid_angle``),
    to rounding: 1e-12 in float64, 1e-6 in float32."""
    detector = preset_detector("TOY_CYLINDER")
    with jax.enable_x64(x64):
        dtype = jnp.float64 if x64 else jnp.float32
        params = jax.tree.map(lambda x: jnp.asarray(x, dtype), default_params(detector))
        params = params.replace(mie_length=jnp.asarray(40.0, dtype))
        source = jax.tree.map(
            lambda x: jnp.asarray(x, dtype),
            IsotropicSource(position=[0.5, -0.2, 0.3], n_photons=1e6),
        )
        mu, _ = direct_light(detector, params, source)
        centres = jnp.asarray(detector.sensor_positions, dtype)
        normals = jnp.asarray(detector.sensor_normals, dtype)
        offset = centres - source.position
        distance = jnp.linalg.norm(offset, axis=1)
        cos_incidence = -jnp.sum(offset * normals, axis=1) / distance
        omega = disc_solid_angle(
            source.position, centres, normals, jnp.asarray(detector.sensor_radius, dtype)
        )
        expected = (
            source.n_photons
            * omega
            / (4 * math.pi)
            * params.quantum_efficiency
            * acceptance_at_cos(params.angular_acceptance, cos_incidence)
            * jnp.exp(
                -distance
                * (
                    1 / params.absorption_length
                    + 1 / params.scattering_length
                    + 1 / params.mie_length
                )
            )
        )
        expected = jnp.where(cos_incidence > 0, expected, 0.0)
        np.testing.assert_allclose(
            np.asarray(mu), np.asarray(expected), rtol=1e-12 if x64 else 1e-6
        )
