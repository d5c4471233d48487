"""The weighted rays of the indirect light: emission, tracing, vertex proposal and
continuation (the module docstring of ``indirect.py`` gives the whole estimator).

A ray leaves the source with weight N / n_rays (expected photons) in a direction from a
shifted Fibonacci lattice through the source's inverse CDF (``emitted_rays``). At each
order ``vertex_step`` traces its segment (``trace``), proposes the next vertex (a bulk
scatter with probability 1/2 at s uniform in [0, t_end], else the segment's end: the
wall, or the sensor glass if a sensor was hit), asks the next-event estimate of the
vertex, and draws the continuation and the specular probes leaving it from one
proposal (``leaving``, ``outgoing``). No proposal depends on ``Params``: the rays'
geometry is fixed by the key and the source, and parameters enter through weights and
times only. Lengths m, times ns.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.sensor_arrays import Sensors
from ..geometry.sensor_grid import first_sensor_hit
from ..geometry.shapes import Shape
from ..numerics import where
from ..pytree import pytree_dataclass
from .emission import sample_directions
from .next_event import GLASS, SCATTER, WALL
from .optics import (
    deflect,
    dome_normal,
    henyey_greenstein_density,
    interaction_rates,
    lambertian_direction,
    orthonormal_basis,
    rayleigh_density,
    sample_henyey_greenstein_cos,
    sample_rayleigh_cos,
    specular_direction,
    travel_time,
)

#: Uniform random numbers drawn per ray and vertex.
UNIFORMS_PER_VERTEX = 8


@pytree_dataclass
class Rays:
    """The rays between two vertices: origins (R, 3) m, unit directions (R, 3),
    expected photons (R,), time at the origin (R,) ns, and the disc each origin lies on
    (R,) int (N for none)."""

    origins: jax.Array
    directions: jax.Array
    weight: jax.Array
    time: jax.Array
    on_disc: jax.Array


@pytree_dataclass
class Probes:
    """Specular probe rays (P of them): origins (P, 3) m, unit directions (P, 3),
    expected photons (P,), time at the origin (P,) ns, and the order (P,) int of the
    vertex they leave (0: the source)."""

    origins: jax.Array
    directions: jax.Array
    weight: jax.Array
    time: jax.Array
    order: jax.Array


def shifted_lattice(key, n: int, dtype):
    """(2, n) points of the Fibonacci lattice (i + 1/2) / n, frac(i / phi) shifted by one
    uniform random vector from ``key`` (mod 1): each point is uniform on the unit square,
    so estimates stay unbiased, and together they cover it far more evenly than
    independent points (randomised quasi-Monte Carlo for the emission directions)."""
    index = np.arange(n)
    lattice = np.stack([(index + 0.5) / n, np.mod(index * (math.sqrt(5.0) - 1.0) / 2.0, 1.0)])
    shift = jax.random.uniform(key, (2, 1), dtype=dtype)
    return jnp.mod(jnp.asarray(lattice, dtype) + shift, 1.0)


def leaving_source(source, key, count: int, dtype) -> dict:
    """``count`` rays leaving the source with N / count photons each: their origins
    (count, 3) m, unit directions (count, 3) from a shifted Fibonacci lattice (``key``)
    through the source's inverse CDF, expected photons (count,) and times (count,) ns,
    as the fields of a ``Rays`` or ``Probes``. An emitter with its own ``leaving(key,
    count, dtype)`` (a track, ``track_rays.TrackEmitter``) makes them itself."""
    if hasattr(source, "leaving"):
        return source.leaving(key, count, dtype)
    u_emit = shifted_lattice(key, count, dtype)
    return {
        "origins": jnp.broadcast_to(source.position, (count, 3)),
        "directions": sample_directions(source, u_emit[0], u_emit[1]),
        "weight": jnp.broadcast_to(source.n_photons / count, (count,)).astype(dtype),
        "time": jnp.broadcast_to(source.time, (count,)).astype(dtype),
    }


def emitted_rays(source, key, n_rays: int, n_sensors: int, dtype) -> Rays:
    """``n_rays`` rays leaving the source (``leaving_source``), on no disc."""
    return Rays(**leaving_source(source, key, n_rays, dtype),
                on_disc=jnp.full(n_rays, n_sensors, dtype=jnp.int32))


def trace(shape: Shape, sensors: Sensors, origins, directions):
    """Segment ends: (t_end m, sensor index or -1, hit bool, alive bool). A ray that
    starts on the wall heading out (light the sensor glass sends below its disc's plane)
    meets the wall at distance 0, as in the sampled mode."""
    t_wall = shape.ray_exit(origins, directions)
    alive = jnp.isfinite(t_wall)
    t_wall = where(alive, jnp.maximum(t_wall, 0.0), 0.0)
    # standard promotion: grid_candidates mixes int32 cells with int64 dims under x64
    with jax.numpy_dtype_promotion("standard"):
        index, t_sensor = first_sensor_hit(
            sensors.grid, sensors.positions, sensors.normals, sensors.radius, origins,
            directions, t_wall,
        )
    hit = alive & (index >= 0)
    t_end = where(hit, t_sensor, t_wall)
    return t_end, where(hit, index, 0), hit, alive


def residual_weight(params, shape_has_walls, weight, t_end, hit):
    """Expected photons that would undergo one more vertex on the traced segment."""
    _, rate_rayleigh, rate_mie, rate_total = interaction_rates(params)
    x = rate_total * t_end
    safe_rate = where(x > 0, rate_total, 1.0)
    interact_length = where(x > 0, -jnp.expm1(-x) / safe_rate, t_end)
    wall = params.wall_reflectivity if shape_has_walls else 0.0
    reflect = where(hit, params.sensor_reflectivity, wall)
    return jnp.sum(weight * ((rate_rayleigh + rate_mie) * interact_length + jnp.exp(-x) * reflect))


def outgoing(params, config, kind, directions, normal, u, glass_direction):
    """Direction leaving a vertex and its weight factor, from uniforms ``u`` (8, R) (rows
    2-7; rows 0-1 choose the vertex): after a scatter, drawn with probability 1/2 each
    from the Rayleigh phase function or the fixed Henyey-Greenstein proposal, factor
    (rate_R p_R + rate_M p_HG(g)) / (p_R / 2 + p_HG(g_q) / 2) per m; after a wall,
    specular (proposal 1/2, factor R_w f_s / 0.5) or Lambertian (R_w (1 - f_s) / 0.5);
    after the glass, ``glass_direction``, factor R_s. No proposal depends on ``Params``.
    Returns (directions (R, 3), factor (R,))."""
    anisotropy = config.rayleigh_anisotropy
    proposal_g = jnp.asarray(config.mie_proposal_asymmetry, directions.dtype)
    _, rate_rayleigh, rate_mie, _ = interaction_rates(params)
    rayleigh = u[2] < 0.5
    cos_theta = where(
        rayleigh,
        sample_rayleigh_cos(u[3], anisotropy),
        sample_henyey_greenstein_cos(u[3], proposal_g),
    )
    p_rayleigh = rayleigh_density(cos_theta, anisotropy)
    p_proposal = henyey_greenstein_density(cos_theta, proposal_g)
    p_mie = henyey_greenstein_density(cos_theta, params.mie_g)
    scatter_weight = (rate_rayleigh * p_rayleigh + rate_mie * p_mie) / (
        0.5 * p_rayleigh + 0.5 * p_proposal
    )
    scatter_direction = deflect(directions, cos_theta, 2.0 * math.pi * u[4])
    mirror = u[5] < 0.5
    reflected = where(
        mirror[:, None],
        specular_direction(directions, normal),
        lambertian_direction(normal, u[6], u[7]),
    )
    wall_weight = (
        params.wall_reflectivity
        * where(mirror, params.wall_specular_fraction, 1.0 - params.wall_specular_fraction)
        / 0.5
    )
    is_scatter = (kind == SCATTER)[:, None]
    is_wall = (kind == WALL)[:, None]
    directions = where(
        is_scatter, scatter_direction, where(is_wall, reflected, glass_direction)
    )
    directions = directions / jnp.linalg.norm(directions, axis=-1, keepdims=True)
    factor = where(
        kind == SCATTER,
        scatter_weight,
        where(kind == WALL, wall_weight, params.sensor_reflectivity),
    )
    return directions, factor


def disc_point(normal, radius, u1, u2):
    """Offset (R, 3) m from a disc's centre of a point uniform on the disc (unit
    ``normal`` (R, 3), ``radius`` (R,) m) from uniforms u1, u2 (R,)."""
    e1, e2 = orthonormal_basis(normal)
    rho = (radius * jnp.sqrt(u1))[:, None]
    phi = (2.0 * math.pi * u2)[:, None]
    return rho * (jnp.cos(phi) * e1 + jnp.sin(phi) * e2)


def leaving(propose, sensors, u_all, vertex, index, kind, directions, continuation=True):
    """The continuation and the probes leaving the vertices, from one proposal
    (``propose``: ``outgoing`` with its vertex arguments bound): ``u_all`` (8, K, R)
    uniforms, set 0 the continuation (if ``continuation``), the others probes. Off the
    glass the continuation is mirrored about the dome where the ray crossed the disc; a
    probe leaves a point drawn uniformly on the disc, mirrored about the dome there, as
    the NEE's ``dome_reflection_density`` assumes. Returns (origins (K, R, 3) m, unit
    directions (K, R, 3), weight factors (K, R)); the continuation leaves the vertex
    itself."""
    centre, disc_normal = sensors.positions[index], sensors.normals[index]
    disc_radius = sensors.radius[index]
    glass = (kind == GLASS)[:, None]

    def one(u, drawn):
        crossing = where(drawn, disc_point(disc_normal, disc_radius, u[6], u[7]), vertex - centre)
        dome = dome_normal(crossing, disc_normal, disc_radius)
        direction, factor = propose(u, specular_direction(directions, dome))
        origin = where(glass & drawn, centre + crossing, vertex)
        return origin, direction, factor

    drawn = jnp.arange(u_all.shape[1]) >= (1 if continuation else 0)
    return jax.vmap(one, in_axes=(1, 0))(u_all, drawn)


def vertex_step(params, shape, sensors: Sensors, config, nee, vertex_key, probe_key,
                rays: Rays, order):
    """One vertex per ray (scan body): trace the segment, propose the vertex (a bulk
    scatter with probability 1/2 at s uniform in [0, t_end], else the segment's end:
    wall, or sensor glass if a sensor was hit), next-event estimate to every sensor,
    the specular probes leaving it (when the detector has walls),
    and the continuation. Returns (next rays, (NEE sums, probes or None))."""
    dtype = rays.weight.dtype
    n = sensors.positions.shape[0]
    n_rays = rays.weight.shape[0]
    has_walls = shape.has_walls
    u = jax.random.uniform(
        jax.random.fold_in(vertex_key, order), (UNIFORMS_PER_VERTEX, n_rays), dtype=dtype
    )
    directions = rays.directions
    t_end, index, hit, alive = trace(shape, sensors, rays.origins, directions)
    weight = where(alive, rays.weight, 0.0)
    scatter = u[0] < 0.5
    s = where(scatter, u[1] * t_end, t_end)
    weight = weight * jnp.exp(-interaction_rates(params)[3] * s) / 0.5
    weight = where(scatter, weight * t_end, weight)
    vertex = rays.origins + s[:, None] * directions
    time = rays.time + travel_time(s, params)
    kind = where(scatter, SCATTER, where(hit, GLASS, WALL))
    wall_normal = shape.inward_normal(vertex) if has_walls else -directions
    glass_normal = sensors.normals[index]
    normal = where((kind == GLASS)[:, None], glass_normal, wall_normal)
    if not has_walls:
        weight = where(kind == WALL, 0.0, weight)
    # a vertex on a disc (glass, or the wall right under it after the glass sent the
    # ray below the disc's plane) never lights that disc: it lies in the disc's
    # plane, but rounding can tilt it into view, where the exact solid angle is 2 pi
    still_on_disc = (kind == WALL) & (s == 0)
    own_disc = where(kind == GLASS, index, where(still_on_disc, rays.on_disc, n))
    detected = nee(vertex, weight, time, kind, directions, normal, own_disc)
    propose = functools.partial(outgoing, params, config, kind, directions, normal)
    origins, leaving_directions, factor = leaving(propose, sensors, u[:, None], vertex, index,
                                                  kind, directions)
    probes = None
    if has_walls:  # probes: light of this vertex mirrored once by the wall into a sensor
        count = config.specular_probes

        def probes_leaving(_):
            u_probe = jax.random.uniform(
                jax.random.fold_in(probe_key, order), (UNIFORMS_PER_VERTEX, count, n_rays),
                dtype=dtype,
            )
            return leaving(propose, sensors, u_probe, vertex, index, kind, directions,
                           continuation=False)

        def no_probes(_):  # the last order's vertices have none (their mirror vertex
            # would be above the cap)
            return (jnp.zeros((count, n_rays, 3), dtype), jnp.zeros((count, n_rays, 3), dtype),
                    jnp.zeros((count, n_rays), dtype))

        probe_origins, probe_directions, probe_factor = jax.lax.cond(
            order < config.n_bounces, probes_leaving, no_probes, None
        )
        probes = Probes(
            origins=probe_origins.reshape(-1, 3),
            directions=probe_directions.reshape(-1, 3),
            weight=(weight * probe_factor / count).reshape(-1),
            time=jnp.broadcast_to(time, probe_factor.shape).reshape(-1),
            order=jnp.full(count * n_rays, order, jnp.int32),
        )
    rays = Rays(vertex, leaving_directions[0], weight * factor[0], time, own_disc)
    return rays, (detected, probes)
