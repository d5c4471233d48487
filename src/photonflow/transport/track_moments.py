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

of the emission density rho^ normalised to one photon are a function of the geometry
alone, tabulated once per energy node of the emission model and footprint width
(``MomentTable``, ``moment_table``). A sensor's light then follows from a two-node
Gauss rule for the measure w: its nodes and weights are those of the orthogonal
polynomials of the moments T_0 ... T_3 (exact for a J cubic in s), so

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

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..constants import SPEED_OF_LIGHT
from ..emission.spline import (
    SplineEmission,
    _bicubic_weights,
    _cell_blocks,
    _cell_widths,
    _footprint_terms,
)
from ..numerics import safe_sqrt, where
from ..pytree import pytree_dataclass
from ..response.detection import acceptance_at_cos
from .optics import interaction_rates, travel_time

#: Moments x^0 ... x^3 of the emission weight along the track (a two-node Gauss rule).
MOMENTS = 4
#: Distance axis: rho' = R0 / S, log-spaced (``DISTANCE_KNOTS`` knots) over this range;
#: beyond it the table's end values hold (rho'^2 T_j tends to the angular profile).
DISTANCE_RANGE = (0.05, 500.0)
DISTANCE_KNOTS = 41
#: Footprint widths tabulated: the first this many of ``FOOTPRINT_WIDTHS`` (half-widths
#: up to 0.64 in cos: a disc of radius r seen from 1.6 r).
FOOTPRINT_LAYERS = 9
#: Cos axis: the model's cos knots, with midpoints added this many times.
COS_REFINE = 0


@pytree_dataclass
class MomentTable:
    """Moments of an emission model's light along the track, by energy node, footprint
    width and geometry (module docstring).

    Attributes:
        log_energy: (K,) the model's energy nodes, log(MeV).
        log_distance: (R,) knots in log(rho'), rho' = R0 / S.
        cos: (A,) knots in cos(theta0) (the model's cos knots).
        values: (K, W, R, A, MOMENTS) rho'^2 T_j per node, footprint layer and knot
            (photons per photon emitted).
        extent: (K,) the light's extent S per node, m.
        total_yield: (K,) photons per particle per node.
    """

    log_energy: jax.Array
    log_distance: jax.Array
    cos: jax.Array
    values: jax.Array
    extent: jax.Array
    total_yield: jax.Array


def moment_table(model: SplineEmission) -> MomentTable:
    """The ``MomentTable`` of ``model`` (arrays of the model's dtype), built once per
    model object: K x ``FOOTPRINT_LAYERS`` x R x A integrals of the model's density along
    the track by Gauss-Legendre panels in u that end at the model's cos knots and at the
    cosines of its knots along the track."""
    return _cached_table(model)


@functools.cache
def _cached_table(model: SplineEmission) -> MomentTable:
    with jax.ensure_compile_time_eval():
        dtype = model.root.dtype
        log_distance = np.linspace(math.log(DISTANCE_RANGE[0]), math.log(DISTANCE_RANGE[1]),
                                   DISTANCE_KNOTS)
        knots = np.asarray(model.cos, np.float64)
        for _ in range(COS_REFINE):
            knots = np.sort(np.concatenate([knots, 0.5 * (knots[1:] + knots[:-1])]))
        cos = jnp.asarray(knots, dtype)
        rows = []
        for k in range(model.log_energy.shape[0]):
            rows.append(_node_moments(model.root[k, :FOOTPRINT_LAYERS], model.fraction,
                                      model.cos, jnp.asarray(log_distance, dtype), cos))
        return MomentTable(
            log_energy=model.log_energy,
            log_distance=jnp.asarray(log_distance, dtype),
            cos=cos,
            values=jnp.stack(rows),
            extent=model.extent,
            total_yield=model.total_yield,
        )


