"""Source light mirrored once by the wall into a sensor, by quadrature (no sampling noise).

A specular reflection is a delta function in direction: a next-event estimate cannot see
it, and rays find it only when a mirrored ray happens to hit a sensor, with a large
weight (on SK at 1,024 rays ~23 p.e. per hit against ~0.3 p.e. of mirrored light per
sensor on average). The first-order path, source s -> wall point P -> sensor j, is
therefore computed like direct light, for every node x of a 7-point rule on disc j
(Radon's degree-5 rule: the centre and six points at sqrt(2/3) r):

    mu_j = N R_w f_s sum_x w_x sum_P S(omega_P) cos_in(x) / A_P(x)
           x QE A(theta_in) exp(-rate_total L) [P not covered by a sensor]

(light of a sensor of efficiency 1: the sensor response applies eff_j), with
L = |P - s| + |x - P| the path length, omega_P the emission direction toward P, A_P the
area per steradian of the reflected ray tube at x (m^2/sr; photons per m^2 across the
ray = S / A_P) and the indicator that the photon reaches the black wall at P
rather than a sensor disc (``uncovered_share``). The reflection points:

- planar faces (cylinder caps, box faces): the mirror image s' of the source; P is where
  the line s' -> x crosses the plane, A_P = L^2;
- the cylinder's barrel: seen from above, a reflection off a circle; its points are the
  stationary points of the horizontal path length over the wall azimuth (up to
  ``MAX_ROOTS``, bracketed on a grid of ``GRID`` azimuths and refined by safeguarded
  Newton steps), the height follows by unfolding; the ray tube is curved only
  horizontally: A_P = (1 + tau^2) |D| l, l the horizontal path length, tau the
  slope, D = l_1 + l_2 - 2 l_1 l_2 / (R cos i) the tangential mirror equation (l_1,
  l_2 horizontal lengths, i the horizontal incidence angle);
- the sphere: the reflection lies in the plane of the centre, s and x: the same circle
  problem there; A_P = |D_t D_s| with D_t as above and D_s = l_1 + l_2 - 2 l_1 l_2 cos i
  / R (sagittal), on 3-D lengths.

Near caustics (a curved wall focusing the ray tube below ``FOCUSING_LIMIT`` of a flat
mirror's, e.g. the axis of a cylinder for a source on it) a node rule is poor: those
paths are left to the rays. Everywhere else the ray estimator of ``indirect.py`` leaves
out its detections after a first-order mirror vertex (it still follows those rays), so
the sum stays unbiased.

The wall under other sensors is not a smooth integrand: a node either reflects off bare
wall or meets a disc, and for a source on a cylinder's axis the reflections line up with
the columns of discs, so node by node the covered part is poorly resolved (the sampled
against the expected mode on SK: studies/transport-validation.md). So each disc is
mapped onto the wall whole: the linear map fitted to its nodes' reflection points takes
it to an ellipse, and the part of that ellipse under other discs (``uncovered_share``,
chord by chord, exact up to the chords' quadrature) is shared by all its nodes. The
cap-barrel edge is still resolved node by node. Roots are found without gradient and
refined by one Newton step with it (the implicit-function derivative), so the light, the
covered part included, is differentiable in the source position; ``Params`` enter only
through the weights. Lengths m, times ns.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.sensor_arrays import Sensors
from ..geometry.sensor_grid import grid_candidates_xyz
from ..geometry.shapes import Box, Cylinder, Sphere
from ..geometry.solid_angle import plane_basis
from ..numerics import hypot, safe_sqrt, where
from ..params import Params
from ..pytree import pytree_dataclass
from ..response.detection import acceptance_at_cos
from .optics import interaction_rates, travel_time

#: Azimuths of the grid that brackets reflection points on a circle.
GRID = 96
#: Reflection points kept per circle problem (a point inside a circle has at most 4).
MAX_ROOTS = 4
#: Safeguarded Newton steps refining each bracketed root (at disc centres).
NEWTON_STEPS = 10
#: Paths whose ray tube is focused below this fraction of a flat mirror's are left to
#: the rays (``focusing_ratio``).
FOCUSING_LIMIT = 0.25
#: A wall point within this distance (m) of a disc's plane and inside its rim is under
#: the sensor (discs sit on the wall; a curved wall departs from the disc's plane by
#: r^2 / 2R, 2 mm for SK's 20" PMTs).
ON_DISC = 0.05
#: Largest |slope| (dimensionless) accepted at a refined root.
ROOT_TOLERANCE = 1e-3
#: Newton steps moving a disc centre's reflection points to the nodes of its disc.
FOLLOW_STEPS = 3
#: Targets nearer than this (m) to a planar face get no mirror path off it (a disc on
#: the face itself; float32 rounding puts its nodes either side of the plane).
PLANE_CLEARANCE = 1e-4


def radon_disc_rule():
    """Radon's 7-point degree-5 rule on the unit disc: (x (7,), y (7,), weight (7,)),
    weights summing to pi."""
    angles = np.arange(6) * (math.pi / 3.0)
    rho = math.sqrt(2.0 / 3.0)
    x = np.concatenate([[0.0], rho * np.cos(angles)])
    y = np.concatenate([[0.0], rho * np.sin(angles)])
    weight = np.concatenate([[math.pi / 4.0], np.full(6, math.pi / 8.0)])
    return x, y, weight


def disc_nodes(centres, normals, radius):
    """Nodes (N, 7, 3) m and area weights (N, 7) m^2 of the 7-point rule on each disc."""
    x, y, weight = (jnp.asarray(a, centres.dtype) for a in radon_disc_rule())
    u, v = jax.vmap(plane_basis)(normals)
    r = radius[:, None, None]
    across = x[None, :, None] * u[:, None] + y[None, :, None] * v[:, None]
    nodes = centres[:, None, :] + r * across
    return nodes, weight[None, :] * radius[:, None] ** 2


# ---- reflection on a circle (2-D) ------------------------------------------------------


def _circle_slope(cos, sin, a, b, radius):
    """(d/dpsi of |a - P| + |b - P|) / R at P = R (cos psi, sin psi), for 2-tuples a and b
    of arrays broadcasting with cos and sin: zero where light from a reflects to b.
    Distances are floored at 1e-6 R: a or b on the circle gives large finite values."""
    floor = (1e-6 * radius) ** 2  # a point on the circle itself: finite, huge, no NaN
    to_a = jnp.sqrt((a[0] - radius * cos) ** 2 + (a[1] - radius * sin) ** 2 + floor)
    to_b = jnp.sqrt((b[0] - radius * cos) ** 2 + (b[1] - radius * sin) ** 2 + floor)
    return (a[0] * sin - a[1] * cos) / to_a + (b[0] * sin - b[1] * cos) / to_b


def circle_reflections(a, b, radius):
    """Reflection points on a circle of ``radius`` (m, centred on the origin) for light
    from 2-D points a to b inside it (2-tuples of (T,) arrays, m).

    Returns (psi (T, MAX_ROOTS) rad, found (T, MAX_ROOTS) bool): azimuths where the
    path length |a - P| + |P - b| is stationary, bracketed on a grid of ``GRID``
    azimuths, refined by safeguarded Newton steps without gradient, then one Newton
    step with it (its derivative is the implicit-function one).
    """
    a = tuple(c[:, None] for c in a)
    b = tuple(c[:, None] for c in b)

    def slope(psi):
        return _circle_slope(jnp.cos(psi), jnp.sin(psi), a, b, radius)

    step = 2.0 * math.pi / GRID
    grid = np.arange(GRID) * step
    values = jax.lax.stop_gradient(
        _circle_slope(
            jnp.asarray(np.cos(grid), a[0].dtype), jnp.asarray(np.sin(grid), a[0].dtype),
            a, b, radius,
        )
    )  # (T, GRID)
    following = jnp.roll(values, -1, axis=-1)
    change = ((values > 0) != (following > 0)) & jnp.isfinite(values) & jnp.isfinite(following)
    rank = jnp.cumsum(change, axis=-1) - 1
    kth = [change & (rank == k) for k in range(MAX_ROOTS)]  # the k-th bracket, if any
    first = jnp.stack([jnp.argmax(bracket, axis=-1) for bracket in kth], axis=-1)
    found = jnp.stack([jnp.any(bracket, axis=-1) for bracket in kth], axis=-1)
    low = first.astype(a[0].dtype) * step
    high = low + step
    f_low = jnp.take_along_axis(values, first, axis=-1)

    def newton(psi):
        value, derivative = jax.jvp(slope, (psi,), (jnp.ones_like(psi),))
        safe = where(derivative != 0, derivative, 1.0)
        return value, psi - value / safe, derivative != 0

    def safeguarded(_, state):
        low, high, f_low, psi = state
        value, candidate, usable = newton(psi)
        same_side = value * f_low > 0
        low, high = where(same_side, psi, low), where(same_side, high, psi)
        f_low = where(same_side, value, f_low)
        inside = usable & (candidate > low) & (candidate < high)
        return low, high, f_low, where(inside, candidate, 0.5 * (low + high))

    state = (low, high, f_low, 0.5 * (low + high))
    psi = jax.lax.stop_gradient(jax.lax.fori_loop(0, NEWTON_STEPS, safeguarded, state)[3])
    refined = newton(psi)[1]
    # a bracket around a jump of the slope (a target on the circle itself) is no root
    residual = jnp.abs(jax.lax.stop_gradient(slope(refined)))
    return refined, found & (residual < ROOT_TOLERANCE)


def follow_reflections(psi, a, b, radius):
    """Reflection azimuths for targets b (2-tuple of (T, 1) or (T, M) arrays, m) near the
    targets whose reflections ``psi`` (T, M) rad are known (the nodes of a disc from its
    centre's): ``FOLLOW_STEPS`` Newton steps without gradient, then one with it.
    Returns (psi, converged): converged where the last step moved less than 1e-4 rad."""

    def newton(psi):
        value, derivative = jax.jvp(
            lambda q: _circle_slope(jnp.cos(q), jnp.sin(q), a, b, radius),
            (psi,),
            (jnp.ones_like(psi),),
        )
        return psi - value / where(derivative != 0, derivative, 1.0)

    start = jax.lax.stop_gradient(
        jax.lax.fori_loop(0, FOLLOW_STEPS, lambda _, q: newton(q), jax.lax.stop_gradient(psi))
    )
    final = newton(start)
    return final, jnp.abs(jax.lax.stop_gradient(final) - start) < 1e-4


# ---- reflection points and ray-tube areas per wall shape --------------------------------


def _planar_reflections(source, targets, normal, offset, on_face):
    """Mirror image in the plane n . p + offset = 0 (n the inward unit normal, a (3,)
    tuple): (P (T, 1, 3), valid (T, 1)). ``on_face(P)`` says whether points P (T, 3)
    lie on the face.

    A target within ``PLANE_CLEARANCE`` of the plane (a node of a disc mounted on this
    face) has no reflection off it: its reflection point would be the target itself, a
    path of zero length out of the wall whose direction is undefined."""
    normal = jnp.asarray(normal, targets.dtype)
    height = jnp.dot(source, normal) + offset  # > 0 inside
    target_height = targets @ normal + offset
    image = source - 2.0 * height * normal
    along = targets - image
    t = height / jnp.maximum(jnp.sum(along * normal, axis=-1), 1e-12)
    points = image + t[:, None] * along
    valid = on_face(points) & (t > 0) & (target_height > PLANE_CLEARANCE)
    return points[:, None], valid[:, None]


def _disc_circle_reflections(a, b, radius):
    """Circle reflections for the nodes of every disc: a and b 2-tuples of (N, Q) arrays
    (m; node 0 the disc centre). Brackets at the centres, follows to the other nodes.
    Returns (psi (N, Q, MAX_ROOTS) rad, found (N, Q, MAX_ROOTS))."""
    centre_psi, centre_found = circle_reflections(
        tuple(c[:, 0] for c in a), tuple(c[:, 0] for c in b), radius
    )
    start = jnp.broadcast_to(centre_psi[:, None, :], a[0].shape + (MAX_ROOTS,))
    psi, converged = follow_reflections(
        start, tuple(c[..., None] for c in a), tuple(c[..., None] for c in b), radius
    )
    moved = jnp.abs(jnp.remainder(psi - start + math.pi, 2.0 * math.pi) - math.pi)
    near = jax.lax.stop_gradient(moved) < 4.0 * math.pi / GRID
    return psi, centre_found[:, None, :] & converged & near


def _barrel_reflections(source, nodes, radius, half_height):
    """Reflections off a cylinder's barrel for nodes (N, Q, 3): (P (T, M, 3), valid
    (T, M)), T = N Q."""
    targets = nodes.reshape(-1, 3)
    a = tuple(jnp.broadcast_to(source[k], nodes.shape[:2]) for k in range(2))
    psi, found = _disc_circle_reflections(a, (nodes[..., 0], nodes[..., 1]), radius)
    psi, found = psi.reshape(targets.shape[0], -1), found.reshape(targets.shape[0], -1)
    wall_x, wall_y = radius * jnp.cos(psi), radius * jnp.sin(psi)
    l_in = hypot(wall_x - source[0], wall_y - source[1])
    l_out = hypot(targets[:, 0:1] - wall_x, targets[:, 1:2] - wall_y)
    horizontal = l_in + l_out
    slope = (targets[:, 2:3] - source[2]) / horizontal
    wall_z = source[2] + slope * l_in
    points = jnp.stack([wall_x, wall_y, wall_z], axis=-1)
    valid = found & (jnp.abs(wall_z) < half_height)
    return points, valid


def _sphere_reflections(source, nodes, radius):
    """Reflections off a sphere for nodes (N, Q, 3): (P (T, M, 3), valid (T, M)). The
    circle problem of each node is solved in the plane of the centre, the source and
    the node."""
    source_norm = safe_sqrt(jnp.sum(source * source))  # finite gradient at the centre
    off_centre = source_norm > 1e-9 * radius
    node_axis = nodes / jnp.linalg.norm(nodes, axis=-1, keepdims=True)
    first = where(off_centre, source / where(off_centre, source_norm, 1.0), node_axis)
    across = nodes - jnp.sum(nodes * first, axis=-1, keepdims=True) * first
    across_norm = safe_sqrt(jnp.sum(across * across, axis=-1, keepdims=True))  # 0: collinear
    spare = jax.vmap(jax.vmap(plane_basis))(first)[0]  # any direction across ``first``
    second = where(
        across_norm > 1e-9 * radius, across / jnp.maximum(across_norm, 1e-30), spare
    )
    a = (jnp.sum(source * first, axis=-1), jnp.sum(source * second, axis=-1))
    b = (jnp.sum(nodes * first, axis=-1), jnp.sum(nodes * second, axis=-1))
    psi, found = _disc_circle_reflections(a, b, radius)
    cos, sin = jnp.cos(psi)[..., None], jnp.sin(psi)[..., None]
    points = radius * (cos * first[..., None, :] + sin * second[..., None, :])
    points = points.reshape(-1, MAX_ROOTS, 3)
    return points, found.reshape(-1, MAX_ROOTS)


def _guarded(x, floor=1e-9):
    """x with |x| raised to ``floor`` (sign kept): a denominator that is never 0."""
    return where(jnp.abs(x) < floor, where(x < 0, -floor, floor), x)


def focusing_ratio(shape, source, wall_points, targets):
    """Ray-tube area of the mirror path source -> P -> target over that of a flat mirror
    (1 for planar faces; < 1 where a curved wall focuses): (...,) for ``wall_points`` P
    and ``targets`` (..., 3) m, ``source`` (3,) or (..., 3) m. Paths with a ratio below
    ``FOCUSING_LIMIT`` (near caustics, where a quadrature node rule is poor) are left
    to the rays of ``indirect.py``; the rest are done here."""
    if isinstance(shape, Cylinder):
        l_in = hypot(wall_points[..., 0] - source[..., 0], wall_points[..., 1] - source[..., 1])
        l_out = hypot(
            targets[..., 0] - wall_points[..., 0], targets[..., 1] - wall_points[..., 1]
        )
        towards = (wall_points[..., 0] - source[..., 0]) * wall_points[..., 0] + (
            wall_points[..., 1] - source[..., 1]
        ) * wall_points[..., 1]
        cos_incidence = _guarded(towards / _guarded(l_in * shape.radius))
        horizontal = _guarded(l_in + l_out)
        tangential = horizontal - 2.0 * l_in * l_out / (shape.radius * cos_incidence)
        rho = hypot(wall_points[..., 0], wall_points[..., 1])
        on_cap = 0.5 * shape.height - jnp.abs(wall_points[..., 2]) < shape.radius - rho
        return where(on_cap, 1.0, jnp.abs(tangential) / horizontal)
    if isinstance(shape, Sphere):
        l_in = jnp.linalg.norm(wall_points - source, axis=-1)
        l_out = jnp.linalg.norm(targets - wall_points, axis=-1)
        cos_incidence = _guarded(
            jnp.sum((wall_points - source) * wall_points, axis=-1) / _guarded(l_in * shape.radius)
        )
        total = _guarded(l_in + l_out)
        tangential = total - 2.0 * l_in * l_out / (shape.radius * cos_incidence)
        sagittal = total - 2.0 * l_in * l_out * cos_incidence / shape.radius
        return jnp.abs(tangential * sagittal) / (total * total)
    return jnp.ones(wall_points.shape[:-1], wall_points.dtype)


def reflection_points(shape, source, nodes):
    """Every first-order mirror path from ``source`` (3,) m to the quadrature ``nodes``
    (N, Q, 3) m of the sensor discs (node 0 the centre) off the walls of ``shape``:
    (P (T, M, 3) m, valid (T, M) bool) for the T = N Q nodes in order."""
    targets = nodes.reshape(-1, 3)
    parts = []
    if isinstance(shape, Cylinder):
        half_height, radius = 0.5 * shape.height, shape.radius

        def on_cap(points):
            return points[:, 0] ** 2 + points[:, 1] ** 2 < radius * radius

        for sign in (1.0, -1.0):
            parts.append(
                _planar_reflections(source, targets, (0.0, 0.0, -sign), half_height, on_cap)
            )
        parts.append(_barrel_reflections(source, nodes, radius, half_height))
    elif isinstance(shape, Box):
        half = shape.half_sizes
        for axis in range(3):
            others = [k for k in range(3) if k != axis]

            def on_face(points, others=others):
                return (jnp.abs(points[:, others[0]]) < half[others[0]]) & (
                    jnp.abs(points[:, others[1]]) < half[others[1]]
                )

            for sign in (1.0, -1.0):
                normal = tuple(-sign if k == axis else 0.0 for k in range(3))
                parts.append(_planar_reflections(source, targets, normal, half[axis], on_face))
    elif isinstance(shape, Sphere):
        parts.append(_sphere_reflections(source, nodes, shape.radius))
    else:
        raise TypeError(f"no mirror paths for {type(shape).__name__}")
    return tuple(jnp.concatenate(xs, axis=1) for xs in zip(*parts, strict=True))


def disc_to_wall(points, valid, radius):
    """The linear map from a disc to the wall about each reflection: (N, M, 2, 3), the
    images A u and A v of the unit vectors of the disc's ``plane_basis`` (m per m), for
    reflection points ``points`` (N, Q, M, 3) m of the Q = 7 nodes of
    ``radon_disc_rule`` (node 0 the centre) in M slots, ``valid`` (N, Q, M), disc radii
    ``radius`` (N,) m. The least-squares fit to the six outer nodes' points about the
    centre's (Radon's nodes at angles k pi / 3 and radius sqrt(2/3) r:
    A u = sum_k (P_k - P_0) cos(k pi / 3) / (3 sqrt(2/3) r)); zero where a slot lacks
    any of its disc's nodes."""
    x, y, _ = radon_disc_rule()
    rho_node = math.sqrt(2.0 / 3.0)
    offsets = points[:, 1:] - points[:, :1]  # (N, 6, M, 3)
    cos_k = jnp.asarray(x[1:] / rho_node, points.dtype)[None, :, None, None]
    sin_k = jnp.asarray(y[1:] / rho_node, points.dtype)[None, :, None, None]
    scale = 1.0 / (3.0 * rho_node * radius)[:, None, None]
    complete = jnp.all(valid, axis=1)[..., None]  # (N, M, 1)
    along = [where(complete, jnp.sum(offsets * c, axis=1) * scale, 0.0)
             for c in (cos_k, sin_k)]
    return jnp.stack(along, axis=-2)


