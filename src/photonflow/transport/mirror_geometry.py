"""Reflection geometry of the first-order mirror paths (``mirror.py``): every path
source s -> wall point P -> node x of a sensor disc, and the area A_P per steradian of
its reflected ray tube at x (m^2/sr; L = |P - s| + |x - P| the path length).

The nodes on each disc are those of Radon's 7-point degree-5 rule (the centre and six
points at sqrt(2/3) r; ``radon_disc_rule``, ``disc_nodes``). The reflection points
(``reflection_points``):

- planar faces (cylinder caps, box faces): the mirror image s' of the source; P is where
  the line s' -> x crosses the plane, A_P = L^2;
- the cylinder's barrel: seen from above, a reflection off a circle; its points are the
  stationary points of the horizontal path length over the wall azimuth (up to
  ``MAX_ROOTS``, bracketed on a grid of ``GRID`` azimuths and refined by safeguarded
  Newton steps, ``circle_reflections``; the nodes of a disc followed from its centre's,
  ``follow_reflections``), the height follows by unfolding; the ray tube is curved only
  horizontally: A_P = (1 + tau^2) |D| l, l the horizontal path length, tau the
  slope, D = l_1 + l_2 - 2 l_1 l_2 / (R cos i) the tangential mirror equation (l_1,
  l_2 horizontal lengths, i the horizontal incidence angle);
- the sphere: the reflection lies in the plane of the centre, s and x: the same circle
  problem there; A_P = |D_t D_s| with D_t as above and D_s = l_1 + l_2 - 2 l_1 l_2 cos i
  / R (sagittal), on 3-D lengths.

``focusing_ratio`` is A_P over a flat mirror's L^2 (paths below ``mirror.FOCUSING_LIMIT``
are left to the rays). Roots are found without gradient and refined by one Newton step
with it (the implicit-function derivative), so the points are differentiable in the
source position. Lengths m.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.shapes import Box, Cylinder, Sphere
from ..geometry.solid_angle import plane_basis
from ..numerics import hypot, safe_sqrt, where

#: Azimuths of the grid that brackets reflection points on a circle.
GRID = 96
#: Reflection points kept per circle problem (a point inside a circle has at most 4).
MAX_ROOTS = 4
#: Safeguarded Newton steps refining each bracketed root (at disc centres).
NEWTON_STEPS = 10
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