@jax.jit
def _node_moments(root, fraction, cos, log_distance, table_cos):
    """(W, R, A', MOMENTS) table values of one energy node's ``root`` (W, 4, D, A) at the
    knots ``log_distance`` (R,) and ``table_cos`` (A',)."""
    cells = _cell_blocks(root)
    knots_sum = jnp.sum(root[0, 0] ** 2 * _cell_widths(fraction)[:, None]
                        * _cell_widths(cos)[None, :])
    norm = jnp.where(knots_sum > 0, 1.0 / jnp.where(knots_sum > 0, knots_sum, 1.0), 0.0)
    rho = jnp.exp(log_distance)[:, None]  # (R, 1)
    c = table_cos[None, :]  # (1, A')
    sine = jnp.sqrt(1.0 - c * c)
    a, b = rho * c, rho * sine  # (R, A)
    u_start = jnp.broadcast_to(c, a.shape)
    u_end = (a - 1.0) / jnp.sqrt((a - 1.0) ** 2 + b * b)
    seen = (a[..., None] - fraction) / jnp.sqrt((a[..., None] - fraction) ** 2
                                                 + (b * b)[..., None])
    fixed = jnp.clip(jnp.broadcast_to(cos, a.shape + cos.shape), u_end[..., None],
                     u_start[..., None])
    ends = jnp.sort(jnp.concatenate([fixed, seen, u_end[..., None], u_start[..., None]],
                                    axis=-1), axis=-1)
    low, high = ends[..., :-1], ends[..., 1:]
    nodes, weights = np.polynomial.legendre.leggauss(2)
    nodes, weights = jnp.asarray(0.5 * (nodes + 1.0), a.dtype), jnp.asarray(0.5 * weights, a.dtype)
    width = (high - low)[..., None]
    u = (low[..., None] + width * nodes).reshape(a.shape + (-1,))  # (R, A, M)
    du = (width * weights).reshape(u.shape)
    sin_u = jnp.sqrt(jnp.maximum(1.0 - u * u, jnp.finfo(a.dtype).tiny))
    x = a[..., None] - b[..., None] * u / sin_u
    inside = (x >= 0.0) & (x <= 1.0)
    x = jnp.clip(x, 0.0, 1.0)
    patch, i, j = _bicubic_weights(fraction, cos, x, u)
    factor = du / sin_u * (rho / sine)[..., None] * norm
    powers = jnp.stack([x**m for m in range(MOMENTS)], axis=-1)  # (R, A, M, MOMENTS)

    def layer(block):
        value = jnp.sum(patch * block[i, j], axis=-1)
        weight = where(inside, value * value * factor, 0.0)
        return jnp.einsum("ram,ramj->raj", weight, powers)

    return jax.lax.map(layer, cells)


def _energy_terms(log_energy, energy):
    """(weights (4,), node indices (4,)) of cubic Hermite interpolation in log E between
    the nodes ``log_energy`` (finite-difference slopes, C1); E (MeV) clamped to the
    nodes."""
    count = log_energy.shape[0]
    x = jnp.clip(jnp.log(energy), log_energy[0], log_energy[-1])
    i = jnp.clip(jnp.searchsorted(log_energy, x, side="right") - 1, 0, count - 2)
    h = log_energy[i + 1] - log_energy[i]
    t = (x - log_energy[i]) / h
    t2, t3 = t * t, t * t * t
    h00, h10, h01, h11 = 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, -2 * t3 + 3 * t2, t3 - t2
    idx = jnp.clip(i + jnp.arange(-1, 3, dtype=i.dtype), 0, count - 1)  # nodes i-1, i, i+1, i+2
    xs = log_energy[idx]
    # slope at node i: (f[i+1] - f[i-1]) / (x[i+1] - x[i-1]), one-sided at the ends
    left = (xs[2] - xs[0])
    right = (xs[3] - xs[1])
    w_left = jnp.stack([-1.0 / left, 0.0 * h, 1.0 / left, 0.0 * h]) * h
    w_right = jnp.stack([0.0 * h, -1.0 / right, 0.0 * h, 1.0 / right]) * h
    base = jnp.stack([0.0 * h, h00, h01, 0.0 * h])
    return base + h10 * w_left + h11 * w_right, idx