#: Discs, the nearest to a disc's mirrored wall patch, that are tested for covering it
#: (the patch is mostly smaller than a disc, rarely a few discs across).
NEAREST_DISCS = 4
#: ``_ellipses_covered`` spreads its chords over the whole ellipse (rather than over
#: the part of the minor range where the disc is) for a disc reaching more than
#: EXTENT_LIMIT half-widths across it, for ellipses smaller than SOLID_SIZE disc radii
#: and for ellipses thinner than sqrt(SOLID_ASPECT) seen across the disc's axis.
EXTENT_LIMIT = 100.0
SOLID_SIZE = 1e-2
SOLID_ASPECT = 1e-3
#: Chords across a disc's wall patch over which the part under another disc is
#: integrated (midpoint rule in the angle of a sine substitution).
CHORDS = 8


def _nearby_discs(grid, sensor_positions, sensor_normals, sensor_radius, centre):
    """The discs the lookup ``grid`` lists near points ``centre`` (..., 3) m: (listed
    (..., K) bool, centres and normals (3-tuples of (..., K)), radii (..., K) m)."""
    candidates = grid_candidates_xyz(grid, tuple(centre[..., k] for k in range(3)))
    listed = candidates >= 0
    index = where(listed, candidates, 0)
    return (listed, tuple(sensor_positions[:, k][index] for k in range(3)),
            tuple(sensor_normals[:, k][index] for k in range(3)), sensor_radius[index])


