"""Direct light of a track at sensors seen from afar, from tables of the emission's
moments along the track: O(1) table reads per sensor instead of a quadrature.

For a sensor at distance a along the track and b across it from the track's start
(R0 = sqrt(a^2 + b^2), cos(theta0) = a / R0), the direct light is (``track_direct``)

    mu = int_0^S ds rho(s, u(s)) / L(s)^2 x J(s),
    J(s) = cos_in r^2 L^2 / (R_r (R_r + L)) x QE x A(cos_in) x exp(-L / lambda),

with L(s) = sqrt((a - s)^2 + b^2) the distance from the emission point, u(s) = (a - s) / L
the cosine under which the point sees the sensor, and R_r = sqrt(L^2 + r^2). The first
factor, w(s) = rho(s, u(s)) / L^2, is sharp (the Cherenkov peak) and depends on the
sensor only through (a, b) and the footprint width of the disc; J is smooth along the
track. In units of the light's extent S (x = s / S, rho' = R0 / S) the moments

    T_j(rho', cos(theta0)) = rho'^2 int_0^1 dx x^j rho^(x, u(x)) / ((a' - x)^2 + b'^2),
    j = 0 ... 3,

of the emission density rho^ normalised to one photon (T_2 and T_3 kept about the mean
T_1 / T_0) are a function of the geometry alone, tabulated once per energy node of the
emission model and footprint width (``emission.moments``). A sensor's light then
follows from a two-node Gauss rule for the measure w: its nodes and weights are those
of the orthogonal polynomials of these moments (exact for a J cubic in s), so

    mu = (yield / R0^2) x T_0 x (p_+ J(s_+) + p_- J(s_-)),

and the arrival-time mean and variance of the two nodes (track time + s / c + the
model's emission-time offset + the travel at the group velocity) give one
moment-matched arrival-time component.

The footprint: the density is averaged over the disc's footprint in cos as in
``track_direct``, with the half-width of the point of the track that sees the sensor
under the emission model's peak angle (``peak_cos``), between the model's
``FOOTPRINT_WIDTHS`` (Catmull-Rom, as the model itself). Between energy nodes the tables
are combined by cubic Hermite weights in log E (local, 4 nodes) on the shared rho'
axis, the way the model combines its densities along x = s / S.

Accurate for sensors seen from afar (J smooth over the light they see); the sensors
nearest the track's light are left to the quadrature (``track_direct``). Lengths m,
times ns, energies MeV.
"""

from __future__ import annotations

import jax.numpy as jnp

from ..constants import SPEED_OF_LIGHT
from ..emission.spline import _PATCH, _bicubic_weights, _footprint_terms
from ..numerics import smoothstep, where
from . import track_direct
from .optics import travel_time
from .track_direct import LIGHT_FLOOR

#: Width (m) of the smooth step that drops a Gauss node beyond the wall (the table holds
#: the whole track's moments; ``length`` cuts them at the nodes).
WALL_RAMP = 0.1


def _patch_values(root, layer, i, j):
    """(N, 16, M) entries of the bicubic patch of cell (i, j) (N,) of footprint ``layer``
    (N,) in ``root`` (W, 4, R, A, M), in ``_PATCH`` order (read per sensor: no table of
    cells is built per track)."""
    return jnp.stack([root[layer, dx + dy, i + cx, j + cy] for cx, dx, cy, dy in _PATCH],
                     axis=1)


def far_direct_light(positions, normals, radius, *, params, position, direction, time,
                     emission, peak, length=None):
    """Direct light of one track at discs seen from afar, from the ``MomentTable``
    (module docstring): one arrival-time component.

    Args:
        positions: (N, 3) disc centres, m. normals: (N, 3) inward unit normals.
        radius: (N,) disc radii, m.
        params: detector parameters (attenuation lengths m, QE, acceptance, group index).
        position: (3,) track start, m. direction: (3,) unit. time: start, ns.
        emission: the track's ``TabulatedSlice`` (``emission.moments``: its energy's
            ``EmissionSlice`` and moment table).
        peak: cos(angle to the track) of the model's peak (``track_direct.peak_cos``).
        length: light counts only for s <= length (m; the distance to the wall); None:
            the whole extent.

    Returns:
        (charge (N, C) p.e. of sensors of efficiency 1, mean arrival times (N, C) ns,
        variances (N, 1) ns^2) of the one component (without light: the time of
        light from the track start and variance 0).
    """
    dtype = positions.dtype
    root = emission.moment_root
    extent, total_yield = emission.extent, emission.total_yield
    along, across = track_direct.beside_track(positions, radius, position, direction)
    distance = jnp.sqrt(along * along + across * across)
    cos0 = along / distance
    # footprint half-width at the point that sees the sensor under the peak angle
    s_peak = jnp.clip(along - across * peak / jnp.sqrt(1.0 - peak * peak), 0.0, extent)
    to_peak = positions - (position + s_peak[:, None] * direction)
    peak_length, peak_cos_in, peak_reach, _ = track_direct.seen_disc(to_peak, normals,
                                                                     radius, params)
    width = track_direct.footprint_width(radius, peak_reach, (to_peak @ direction) / peak_length,
                                         peak_cos_in, normals @ direction)
    log_rho = jnp.log(distance / extent)
    patch, i, j = _bicubic_weights(emission.log_distance, emission.table_cos, log_rho, cos0)
    moments = 0.0
    for weight, layer in _footprint_terms(width, root.shape[0]):
        moments = moments + weight[:, None] * jnp.einsum(
            "np,npm->nm", patch, _patch_values(root, layer, i, j))
    moments = moments[:, None, :]  # one component
    nodes, node_weights = _gauss_nodes(moments)  # (N, C, 2) in x, fractions of T_0
    light0 = (total_yield / (distance * distance))[:, None] * jnp.maximum(moments[..., 0], 0.0)
    s = nodes * extent
    emitted = position + s[..., None] * direction  # (N, C, 2, 3)
    length_, _, _, share = track_direct.seen_disc(
        positions[:, None, None, :] - emitted, normals[:, None, None, :],
        radius[:, None, None], params)
    factor = share * length_ * length_
    if length is not None:  # the wall: a smooth cut, so the light moves continuously
        factor = factor * smoothstep((length - s) / WALL_RAMP + 0.5)
    light = light0[..., None] * node_weights * factor  # (N, C, 2)
    charge = jnp.sum(light, axis=-1)
    offset_mean, offset_variance = emission.time_moments(s)
    # arrival times relative to light from the start, so the variance does not cancel
    reference = (time + travel_time(distance, params))[:, None]
    arrival = (s / SPEED_OF_LIGHT + offset_mean + travel_time(length_, params)
               - travel_time(distance, params)[:, None, None])
    lit = charge > LIGHT_FLOOR
    safe = where(lit, charge, 1.0)
    mean = jnp.sum(light * arrival, axis=-1) / safe
    second = jnp.sum(light * (offset_variance + arrival * arrival), axis=-1) / safe
    return (charge, reference + where(lit, mean, 0.0),
            where(lit, jnp.maximum(second - mean * mean, 0.0), 0.0).astype(dtype))