def _slopes(values, knots, axis):
    """Finite-difference slopes of ``values`` along ``axis`` on the nonuniform ``knots``
    (central inside, one-sided at the ends)."""
    v = jnp.moveaxis(values, axis, 0)
    central = (v[2:] - v[:-2]) / (knots[2:] - knots[:-2]).reshape((-1,) + (1,) * (v.ndim - 1))
    first = (v[1:2] - v[:1]) / (knots[1] - knots[0])
    last = (v[-1:] - v[-2:-1]) / (knots[-1] - knots[-2])
    return jnp.moveaxis(jnp.concatenate([first, central, last]), 0, axis)


def track_table(table: MomentTable, energy):
    """The moment table at ``energy`` (MeV, clamped to the nodes): cells (W, R - 1, A - 1,
    16, MOMENTS) of bicubic Hermite patches in (log rho', cos)."""
    weights, idx = _energy_terms(table.log_energy, energy)
    values = jnp.tensordot(weights, table.values[idx], axes=1)  # (W, R, A, MOMENTS)
    d_r = _slopes(values, table.log_distance, 1)
    d_c = _slopes(values, table.cos, 2)
    d_rc = _slopes(d_r, table.cos, 2)
    root = jnp.stack([values, d_r, d_c, d_rc], axis=1)  # (W, 4, R, A, MOMENTS)
    cells = jnp.moveaxis(_cell_blocks(jnp.moveaxis(root, -1, 0).reshape(
        (-1,) + root.shape[1:4])).reshape((root.shape[-1], root.shape[0])
                                          + (root.shape[2] - 1, root.shape[3] - 1, 16)),
        0, -1)
    return cells


def far_direct_light(positions, normals, radius, *, params, position, direction, time,
                     table: MomentTable, energy, emission, peak, length=None):
    """Direct light of one track at discs seen from afar, from the ``MomentTable``
    (module docstring): one arrival-time component per disc.

    Args:
        positions: (N, 3) disc centres, m. normals: (N, 3) inward unit normals.
        radius: (N,) disc radii, m.
        params: detector parameters (attenuation lengths m, QE, acceptance, group index).
        position: (3,) track start, m. direction: (3,) unit. time: start, ns.
        table: the emission model's ``MomentTable``. energy: kinetic energy, MeV.
        emission: the track's ``EmissionSlice`` (its extent, yield and emission-time
            offsets).
        peak: cos(angle to the track) of the model's peak (``track_direct.peak_cos``).
        length: light counts only for s <= length (m; the distance to the wall); None:
            the whole extent.

    Returns:
        (charge (N,) p.e. of sensors of efficiency 1, mean arrival time (N,) ns, variance
        (N,) ns^2).
    """
    dtype = positions.dtype
    cells = track_table(table, energy)
    extent, total_yield = emission.extent, emission.total_yield
    offset = positions - position
    along = offset @ direction
    across2 = jnp.maximum(jnp.sum(offset * offset, axis=-1) - along * along, 0.0)
    soft = 0.25 * radius
    across = jnp.sqrt(across2 + soft * soft)
    distance = jnp.sqrt(along * along + across * across)
    cos0 = along / distance
    # footprint half-width at the point that sees the sensor under the peak angle
    s_peak = jnp.clip(along - across * peak / jnp.sqrt(1.0 - peak * peak), 0.0, extent)
    width = _footprint_width(positions, normals, radius, position, direction, s_peak)
    log_rho = jnp.log(distance / extent)
    patch, i, j = _bicubic_weights(table.log_distance, table.cos, log_rho, cos0)
    moments = 0.0
    for weight, layer in _footprint_terms(width, cells.shape[0]):
        moments = moments + weight[:, None] * jnp.einsum(
            "np,npm->nm", patch, cells[layer, i, j])
    nodes, node_weights = _gauss_nodes(moments)  # (N, 2) in x, fractions of T_0
    light0 = total_yield / (distance * distance) * jnp.maximum(moments[:, 0], 0.0)
    s = nodes * extent
    emitted = position + s[..., None] * direction  # (N, 2, 3)
    to_sensor = positions[:, None, :] - emitted
    length_ = jnp.sqrt(jnp.sum(to_sensor * to_sensor, axis=-1) + soft[:, None] ** 2)
    cos_in = -jnp.sum(to_sensor * normals[:, None, :], axis=-1) / length_
    radius2 = (radius * radius)[:, None]
    reach = jnp.sqrt(length_ * length_ + radius2)
    factor = (jnp.maximum(cos_in, 0.0) * radius2 * length_ * length_ / (reach * (reach + length_))
              * params.quantum_efficiency
              * acceptance_at_cos(params.angular_acceptance, cos_in)
              * jnp.exp(-interaction_rates(params)[3] * length_))
    if length is not None:
        factor = where(s <= length, factor, 0.0)
    light = light0[:, None] * node_weights * factor  # (N, 2)
    charge = jnp.sum(light, axis=1)
    offset_mean, offset_variance = emission.time_moments(s)
    arrival = time + s / SPEED_OF_LIGHT + offset_mean + travel_time(length_, params)
    lit = charge > 1e-12
    safe = where(lit, charge, 1.0)
    mean = jnp.sum(light * arrival, axis=1) / safe
    second = jnp.sum(light * (offset_variance + arrival * arrival), axis=1) / safe
    reference = time + travel_time(distance, params)
    return (charge, where(lit, mean, reference),
            where(lit, jnp.maximum(second - mean * mean, 0.0), 0.0).astype(dtype))