def _across(discs, points):
    """(height above the disc's plane m, vector across its axis (3-tuple) m, its length m)
    of points (3-tuple of arrays broadcasting against the (..., K) ``discs``)."""
    _, position, normal, _ = discs
    offset = [p - c for p, c in zip(points, position, strict=True)]
    height = sum(o * n for o, n in zip(offset, normal, strict=True))
    across = [o - height * n for o, n in zip(offset, normal, strict=True)]
    return height, across, safe_sqrt(sum(a * a for a in across))  # 0 on the axis


def _points_covered(discs, points):
    """Whether points (3-tuple of (...,) arrays broadcasting against ``discs``' leading
    axes) lie under one of ``discs`` (``_nearby_discs``): within its radius of its
    centre across its axis and within ``ON_DISC`` m of its plane."""
    listed, _, _, radius = discs
    height, _, distance = _across(discs, tuple(p[..., None] for p in points))
    return jnp.any(listed & (jnp.abs(height) < ON_DISC) & (distance < radius), axis=-1)


def _principal_axes(spans):
    """The principal half-axes (2-tuple of 3-tuples of (...,) arrays, m) of ellipses with
    conjugate half-axes ``spans`` (..., 2, 3) m, the longer first: the singular vectors
    of the 3 x 2 map scaled by its singular values (closed form for 2 x 2)."""
    s1, s2 = spans[..., 0, :], spans[..., 1, :]
    a, b, c = jnp.sum(s1 * s1, -1), jnp.sum(s1 * s2, -1), jnp.sum(s2 * s2, -1)
    # eigenvector of [[a, b], [b, c]] for the larger eigenvalue: angle of the major axis.
    # A circle has any axes, and near one the angle is set by rounding and its gradient
    # (~ 1 / anisotropy) overflows: ellipses round to sqrt(eps) keep the conjugate
    # half-axes themselves (nearly orthogonal and equal there), with safe arguments
    finfo = jnp.finfo(a.dtype)
    round_ = (jnp.abs(b) + jnp.abs(a - c)) <= 10.0 * math.sqrt(finfo.eps) * (a + c) + finfo.tiny
    angle = 0.5 * jnp.arctan2(where(round_, 0.0, 2.0 * b), where(round_, 1.0, a - c))
    major = jnp.cos(angle)[..., None] * s1 + jnp.sin(angle)[..., None] * s2
    minor = -jnp.sin(angle)[..., None] * s1 + jnp.cos(angle)[..., None] * s2
    return (tuple(major[..., k] for k in range(3)), tuple(minor[..., k] for k in range(3)))


