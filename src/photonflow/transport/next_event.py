"""Next-event estimates of the indirect light: what a vertex sends to every sensor.

From a vertex (a bulk scatter, a wall reflection or a reflection off a sensor's glass)
of a ray with weight w (expected photons), the light reaching sensor j directly is

    w x redirection density toward j (per sr) x Omega_j x QE x A(theta_in)
      x exp(-rate_total d_j),

arriving at the ray's time + d_j n_g / c: the redirection density is the phase function
of a scatter (rate_rayleigh p_R + rate_mie p_HG, per m), the Lambertian part of a wall
reflection (wall_reflectivity (1 - specular fraction) cos_out / pi) or the glass's
(sensor_reflectivity x ``dome_reflection_density``); Omega_j the disc's solid angle
(``far_solid_angle``; exact for discs within ``sensor_arrays.NEAR_RADII`` radii, by
``near_correction_sums``). The light is that of a sensor of relative efficiency 1
before its time offset (the sensor response applies both). Times are accumulated
relative to a per-sensor reference time (float32 accuracy). Lengths m, times ns.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from ..geometry.sensor_arrays import Sensors
from ..geometry.sensor_grid import grid_candidates
from ..geometry.solid_angle import disc_solid_angle_local
from ..numerics import where
from ..response.detection import acceptance_at_cos
from .optics import (
    dome_reflection_density_cos,
    henyey_greenstein_density,
    interaction_rates,
    lambertian_density,
    rayleigh_density,
    travel_time,
)

#: Rays whose next-event estimates are computed together (bounds memory to ~ block x N).
NEE_BLOCK = 128
#: Rim nodes of the exact solid angle of discs near a vertex.
NEAR_NODES = 32
#: Vertex kinds.
SCATTER, WALL, GLASS = 0, 1, 2
#: Sums of a next-event estimate: c, c t, c t^2 of every vertex, then of the bulk scatters.
NEE_SUMS = 6


def far_solid_angle(distance, cos_in, radius):
    """Solid angle (sr) of a disc (radius m) seen from distance d (m) at incidence cos_in.

    The on-axis value 2 pi r^2 / (R (R + d)), R = sqrt(d^2 + r^2), tilted by cos_in and
    corrected to second order in (r / d): x (1 + 15/8 (r/d)^2 sin^2). Relative error
    below 1 % for d > 4 r at any incidence; nearer discs are computed exactly
    (``near_correction_sums``).
    """
    r2 = radius * radius
    hypot = jnp.sqrt(distance * distance + r2)
    cos_in = jnp.maximum(cos_in, 0.0)
    tilt = 1.0 + 1.875 * r2 / (distance * distance) * (1.0 - cos_in * cos_in)
    return jnp.minimum(
        cos_in * (2.0 * math.pi) * r2 / (hypot * (hypot + distance)) * tilt, 2.0 * math.pi
    )


def redirection(params, config, cos_turn, cos_out, in_normal, kind):
    """Per-sr density of light leaving a vertex, from the cosines of the outgoing
    direction u with the incoming direction i (``cos_turn``) and with the surface normal n
    (``cos_out``), and i . n (``in_normal``): phase function for a scatter, Lambertian for a
    wall, the dome reflection density (u . n - i . n) / (4 pi (1 - u . i)) for glass."""
    _, rate_rayleigh, rate_mie, _ = interaction_rates(params)
    scatter_density = rate_rayleigh * rayleigh_density(
        cos_turn, config.rayleigh_anisotropy
    ) + rate_mie * henyey_greenstein_density(cos_turn, params.mie_g)
    wall_density = (
        params.wall_reflectivity
        * (1.0 - params.wall_specular_fraction)
        * lambertian_density(cos_out)
    )
    glass_density = params.sensor_reflectivity * dome_reflection_density_cos(
        cos_turn, cos_out, in_normal
    )
    return where(
        kind == SCATTER, scatter_density, where(kind == WALL, wall_density, glass_density)
    )


def dot(a, b):
    """Dot product of two component 3-tuples."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def pair_light(params, config, vertex, d_in, wall_n, kind, positions, normals):
    """Geometry and light factors of vertex-sensor pairs, on x, y, z components.

    ``vertex``, ``d_in`` (incoming direction), ``wall_n`` (surface normal at the vertex)
    are 3-tuples of (R, 1) arrays, ``kind`` (R, 1); ``positions`` and ``normals`` 3-tuples
    of sensor arrays broadcasting against them ((1, N) or (R, K)). Components are kept
    apart (structure of arrays) so that XLA fuses every pair's arithmetic into one loop.
    Returns (distance m, cos_in, factor): factor = redirection density x attenuation x
    acceptance x QE (per sr per unit weight, before the solid angle).
    """
    offset = tuple(p - v for p, v in zip(positions, vertex, strict=True))
    distance = jnp.sqrt(jnp.maximum(dot(offset, offset), 1e-12))
    inverse = 1.0 / distance
    cos_in = -dot(offset, normals) * inverse
    cos_turn = dot(offset, d_in) * inverse
    cos_out = dot(offset, wall_n) * inverse
    density = redirection(params, config, cos_turn, cos_out, dot(d_in, wall_n), kind)
    factor = (
        density
        * jnp.exp(-interaction_rates(params)[3] * distance)
        * acceptance_at_cos(params.angular_acceptance, jnp.maximum(cos_in, 0.0))
        * params.quantum_efficiency
    )
    return distance, cos_in, factor