def _footprint_width(positions, normals, radius, position, direction, s):
    """Half-width in cos of the footprint of each disc seen from the point s (N,) m of
    the track (``track_direct``: sin(theta) x its angular half-size along theta)."""
    to_sensor = positions - (position + s[:, None] * direction)
    distance2 = jnp.sum(to_sensor * to_sensor, axis=-1)
    length = jnp.sqrt(distance2 + (0.25 * radius) ** 2)
    u = (to_sensor @ direction) / length
    cos_in = -jnp.sum(to_sensor * normals, axis=-1) / length
    reach = jnp.sqrt(length * length + radius * radius)
    facing = normals @ direction
    sin2 = jnp.maximum(1.0 - u * u, 0.0)
    return radius / reach * safe_sqrt(jnp.maximum(sin2 - (u * cos_in + facing) ** 2, 0.0))


#: Largest standardised skewness of the weight along the track the Gauss rule takes
#: (table interpolation can make a narrow weight's moments inconsistent).
SKEW_LIMIT = 8.0


def _gauss_nodes(moments):
    """Nodes (N, 2) in x = s / S and weights (N, 2) (fractions, summing to 1) of the
    two-node Gauss rule of a measure on [0, 1] with the raw moments (N, MOMENTS) T_0 ...
    T_3: mean m, standard deviation sd and skewness g give the roots
    t = (g +- sqrt(g^2 + 4)) / 2 of the second orthogonal polynomial in (x - m) / sd."""
    tiny = jnp.finfo(moments.dtype).tiny
    total = jnp.maximum(moments[:, 0], tiny)
    m1, m2, m3 = (moments[:, k] / total for k in (1, 2, 3))
    mean = jnp.clip(m1, 0.0, 1.0)
    variance = jnp.clip(m2 - mean * mean, 0.0, mean * (1.0 - mean))
    sd = jnp.sqrt(variance + 1e-12)
    third = m3 - 3.0 * mean * m2 + 2.0 * mean**3
    skew = jnp.clip(third / (sd * sd * sd), -SKEW_LIMIT, SKEW_LIMIT)
    root = jnp.sqrt(skew * skew + 4.0)
    upper, lower = 0.5 * (skew + root), 0.5 * (skew - root)
    nodes = jnp.clip(mean[:, None] + sd[:, None] * jnp.stack([upper, lower], axis=1), 0.0, 1.0)
    weights = jnp.stack([-lower, upper], axis=1) / root[:, None]
    return nodes, weights