def _ellipses_covered(discs, centre, spans):
    """Fraction (...,) of the ellipses about ``centre`` (..., 3) m with conjugate
    half-axes ``spans`` (..., 2, 3) m that lies under ``discs`` (``_nearby_discs`` of
    the centres), for ellipses whose centre is within ``ON_DISC`` m of a disc's plane
    (the discs sit on the wall). The ellipse is cut into ``CHORDS`` chords along its
    major axis, spread over the offsets along its minor axis where the disc is; the part
    of each chord over the disc (a line across a circle) is exact, and the chords are
    summed by the midpoint rule after the substitution offset = middle + half
    sin(theta), which smooths the chord lengths' square-root ends. Thin ellipses, whose
    covered part changes abruptly across their width, and discs over the edge of a large
    ellipse are then as accurate as the rest."""
    listed, _, normal, radius = discs
    height, across, _ = _across(discs, tuple(centre[..., k, None] for k in range(3)))
    major, minor = (tuple(a[..., None] for a in axis) for axis in _principal_axes(spans))

    def flat(vector):  # the part across each disc's axis, in units of the disc's radius
        along = sum(v * n for v, n in zip(vector, normal, strict=True))
        return tuple((v - along * n) / radius for v, n in zip(vector, normal, strict=True))

    major, minor = flat(major), flat(minor)
    across = tuple(q / radius for q in across)  # already across the axis
    alpha = sum(m * m for m in major)
    # the minor offsets w where the disc can be: the disc is the ellipse |q + M w| < 1
    # in the coordinates w of this one (M = [major, minor], q = across, in radii); its
    # extent in w_2 is w0_2 +- sqrt(G^-1_22), G = M^T M, w0 = -G^-1 M^T q
    mixed = sum(a * b for a, b in zip(major, minor, strict=True))
    g22 = sum(m * m for m in minor)
    det = alpha * g22 - mixed * mixed
    # that range is worth computing only for an ellipse that, seen across the disc's
    # axis, is neither a point (smaller than SOLID_SIZE radii) nor a segment (widths
    # in a ratio below sqrt(SOLID_ASPECT)), and narrower than EXTENT_LIMIT half-widths:
    # otherwise the chords cover the whole minor range [-1, 1], each still cut exactly
    # by the disc, and no 1 / det (huge near a segment, overflowing in the gradient) is
    # evaluated
    size = alpha + g22
    solid = ((size > SOLID_SIZE**2) & (det > SOLID_ASPECT * size * size)
             & (det * EXTENT_LIMIT**2 > alpha))
    safe_det = where(solid, det, 1.0)
    on_major = sum(q * m for q, m in zip(across, major, strict=True))
    on_minor = sum(q * m for q, m in zip(across, minor, strict=True))
    middle = where(solid, -(alpha * on_minor - mixed * on_major) / safe_det, 0.0)
    extent = safe_sqrt(where(solid, alpha / safe_det, 1.0))
    low = where(solid, jnp.maximum(middle - extent, -1.0), -1.0)
    high = where(solid, jnp.minimum(middle + extent, 1.0), 1.0)
    centre_w, half_w = 0.5 * (low + high), jnp.maximum(0.5 * (high - low), 0.0)
    # a major half-axis below 1e-4 radii across the disc: each chord is a point
    tiny = jnp.asarray(1e-8, alpha.dtype)
    safe_alpha = where(alpha > tiny, alpha, 1.0)  # the point-like branch is used below
    # the chords on a trailing axis (one fused loop; the graph does not grow with CHORDS)
    theta = -0.5 * math.pi + (np.arange(CHORDS) + 0.5) * math.pi / CHORDS
    sin_theta = jnp.asarray(np.sin(theta), alpha.dtype)
    chord_weight = jnp.asarray(np.cos(theta) / CHORDS, alpha.dtype)
    across, minor, major = (tuple(c[..., None] for c in v) for v in (across, minor, major))
    alpha, safe_alpha, centre_w, half_w = (
        x[..., None] for x in (alpha, safe_alpha, centre_w, half_w)
    )
    offset = centre_w + half_w * sin_theta  # each chord's minor offset
    reach = safe_sqrt(1.0 - offset * offset)  # its half-length
    start = tuple(q + offset * n for q, n in zip(across, minor, strict=True))
    beta = sum(q * m for q, m in zip(start, major, strict=True))
    gamma = sum(q * q for q in start) - 1.0  # the disc: |start + x major| < 1
    root = safe_sqrt(beta * beta - alpha * gamma)
    inside = (jnp.minimum((-beta + root) / safe_alpha, reach)
              - jnp.maximum((-beta - root) / safe_alpha, -reach))
    point_like = where(gamma < 0, 2.0 * reach, 0.0)  # a chord of no length
    length = where(alpha > tiny, jnp.maximum(inside, 0.0), point_like)
    fraction = jnp.sum(length * half_w * chord_weight, axis=-1)
    on_plane = listed & (jnp.abs(height) < ON_DISC)
    return jnp.minimum(jnp.sum(where(on_plane, fraction, 0.0), axis=-1), 1.0)


