"""The wall under other sensor discs, for the first-order mirror paths (``mirror.py``).

The wall under other sensors is not a smooth integrand: a node either reflects off bare
wall or meets a disc, and for a source on a cylinder's axis the reflections line up with
the columns of discs, so node by node the covered part is poorly resolved (the sampled
against the expected mode on SK: studies/transport-validation.md). So each disc is
mapped onto the wall whole: the linear map fitted to its nodes' reflection points
(``disc_to_wall``) takes it to an ellipse, and the part of that ellipse under other
discs (``uncovered_share``, chord by chord, exact up to the chords' quadrature) is
shared by all its nodes. The cap-barrel edge is still resolved node by node
(``_points_covered``). Differentiable in the reflection points. Lengths m.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.sensor_grid import grid_candidates_xyz
from ..numerics import safe_sqrt, where
from .mirror_geometry import radon_disc_rule

#: A wall point within this distance (m) of a disc's plane and inside its rim is under
#: the sensor (discs sit on the wall; a curved wall departs from the disc's plane by
#: r^2 / 2R, 2 mm for SK's 20" PMTs).
ON_DISC = 0.05
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
