"""Exact solid angle of a flat disc seen from a point, smooth and differentiable.

Method (a boundary integral, by Green's theorem in the disc's plane): let q be the
point relative to the disc centre, h = |q . n| its distance from the plane, e(t) =
cos t u + sin t v the unit vectors of the plane (u, v orthonormal, perpendicular to
the normal n) and R(t) = |q - r e(t)| the distance from the point to the rim point at
azimuth t. Then

    Omega = integral_0^{2 pi} r (r - q . e(t)) / (R(t) (R(t) + h)) dt.

This is the familiar Omega = integral (1 - h / sqrt(h^2 + rho^2)) dphi over the
azimuth phi of the rim seen from the foot of the perpendicular, rewritten with the rim
parameter t (dphi = r (r - q . e) / rho^2 dt, rho the in-plane distance, and
(1 - h / R) / rho^2 = 1 / (R (R + h)), free of cancellation). It holds for any
off-axis point, whether the foot of the perpendicular falls inside the disc or not
(the phi integral then runs forth and back and the two halves subtract). The
integrand is smooth and 2 pi-periodic, so the trapezoid rule with equally spaced
nodes converges geometrically: 64 nodes give ~1e-12 relative error once the point is
a disc radius away from the rim, and the result is a smooth function of every input.

Far from the disc the terms -r q . e(t) g(R(t)), g(R) = 1 / (R (R + h)), nearly cancel
around the rim (a loss of d / r digits in float32). Since the nodes' sum of q . e(t)
is zero, g(R0) with R0^2 = |q|^2 + r^2 is subtracted from g(R) inside that term, and
g(R) - g(R0) is written with R0^2 - R^2 = 2 r q . e(t), free of cancellation:

    Omega = r^2 (2 pi / n) sum_t [ g(R) - 2 (q . e)^2 (1 + h / (R + R0))
                                         / (R R0 (R + h) (R0 + h)) ].

The emission-weighted solid angle of a source with an axially symmetric density S(theta)
(the sources' ``disc_fraction``, ``photonflow.sources``) is likewise a rim integral: by
Stokes' theorem on the unit sphere, integral_R S dOmega = rim integral of G(theta) dphi,
G(theta) = integral_0^theta S sin, (theta, phi) polar angles about the source axis. The
diffuser needs the cosine moment (``disc_cosine_moment``), the laser the solid angle of
the disc's image inside its cone (``disc_cone_solid_angle``), each in a form free of the
poles of dphi and of float32 cancellation.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ..inline_jit import inline_jit
from ..numerics import clip, where

#: Default number of rim nodes of the trapezoid rule.
DEFAULT_NODES = 64


def plane_basis(normal):
    """Two unit vectors (u, v) completing the unit ``normal`` (3,) to an orthonormal basis.

    Branch-free construction of Duff et al., JCGT 6(1), 2017 ("Building an orthonormal
    basis, revisited").
    """
    sign = where(normal[2] >= 0, 1.0, -1.0).astype(normal.dtype)
    a = -1.0 / (sign + normal[2])
    b = normal[0] * normal[1] * a
    u = jnp.stack([1.0 + sign * normal[0] ** 2 * a, sign * b, -sign * normal[0]])
    v = jnp.stack([b, sign + normal[1] ** 2 * a, -normal[1]])
    return u, v


#: A pole of ``disc_cone_solid_angle``'s rim integral within this many disc radii of
#: the disc's centre (as seen from the apex) counts as inside its image.
POLE_MARGIN = 1.5


def _flat_discs(point, centre, normal, radius):
    """Cast the disc arrays to the dtype of ``point`` (3,), broadcast them against each other
    and flatten: (M, 3) centres, (M, 3) normals, (M,) radii and the batch shape."""
    point = jnp.asarray(point)
    centre = jnp.asarray(centre, dtype=point.dtype)
    normal = jnp.asarray(normal, dtype=point.dtype)
    radius = jnp.asarray(radius, dtype=point.dtype)
    batch = jnp.broadcast_shapes(centre.shape[:-1], normal.shape[:-1], radius.shape)
    centre = jnp.broadcast_to(centre, (*batch, 3)).reshape(-1, 3)
    normal = jnp.broadcast_to(normal, (*batch, 3)).reshape(-1, 3)
    radius = jnp.broadcast_to(radius, batch).reshape(-1)
    return point, centre, normal, radius, batch


@inline_jit(static_argnames=("n_nodes",))
def disc_solid_angle(point, centre, normal, radius, n_nodes: int = DEFAULT_NODES):
    """Solid angle (sr) of a flat disc seen from a point.

    Args:
        point: (3,) viewing point, m.
        centre: (..., 3) disc centres, m.
        normal: (..., 3) unit disc normals (either orientation; both faces count).
        radius: (...,) disc radii, m.
        n_nodes: rim nodes of the trapezoid rule (static).

    Returns:
        (...,) solid angle in sr, in [0, 2 pi]; 2 pi (1 - h / sqrt(h^2 + r^2)) on the axis
        at height h. Undefined (division by zero) only for a point on the rim itself.
    """
    point, centre, normal, radius, batch = _flat_discs(point, centre, normal, radius)
    angles = (jnp.arange(n_nodes, dtype=point.dtype) + 0.5) * (2.0 * math.pi / n_nodes)
    cos_t, sin_t = jnp.cos(angles), jnp.sin(angles)

    def one(c, n, r):
        q = point - c  # relative to the disc centre: float32-safe at 40 m
        h = jnp.abs(jnp.dot(q, n))
        u, v = plane_basis(n)
        rim = cos_t[:, None] * u + sin_t[:, None] * v  # (n_nodes, 3) unit in-plane vectors
        to_rim = q - r * rim
        distance = jnp.sqrt(jnp.sum(to_rim * to_rim, axis=-1))  # R(t)
        mean_distance = jnp.sqrt(jnp.dot(q, q) + r * r)  # R0
        along = rim @ q  # q . e(t); R0^2 - R^2 = 2 r q . e
        integrand = 1.0 / (distance * (distance + h)) - 2.0 * along**2 * (
            1.0 + h / (distance + mean_distance)
        ) / (distance * mean_distance * (distance + h) * (mean_distance + h))
        return r * r * jnp.sum(integrand) * (2.0 * math.pi / n_nodes)

    return jax.vmap(one)(centre, normal, radius).reshape(batch)


def _unit(vector):
    """``vector / |vector|``, (3,)."""
    return vector / jnp.sqrt(jnp.sum(vector * vector))


def versine(angle):
    """1 - cos(angle) = 2 sin^2(angle / 2), free of cancellation at small angles (rad)."""
    return 2.0 * jnp.sin(0.5 * angle) ** 2


@inline_jit(static_argnames=("n_nodes",))
def disc_cosine_moment(point, axis, centre, normal, radius, n_nodes: int = DEFAULT_NODES):
    """Integral of cos(theta) over the solid angle of a flat disc seen from a point, sr.

    theta is the angle between a viewing direction and ``axis``. By Stokes' theorem on the
    unit sphere (d(sin^2 theta / 2) d phi = cos theta dOmega) it is the rim integral

        M = integral (x dy - y dx) / (2 |w|^2) = integral a . (w x dw/dt) / (2 |w|^2) dt,

    w(t) = c - p + r e(t) the rim point relative to the point p, (x, y) its components
    across the axis a. The 1-form sin^2 theta dphi / 2 vanishes at both poles, so this
    holds wherever the axis points. With Q = c - p, e'(t) = de/dt and R0^2 = |Q|^2 + r^2,
    a . (w x w') = r a . (Q x e') + r^2 a . n; the first term's sum over equally spaced
    nodes against 1 / R0^2 is zero, which leaves terms of order (r / d)^2 (float32-safe):

        M = s r^2 (2 pi / n) / 2 sum_t [a . n - 2 (a . (Q x e')) (Q . e) / R0^2] / |w|^2,

    s = sign(n . Q) orienting the rim counterclockwise as seen from beyond the disc.

    Args:
        point: (3,) viewing point, m.
        axis: (3,) axis direction (normalised here).
        centre: (..., 3) disc centres, m. normal: (..., 3) unit normals (either sign).
        radius: (...,) disc radii, m.
        n_nodes: rim nodes of the trapezoid rule (static).

    Returns:
        (...,) M in sr, in [-Omega, Omega]; pi sin^2(rho) on the axis of a face-on disc of
        angular radius rho.
    """
    point, centre, normal, radius, batch = _flat_discs(point, centre, normal, radius)
    axis = _unit(jnp.asarray(axis, dtype=point.dtype))
    angles = (jnp.arange(n_nodes, dtype=point.dtype) + 0.5) * (2.0 * math.pi / n_nodes)
    cos_t, sin_t = jnp.cos(angles), jnp.sin(angles)

    def one(c, n, r):
        to_centre = c - point  # Q
        u, v = plane_basis(n)
        rim = cos_t[:, None] * u + sin_t[:, None] * v  # e(t)
        tangent = -sin_t[:, None] * u + cos_t[:, None] * v  # e'(t)
        to_rim = to_centre + r * rim  # w(t)
        rim_sq = jnp.sum(to_rim * to_rim, axis=-1)
        mean_sq = jnp.dot(to_centre, to_centre) + r * r  # R0^2
        swirl = tangent @ jnp.cross(axis, to_centre)  # a . (Q x e')
        integrand = (jnp.dot(axis, n) - 2.0 * swirl * (rim @ to_centre) / mean_sq) / rim_sq
        orientation = jnp.sign(jnp.dot(n, to_centre))
        return orientation * 0.5 * r * r * jnp.sum(integrand) * (2.0 * math.pi / n_nodes)

    return jax.vmap(one)(centre, normal, radius).reshape(batch)


#: Base intervals of the composite rule of ``disc_cone_solid_angle``.
CONE_INTERVALS = 32
#: Gauss-Legendre nodes per piece of a base interval (at most three pieces).
CONE_GAUSS_NODES = 4


def _quadratic_zeros(f0, f_half, f1):
    """Zeros in [0, 1] of the quadratic through (0, f0), (1/2, f_half), (1, f1), sorted.

    Returns two break points (lo, hi) in [0, 1]: the real zeros, clipped to [0, 1]; where
    there are none, points that join the zeros continuously as the discriminant crosses
    zero. Uses the cancellation-free pair q / A, f0 / q.
    """
    a = 2.0 * (f1 - 2.0 * f_half + f0)
    b = 4.0 * f_half - 3.0 * f0 - f1
    root = jnp.sqrt(jnp.maximum(b * b - 4.0 * a * f0, 0.0))
    q = -0.5 * (b + where(b >= 0, root, -root))
    first = where(a != 0, q / where(a != 0, a, 1.0), 2.0)
    second = where(q != 0, f0 / where(q != 0, q, 1.0), 2.0)
    first, second = clip(first, 0.0, 1.0), clip(second, 0.0, 1.0)
    return jnp.minimum(first, second), jnp.maximum(first, second)


def _gauss_legendre(n_nodes: int, dtype):
    """Gauss-Legendre nodes in (0, 1) and weights summing to 1."""
    nodes, weights = np.polynomial.legendre.leggauss(n_nodes)
    return jnp.asarray(0.5 * (nodes + 1.0), dtype), jnp.asarray(0.5 * weights, dtype)


@inline_jit(static_argnames=("n_intervals", "n_gauss"))
def disc_cone_solid_angle(
    point,
    axis,
    opening_angle,
    centre,
    normal,
    radius,
    n_intervals: int = CONE_INTERVALS,
    n_gauss: int = CONE_GAUSS_NODES,
):
    """Solid angle (sr) of the part of a flat disc's image that lies inside a cone.

    The cone K has its apex at the viewing point p, the axis a and half-angle alpha; R is
    the set of directions from p to the disc. With theta, phi polar angles about a, Stokes'
    theorem (d[(1 - cos theta) dphi] = dOmega) turns Omega(R n K) into rim integrals of
    the kinked functions (cos alpha - cos theta)_+ and (cos theta - cos alpha)_+ against
    dphi = a . (w x dw/dt) / |w_perp|^2 dt (w(t) the rim point relative to p, w_perp its
    part across a). Either of two exact forms applies, chosen per disc so that the pole
    where its 1-form is singular lies far from the rim:

        (A) Omega(R n K) = Omega(R) - integral (cos alpha - cos theta)_+ dphi
            (needs -a outside R; its integrand is zero near a; Omega by ``disc_solid_angle``,
            so a disc inside the cone gets exactly Omega(R));
        (B) Omega(R n K) = -integral (cos theta - cos alpha)_+ dphi
            (needs a outside R; its integrand is zero near -a and outside the cone, so a
            disc outside the cone gets exactly 0).

    (A) is used when the disc's centre is inside the cone or within two angular radii
    of the axis, and not within two angular radii of -a; otherwise (B). Where the rim
    crosses the cone's edge the integrand has a kink: the rim parameter is cut into
    ``n_intervals`` base intervals, each split at the zeros of the quadratic through the
    values of cos theta - cos alpha at its ends and midpoint, and every piece is integrated
    by ``n_gauss``-point Gauss-Legendre. The break points carry no gradient (the exact
    integral does not depend on them), and the result is continuous and differentiable in
    every input. 1 - cos theta is evaluated as |w_perp|^2 / (|w| (|w| + z)) and
    1 - cos alpha as 2 sin^2(alpha / 2), free of cancellation near the axis.

    Args:
        point: (3,) apex / viewing point, m.
        axis: (3,) cone axis (normalised here).
        opening_angle: half-angle alpha of the cone, rad, in (0, pi].
        centre: (..., 3) disc centres, m. normal: (..., 3) unit normals (either sign).
        radius: (...,) disc radii, m.
        n_intervals, n_gauss: quadrature sizes (static).

    Returns:
        (...,) Omega(R n K) in sr, in [0, min(Omega(R), 2 pi (1 - cos alpha))], at any
        distance from the disc (``_use_outside_form`` keeps each form's pole out of the
        disc's image).
    """
    point, centre, normal, radius, batch = _flat_discs(point, centre, normal, radius)
    dtype = point.dtype
    axis = _unit(jnp.asarray(axis, dtype=dtype))
    opening_angle = jnp.asarray(opening_angle, dtype=dtype)
    cone_versine = versine(opening_angle)
    frame = jnp.stack([*plane_basis(axis), axis])  # rows: two unit vectors across a, a
    omega = disc_solid_angle(point, centre, normal, radius)
    step = 2.0 * math.pi / n_intervals
    base = jnp.arange(n_intervals, dtype=dtype)
    gauss_nodes, gauss_weights = _gauss_legendre(n_gauss, dtype)

    def one(c, n, r, omega_one):
        to_centre = c - point  # Q
        u, v = plane_basis(n)
        # w(t) = Q + r (cos t u + sin t v) in the axis frame, and a . (w x dw/dt) =
        # r e'(t) . (a x Q) + r^2 a . n: each a constant plus cos t and sin t terms
        centre_xyz = frame @ to_centre
        u_xyz, v_xyz = r * (frame @ u), r * (frame @ v)
        swirl = jnp.cross(axis, to_centre)
        turn_cos, turn_sin = r * jnp.dot(v, swirl), -r * jnp.dot(u, swirl)
        turn_mean = r * r * jnp.dot(axis, n)

        def rim_terms(t):
            """cos alpha - cos theta, a . (w x dw/dt) and |w_perp|^2 at rim parameters t."""
            cos_t, sin_t = jnp.cos(t), jnp.sin(t)
            x, y, z = (centre_xyz[k] + cos_t * u_xyz[k] + sin_t * v_xyz[k] for k in range(3))
            perp_sq = x * x + y * y
            length = jnp.sqrt(perp_sq + z * z)
            rim_versine = where(
                z > 0, perp_sq / (length * (length + jnp.maximum(z, 0.0))), (length - z) / length
            )
            turn = turn_mean + cos_t * turn_cos + sin_t * turn_sin
            return rim_versine - cone_versine, turn, perp_sq

        geometry = jax.lax.stop_gradient((to_centre, r, axis, opening_angle))
        use_outside = _use_outside_form(*geometry, jax.lax.stop_gradient(n))

        ends = rim_terms(jax.lax.stop_gradient(base * step))[0]
        halves = rim_terms(jax.lax.stop_gradient((base + 0.5) * step))[0]
        lo, hi = _quadratic_zeros(ends, halves, jnp.roll(ends, -1))
        edges = jax.lax.stop_gradient(
            jnp.stack([jnp.zeros_like(lo), lo, hi, jnp.ones_like(hi)], axis=-1)
        )
        starts, lengths = edges[:, :-1], edges[:, 1:] - edges[:, :-1]  # (n_intervals, 3)
        local = starts[..., None] + lengths[..., None] * gauss_nodes  # (n_intervals, 3, m)
        weights = step * lengths[..., None] * gauss_weights
        excess, turn, perp_sq = rim_terms((base[:, None, None] + local) * step)
        part = where(use_outside, excess, -excess)
        inside = part > 0
        integrand = where(inside, part / where(inside, perp_sq, 1.0), 0.0) * turn
        contour = jnp.sign(jnp.dot(n, to_centre)) * jnp.sum(weights * integrand)
        return where(use_outside, omega_one - contour, -contour)

    return jax.vmap(one)(centre, normal, radius, omega).reshape(batch)


def _use_outside_form(to_centre, radius, axis, opening_angle, normal):
    """Whether ``disc_cone_solid_angle`` uses form (A) for a disc (bool, no gradient).

    Form (A) has its pole at -a, form (B) at a; a pole inside the disc's image R (or near
    its rim) makes that form wrong. A flat disc's image lies within an open hemisphere,
    so a and -a are never both in it: a disc whose image (enlarged by ``POLE_MARGIN``)
    contains a takes (A), one containing -a takes (B). Otherwise, with theta_c the angle
    from the axis to the disc centre and rho = arcsin(r / d) the angular radius of a
    sphere around the disc: (A) when theta_c < max(alpha, 2 rho) and theta_c < pi - 2 rho.
    """
    distance = jnp.sqrt(jnp.sum(to_centre * to_centre))
    cos_centre = clip(jnp.dot(to_centre, axis) / distance, -1.0, 1.0)
    centre_angle = jnp.arccos(cos_centre)
    spread = jnp.arcsin(jnp.minimum(radius / distance, 1.0))
    by_angle = (centre_angle < jnp.maximum(opening_angle, 2.0 * spread)) & (
        centre_angle < math.pi - 2.0 * spread
    )
    pole_a_inside = _sees_disc(to_centre, normal, POLE_MARGIN * radius, axis)
    pole_minus_a_inside = _sees_disc(to_centre, normal, POLE_MARGIN * radius, -axis)
    return pole_a_inside | (~pole_minus_a_inside & by_angle)


def _sees_disc(to_centre, normal, radius, direction):
    """Whether the ray from the viewing point along ``direction`` (unit) meets the disc of
    ``radius`` (m) about ``to_centre`` (m, from the point) with unit ``normal``."""
    height = jnp.dot(to_centre, normal)
    along = jnp.dot(direction, normal)
    meets = height * along > 0
    t = height / where(meets, along, 1.0)
    miss = t * direction - to_centre
    return meets & (jnp.sum(miss * miss) < radius * radius)


def disc_solid_angle_local(in_plane_sq, height, radius, n_nodes: int = DEFAULT_NODES):
    """Solid angle (sr) of a disc from the viewpoint's position relative to it, elementwise.

    The rim integral of ``disc_solid_angle`` depends only on rho^2 = |q|^2 - (q . n)^2
    (``in_plane_sq``, m^2, the squared distance of the viewpoint's foot from the disc
    axis), h = |q . n| (``height``, m) and r (``radius``, m): with the rim parameter t
    measured from the foot's azimuth, q . e(t) = rho cos t. The nodes t and -t give
    equal terms, so n_nodes / 2 of them are summed (twice). Arrays of any broadcasting
    shapes; plain arithmetic on them (XLA fuses it into one loop), no 3-vectors. rho is
    taken with a zero-gradient square root at 0; the sum is even in rho, so gradients
    stay finite on the axis.
    """
    positive = in_plane_sq > 0
    rho = where(positive, jnp.sqrt(where(positive, in_plane_sq, 1.0)), 0.0)
    mean_sq = in_plane_sq + height * height + radius * radius
    mean_distance = jnp.sqrt(mean_sq)  # R0
    # the half-rim nodes on a trailing axis: one fused loop with a reduction, and an
    # HLO graph (compile time) independent of n_nodes
    cos_t = np.cos((np.arange(n_nodes // 2) + 0.5) * 2.0 * math.pi / n_nodes)
    rho, height, radius, mean_sq, mean_distance = (
        jnp.asarray(x)[..., None] for x in (rho, height, radius, mean_sq, mean_distance)
    )
    along = rho * jnp.asarray(cos_t, rho.dtype)
    distance = jnp.sqrt(jnp.maximum(mean_sq - 2.0 * radius * along, 0.0))  # R(t)
    terms = 1.0 / (distance * (distance + height)) - 2.0 * along * along * (
        1.0 + height / (distance + mean_distance)
    ) / (distance * mean_distance * (distance + height) * (mean_distance + height))
    return radius[..., 0] ** 2 * jnp.sum(terms, axis=-1) * (4.0 * math.pi / n_nodes)