def uncovered_share(near_grid, sensor_positions, sensor_normals, sensor_radius, points, valid):
    """(N, Q, M): the fraction of the light of each quadrature node that reaches the
    bare wall at its reflection point rather than a sensor disc, for reflection points
    ``points`` (N, Q, M, 3) m of the Q nodes of ``radon_disc_rule`` on the discs
    (``valid`` (N, Q, M); radii ``sensor_radius`` (N,) m).

    The wall under other sensors is a step function of the node, which a 7-node rule
    resolves poorly: where the wall's reflections line up with the rows of discs (a
    source on a cylinder's axis) it took ~10 % too much of SK's barrel mirror light as
    covered. So the disc is mapped onto the wall whole: the linear map of
    ``disc_to_wall`` takes it to an ellipse, whose covered fraction
    (``_ellipses_covered``) every node of the disc shares (the light varies little
    across a disc). A slot where some of the disc's nodes have no reflection (the
    cap-barrel edge) keeps the point test per node. Only the ``NEAREST_DISCS`` discs
    nearest to the patch's centre are tested; ``near_grid`` must list them
    (``sensor_arrays.near_grid_for``'s lists every disc within 4 radii)."""
    linear = disc_to_wall(points, valid, sensor_radius)  # (N, M, 2, 3)
    spans = sensor_radius[:, None, None, None] * linear
    # look the discs up at the first node with a reflection in each slot (the centre's
    # when it has one): the grid lists every disc within reach of all the disc's nodes
    first = jnp.argmax(valid, axis=1)[:, None, :, None]  # (N, 1, M, 1)
    lookup = jnp.take_along_axis(points, first, axis=1)[:, 0]  # (N, M, 3)
    discs = _nearby_discs(near_grid, sensor_positions, sensor_normals, sensor_radius, lookup)
    # only the discs nearest to the lookup point can cover much of the patch
    _, _, distance = _across(discs, tuple(lookup[..., k, None] for k in range(3)))
    _, nearest = jax.lax.top_k(-where(discs[0], distance, jnp.inf), NEAREST_DISCS)
    discs = jax.tree.map(lambda x: jnp.take_along_axis(x, nearest, axis=-1), discs)
    whole = _ellipses_covered(discs, lookup, spans)  # (N, M); complete slots: lookup = P_0
    nodes = _points_covered(jax.tree.map(lambda x: x[:, None], discs),
                            tuple(points[..., k] for k in range(3)))  # (N, Q, M)
    complete = jnp.all(valid, axis=1)  # (N, M)
    return 1.0 - where(complete[:, None], whole[:, None], nodes.astype(whole.dtype))