#: Largest standardised skewness of the weight along the track the Gauss rule takes
#: (table interpolation can make a narrow weight's moments inconsistent).
SKEW_LIMIT = 8.0


def _gauss_nodes(moments):
    """Nodes (..., 2) in x = s / S and weights (..., 2) (fractions, summing to 1) of the
    two-node Gauss rule of a measure on [0, 1] with the moments (..., MOMENTS) (T_0, T_1,
    and the second and third moments about the mean T_1 / T_0): mean m, standard
    deviation sd and skewness g give the roots t = (g +- sqrt(g^2 + 4)) / 2 of the second
    orthogonal polynomial in (x - m) / sd."""
    tiny = jnp.finfo(moments.dtype).tiny
    total = jnp.maximum(moments[..., 0], tiny)
    mean = jnp.clip(moments[..., 1] / total, 0.0, 1.0)
    variance = jnp.clip(moments[..., 2] / total, 0.0, mean * (1.0 - mean))
    sd = jnp.sqrt(variance + 1e-12)
    skew = jnp.clip(moments[..., 3] / total / (sd * sd * sd), -SKEW_LIMIT, SKEW_LIMIT)
    root = jnp.sqrt(skew * skew + 4.0)
    upper, lower = 0.5 * (skew + root), 0.5 * (skew - root)
    nodes = jnp.clip(mean[..., None] + sd[..., None] * jnp.stack([upper, lower], axis=-1),
                     0.0, 1.0)
    weights = jnp.stack([-lower, upper], axis=-1) / root[..., None]
    return nodes, weights


#: Discs nearest the track's light whose direct light comes from the quadrature
#: (``track_direct``) instead of the table: beside the track the weight J varies over
#: the light a disc sees (a muon 2.8 m from the wall heading out: 2.8 % rms for the
#: tabulated light of discs 1-4 m from the track).
QUADRATURE_SENSORS = 128
#: ... blended in smoothly: a disc's weight rises from 0 at the nearness of the next disc
#: left out to 1 at (1 + ``QUADRATURE_BLEND``) times it.
QUADRATURE_BLEND = 0.5


def tabulated_direct_light(sensors, params, position, direction, time, emission,
                           length=None):
    """``track_direct.track_direct_light`` with the light of discs seen from afar read
    from the emission's moment table (``far_direct_light``); the
    ``QUADRATURE_SENSORS`` discs nearest the track's light by the quadrature, and the
    near field's sub-discs as there. ``emission``: a ``TabulatedSlice``. Returns
    (charge (N, C) p.e., mean arrival times (N, C) ns, variances (N, C) ns^2) of the C =
    ``track_direct.DIRECT_COMPONENTS`` components (the table's light in the first)."""
    extent = emission.extent if length is None else jnp.minimum(emission.extent, length)
    near = track_direct.near_field_size(sensors)
    if near <= 0:
        return track_direct.track_direct_light(sensors, params, position, direction, time,
                                               emission, length)
    light = track_direct.disc_light_of(params, position, direction, time, emission, extent)
    near_by = track_direct.nearness(sensors, position, direction, extent)
    far = far_direct_light(sensors.positions, sensors.normals, sensors.radius,
                           params=params, position=position, direction=direction,
                           time=time, emission=emission,
                           peak=track_direct.peak_cos(emission), length=length)
    pad = track_direct.DIRECT_COMPONENTS - 1
    charge, mean, variance = (jnp.concatenate([x, jnp.broadcast_to(fill, x.shape[:1] + (pad,))],
                                              axis=1)
                              for x, fill in zip(far, (0.0, far[1][:, :1], 0.0), strict=True))
    count = min(QUADRATURE_SENSORS, sensors.positions.shape[0] - 1)
    index, blend = track_direct.top_blend(near_by, count, relative_ramp=QUADRATURE_BLEND)
    quadrature = light(sensors.positions[index], sensors.normals[index],
                       sensors.radius[index],
                       breaks=track_direct._peak_breaks(emission, sensors.positions.dtype))
    base = track_direct.blend_into((charge, mean, variance), index, quadrature, blend)
    return track_direct.refine_near_field(base, sensors, near_by, light, near)