def components(vectors):
    """(..., 3) -> 3-tuple of (..., 1) arrays (a trailing pair axis)."""
    return tuple(vectors[..., k, None] for k in range(3))


def vertex_pair_light(params, config, vertex, d_in, wall_n, kind, positions, normals):
    """``pair_light`` of R vertices (``vertex``, incoming direction ``d_in`` and surface
    normal ``wall_n`` (R, 3), ``kind`` (R,)) with sensors at ``positions`` (m) and
    ``normals`` (..., 3) that broadcast against (R, 1, 3): (1, N, 3) for every sensor,
    (R, K, 3) for candidates per vertex. Returns (distance m, cos_in, factor)."""
    return pair_light(
        params, config, components(vertex), components(d_in), components(wall_n),
        kind[:, None], tuple(positions[..., k] for k in range(3)),
        tuple(normals[..., k] for k in range(3)),
    )


def next_event_sums(
    params, sensors: Sensors, config, reference, vertex, weight, time, kind, d_in, wall_n,
    own_disc,
):
    """NEE of one vertex per ray to every sensor: ``NEE_SUMS`` (N,) sums, those of c, c t,
    c t^2 (t - reference) over every vertex, then over the bulk-scatter vertices alone
    (``kind`` SCATTER); c in p.e. of a sensor of efficiency 1.

    ``own_disc`` (R,) is the sensor each vertex leaves out (N for none)."""
    distance, cos_in, factor = vertex_pair_light(
        params, config, vertex, d_in, wall_n, kind, sensors.positions[None],
        sensors.normals[None],
    )
    n = sensors.positions.shape[0]
    solid_angle = far_solid_angle(distance, cos_in, sensors.radius)
    contribution = weight[:, None] * factor * solid_angle
    own = own_disc[:, None] == jnp.arange(n, dtype=own_disc.dtype)
    contribution = where(own, 0.0, contribution)
    relative = time[:, None] + travel_time(distance, params) - reference
    return tuple(jnp.sum(c, axis=0) for c in _weighted_by_time(contribution, relative, kind))


def near_correction_sums(
    params, sensors: Sensors, config, reference, vertex, weight, time, kind, d_in, wall_n,
    own_disc,
):
    """Exact-minus-far solid-angle correction of the NEE for the sensors near each vertex
    (the candidates of ``sensors.near_grid``, which lists every sensor within 4 radii):
    the ``NEE_SUMS`` (N,) sums of ``next_event_sums``; ``own_disc`` (R,) gets none."""
    n = sensors.positions.shape[0]
    candidates = grid_candidates(sensors.near_grid, vertex)  # (R, K)
    valid = candidates >= 0
    index = where(valid, candidates, 0)
    positions = sensors.positions[index]
    normals = sensors.normals[index]
    radius = sensors.radius[index]
    distance, cos_in, factor = vertex_pair_light(
        params, config, vertex, d_in, wall_n, kind, positions, normals
    )
    # Pairs that cannot see each other (discs facing away, the disc a glass vertex lies
    # on) are evaluated at a harmless point and dropped, keeping gradients finite.
    seen = valid & (cos_in > 1e-6)
    left_out = candidates == own_disc[:, None]
    from_centre = where(seen[..., None], vertex[:, None, :] - positions, normals)
    height = jnp.abs(jnp.sum(from_centre * normals, axis=-1))
    in_plane_sq = jnp.maximum(jnp.sum(from_centre * from_centre, axis=-1) - height**2, 0.0)
    exact = disc_solid_angle_local(in_plane_sq, height, radius, NEAR_NODES)
    delta = where(seen & ~left_out, exact - far_solid_angle(distance, cos_in, radius), 0.0)
    contribution = weight[:, None] * factor * delta
    relative = time[:, None] + travel_time(distance, params) - reference[index]
    zeros = jnp.zeros(n, dtype=contribution.dtype)
    flat = index.reshape(-1)
    return tuple(zeros.at[flat].add(c.reshape(-1))
                 for c in _weighted_by_time(contribution, relative, kind))


def _weighted_by_time(contribution, relative, kind):
    """The ``NEE_SUMS`` summands of (R, ...) pair contributions c with times t relative
    to the reference (ns): c, c t, c t^2, then the same of the rows whose vertex
    ``kind`` (R,) is SCATTER."""
    scattered = where((kind == SCATTER).reshape((-1,) + (1,) * (contribution.ndim - 1)),
                      contribution, 0.0)
    return tuple(x for c in (contribution, scattered)
                 for x in (c, c * relative, c * relative * relative))


def nee_in_blocks(nee_block, n: int, dtype, vertex_data):
    """Next-event sums (``NEE_SUMS`` x (N,)) of R vertices, ``NEE_BLOCK`` rays at a time (memory ~
    NEE_BLOCK x N, not R x N); ``vertex_data`` are (R, ...) arrays, the second the
    weights (padding rays get weight 0)."""
    n_rays = vertex_data[0].shape[0]
    block = min(NEE_BLOCK, n_rays)
    pad = -n_rays % block
    padded = [jnp.pad(x, [(0, pad)] + [(0, 0)] * (x.ndim - 1)) for x in vertex_data]
    padded[1] = padded[1].at[n_rays:].set(0.0)
    blocks = [x.reshape((-1, block) + x.shape[1:]) for x in padded]

    def accumulate(total, data):
        return tuple(a + b for a, b in zip(total, nee_block(*data), strict=True)), None

    zeros = tuple(jnp.zeros(n, dtype=dtype) for _ in range(NEE_SUMS))
    return jax.lax.scan(accumulate, zeros, blocks)[0]