@pytree_dataclass
class MirrorPaths:
    """The first-order mirror paths of one source (``mirror_paths``): the part of
    ``mirror_light`` that does not depend on ``Params``, for T = 7 N quadrature nodes
    (disc by disc) and M reflection slots per node.

    Attributes:
        weight: (T, M) m^2/sr-normalised light per emitted photon and unit specular
            reflectivity R_w f_s, before QE, acceptance and attenuation: the
            emission density toward the wall point (1/sr) x cos_in / the ray tube's area
            per sr (m^2/sr) x the node's area (m^2) x the share of it over bare wall;
            0 where the path does not count (no reflection, the wall under a disc, the
            disc facing away, or focused below ``FOCUSING_LIMIT``: left to the rays).
        cos_in: (T, M) cosine of the incidence on the disc at the node.
        path: (T, M) m, source -> wall -> node.
    """

    weight: jax.Array
    cos_in: jax.Array
    path: jax.Array


def mirror_paths(shape, sensors: Sensors, source) -> MirrorPaths:
    """The first-order mirror paths from ``source`` to every sensor (``MirrorPaths``).

    Args:
        shape: the walled ``Shape`` (``Cylinder``, ``Sphere`` or ``Box``).
        sensors: the detector's ``Sensors`` (m). The wall under other discs, across a
            disc's whole mirrored patch, is found with its ``near_grid`` (every disc
            within a few radii of a point); without one, with its ``grid`` (only the
            discs within r + ``BASE_MARGIN`` of a point, too few for patches larger
            than that).
        source: a calibration source (position m, ``emission_density``).

    Differentiable in the source position (the roots by their implicit-function
    derivative, the covered share chord by chord). For a fixed source (a calibration
    run) it can be computed once and passed to ``mirror_light`` at every ``Params``.
    """
    sensor_positions, sensor_normals, sensor_radius = (
        sensors.positions, sensors.normals, sensors.radius
    )
    n = sensor_positions.shape[0]
    nodes, node_area = disc_nodes(sensor_positions, sensor_normals, sensor_radius)
    per_disc = nodes.shape[1]
    targets = nodes.reshape(-1, 3)
    receiver = jnp.repeat(jnp.arange(n), per_disc)
    points, valid = reflection_points(shape, source.position, nodes)
    # slots without a reflection get a harmless point inside (finite values and gradients)
    harmless = 0.5 * (source.position + targets)[:, None, :]
    points = where(valid[..., None], points, harmless)
    focusing = focusing_ratio(shape, source.position, points, targets[:, None])

    incoming = points - source.position
    l_in = jnp.linalg.norm(incoming, axis=-1)
    emission = incoming / l_in[..., None]
    outgoing = targets[:, None] - points
    l_out = jnp.linalg.norm(outgoing, axis=-1)
    cos_in = -jnp.sum(outgoing * sensor_normals[receiver][:, None], axis=-1) / l_out
    uncovered = uncovered_share(
        sensors.grid if sensors.near_grid is None else sensors.near_grid,
        sensor_positions, sensor_normals, sensor_radius,
        points.reshape(n, per_disc, -1, 3),
        valid.reshape(n, per_disc, -1),
    ).reshape(points.shape[:2])
    counts = valid & (uncovered > 0) & (cos_in > 0)
    counts = counts & (jax.lax.stop_gradient(focusing) >= FOCUSING_LIMIT)

    path = l_in + l_out
    safe_tube = where(counts, focusing * path * path, 1.0)  # ray-tube area per sr
    weight = (
        source.emission_density(emission)
        * jnp.maximum(cos_in, 0.0)
        / safe_tube
        * node_area.reshape(-1)[:, None]
        * uncovered
    )
    return MirrorPaths(weight=where(counts, weight, 0.0), cos_in=cos_in, path=path)


def mirror_light(params: Params, paths: MirrorPaths, source, reference_time):
    """First-order specular light from the source per sensor (see the module docstring).

    Args:
        params: detector parameters (reflectivities, lengths m).
        paths: the source's ``mirror_paths``.
        source: the same source (photons, time ns).
        reference_time: (N,) ns subtracted from arrival times.

    Returns:
        (N,) sums of c, c t and c t^2: c expected p.e. of a sensor of efficiency 1, t
        arrival time minus the reference (ns; before the sensor's time offset, the
        transit-time spread and the pulse width).
    """
    n = reference_time.shape[0]
    receiver = jnp.repeat(jnp.arange(n), paths.weight.shape[0] // n)
    rate_total = interaction_rates(params)[3]
    detected = (
        source.n_photons
        * params.wall_reflectivity
        * params.wall_specular_fraction
        * paths.weight
        * params.quantum_efficiency
        * acceptance_at_cos(params.angular_acceptance, jnp.maximum(paths.cos_in, 0.0))
        * jnp.exp(-rate_total * paths.path)
    )
    relative = source.time + travel_time(paths.path, params) - reference_time[receiver][:, None]
    return tuple(jnp.sum((detected * relative**k).reshape(n, -1), axis=1) for k in range(3))
