"""Indirect light (scattered and reflected) by weighted rays with fixed random numbers.

The expected p.e. of every path with 1..n_bounces vertices (bulk scatter, wall reflection,
sensor-glass reflection) is estimated from ``n_rays`` rays whose random numbers are fixed
by a key (common random numbers), so the estimate is a smooth function of every
parameter that does not move the rays' geometry, and a pathwise (reparameterised)
function of those that do. Physics exactly as in ``optics.py``.

A ray starts at the source with weight N / n_rays (expected photons) in a direction drawn
from the source's emission density. Per segment from the current vertex:

1. trace: distance ``t_wall`` to the wall and the first sensor front face on the way
   (``first_sensor_hit``); the segment ends at the sensor if one is hit, else at the wall
   (length ``t_end``);
2. no detection on the segment itself: direct light is done by quadrature, light
   mirrored once from the source too (``mirror.py``), and light mirrored into a sensor
   after a later vertex by the specular probes (below);
3. next vertex with a fixed proposal: with probability 1/2 a bulk scatter at s uniform in
   [0, t_end] (weight x exp(-rate_total s) t_end / 0.5; the scattering rate enters below),
   else the end of the segment (weight x exp(-rate_total t_end) / 0.5): the wall, or the
   sensor glass if a sensor was hit;
4. next-event estimate (NEE) at the vertex to every sensor j facing it: weight x
   redirection density toward the sensor (per sr; scatter: rate_rayleigh p_R + rate_mie
   p_HG, per m; wall: wall_reflectivity (1 - specular fraction) cos_out / pi; sensor
   glass: sensor_reflectivity x ``dome_reflection_density``) x Omega_j x QE x eff_j x
   A(theta_in) x exp(-rate_total d_j), arriving at ray time + d_j n_g / c + offset_j.
   Omega_j = cos_in 2 pi r^2 / (R (R + d)), R = sqrt(d^2 + r^2): the on-axis disc
   solid angle tilted by cos_in (far field pi r^2 cos_in / d^2, bounded by 2 pi near
   the disc);
5. continue: after a scatter the new direction is drawn with probability 1/2 each from
   the Rayleigh phase function or from a Henyey-Greenstein proposal of fixed asymmetry
   g_q (``config.mie_proposal_asymmetry``), weight x (rate_R p_R + rate_M p_HG(g)) /
   (p_R / 2 + p_HG(g_q) / 2) (one-sample mixture importance sampling); no proposal
   depends on ``Params``, so the rays' geometry is fixed by the key and the source, and
   parameters enter only through weights and times (cheap gradients, smooth results);
   after a wall vertex specular (proposal 1/2, weight x R_w f_s / 0.5) or Lambertian
   (weight x R_w (1 - f_s) / 0.5); after the sensor glass, mirrored about the dome
   normal where the ray crossed the disc, weight x R_s.

A specular reflection is a delta function in direction, which a next-event estimate
cannot see; a ray that happened to be mirrored into a sensor would carry its whole
weight there (on SK at 1,024 rays and 2e5 photons, single sensors got 8-40 p.e. of such
spikes, heavy-tailed noise that drove fits of the wall reflectivity to zero). So light
whose last vertex is a specular wall reflection is found by *specular probes*
(``_specular_probes``): from every vertex of order k < n_bounces, ``specular_probes``
rays leave in directions drawn from the same proposals as the continuation (off the
glass: from a point uniform on the disc, as the NEE's dome density assumes), each with
1 / specular_probes of the weight; one that reaches the wall survives with
exp(-rate_total t) R_w f_s, is mirrored, and counts on the sensor its mirrored segment
ends on (attributed to order k + 1). From the source (k = 0) the probes are emission
directions of their own and count only paths focused below ``FOCUSING_LIMIT`` (the rest
is ``mirror_light``). No branch choice is made along a probe, so each carries far less
weight than a continuing ray would; the variance of the mirrored light falls 5-7x on SK
at 8 probes.

After the last vertex its outgoing segment is traced once more: the expected photons
that would undergo a further vertex (scatter or reflection) on it are the
``residual_weight``. Every path with <= n_bounces vertices is estimated without bias (up
to the disc solid angle approximation of the NEE, the acceptance taken at the disc
centre, and glass reflections drawn for light crossing the disc uniformly).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from weakref import WeakKeyDictionary

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.detector import Detector
from ..geometry.sensor_grid import (
    SensorGrid,
    build_sensor_grid,
    first_sensor_hit,
    grid_candidates,
)
from ..geometry.shapes import Shape
from ..numerics import strict_array, where
from ..params import Params
from ..pytree import pytree_dataclass
from .emission import sample_directions
from .mirror import FOCUSING_LIMIT, MirrorPaths, focusing_ratio, mirror_light, mirror_paths
from .optics import (
    TransportConfig,
    acceptance_at_cos,
    deflect,
    dome_normal,
    dome_reflection_density_cos,
    henyey_greenstein_density,
    interaction_rates,
    lambertian_density,
    lambertian_direction,
    orthonormal_basis,
    rayleigh_density,
    sample_henyey_greenstein_cos,
    sample_rayleigh_cos,
    specular_direction,
    travel_time,
)
from .solid_angle import disc_solid_angle_local

#: Uniform random numbers drawn per ray and vertex.
_UNIFORMS_PER_VERTEX = 8
#: Rays whose next-event estimates are computed together (bounds memory to ~ block x N).
NEE_BLOCK = 128
#: Rim nodes of the exact solid angle of discs near a vertex.
NEAR_NODES = 32
#: Discs nearer than this many radii to a vertex get the exact solid angle.
NEAR_RADII = 4.0
#: Vertex kinds.
_SCATTER, _WALL, _GLASS = 0, 1, 2


@pytree_dataclass
class IndirectLight:
    """Indirect light per sensor, split by the order k = 1..n_bounces of its last vertex.

    Attributes:
        charge: (n_bounces, N) expected p.e. whose last vertex is the k-th.
        time_mean: (n_bounces, N) charge-weighted mean arrival time, ns (ray time plus
            travel time plus the sensor's time offset; no transit-time spread or pulse
            width); the reference time where a sensor gets no light of that order.
        time_variance: (n_bounces, N) charge-weighted variance of those times, ns^2.
        residual_weight: scalar, expected photons that would undergo a further vertex
            after the cap (not followed).
    """

    charge: jax.Array
    time_mean: jax.Array
    time_variance: jax.Array
    residual_weight: jax.Array


@dataclasses.dataclass(frozen=True)
class _Sensors:
    positions: jax.Array
    normals: jax.Array
    radius: jax.Array


def _trace(shape: Shape, grid, sensors: _Sensors, origins, directions):
    """Segment ends: (t_end m, sensor index or -1, hit bool, alive bool). A ray that
    starts on the wall heading out (light the sensor glass sends below its disc's plane)
    meets the wall at distance 0, as in the sampled mode."""
    t_wall = shape.ray_exit(origins, directions)
    alive = jnp.isfinite(t_wall)
    t_wall = where(alive, jnp.maximum(t_wall, 0.0), 0.0)
    # standard promotion: grid_candidates mixes int32 cells with int64 dims under x64
    with jax.numpy_dtype_promotion("standard"):
        index, t_sensor = first_sensor_hit(
            grid, sensors.positions, sensors.normals, sensors.radius, origins, directions, t_wall
        )
    hit = alive & (index >= 0)
    t_end = where(hit, t_sensor, t_wall)
    return t_end, where(hit, index, 0), hit, alive


def _detect_on_segment(params, sensors, weight, time, directions, t_end, index, counts, slot,
                       size):
    """Scatter-add the detections of rays whose segment ends on sensor ``index`` (where
    ``counts``) into ``size`` slots at ``slot`` (the sensor, or order x N + sensor):
    (size,) sums of c, c t, c t^2 with t = ``time`` + the segment's travel time +
    the sensor's offset (ns)."""
    rate_total = interaction_rates(params)[3]
    cos_in = -jnp.sum(directions * sensors.normals[index], axis=-1)
    detected = (
        weight
        * jnp.exp(-rate_total * t_end)
        * params.quantum_efficiency
        * params.efficiency[index]
        * acceptance_at_cos(params.angular_acceptance, cos_in)
    )
    detected = where(counts, detected, 0.0)
    arrival = time + travel_time(t_end, params) + params.time_offset[index]
    zeros = jnp.zeros(size, dtype=weight.dtype)
    return (
        zeros.at[slot].add(detected),
        zeros.at[slot].add(detected * arrival),
        zeros.at[slot].add(detected * arrival * arrival),
    )


def far_solid_angle(distance, cos_in, radius):
    """Solid angle (sr) of a disc (radius m) seen from distance d (m) at incidence cos_in.

    The on-axis value 2 pi r^2 / (R (R + d)), R = sqrt(d^2 + r^2), tilted by cos_in and
    corrected to second order in (r / d): x (1 + 15/8 (r/d)^2 sin^2). Relative error
    below 1 % for d > 4 r at any incidence; nearer discs are computed exactly
    (``_near_correction``).
    """
    r2 = radius * radius
    hypot = jnp.sqrt(distance * distance + r2)
    cos_in = jnp.maximum(cos_in, 0.0)
    tilt = 1.0 + 1.875 * r2 / (distance * distance) * (1.0 - cos_in * cos_in)
    return jnp.minimum(
        cos_in * (2.0 * math.pi) * r2 / (hypot * (hypot + distance)) * tilt, 2.0 * math.pi
    )


def _redirection(params, config, cos_turn, cos_out, in_normal, kind):
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
        kind == _SCATTER, scatter_density, where(kind == _WALL, wall_density, glass_density)
    )


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _pair_light(params, config, vertex, d_in, wall_n, kind, positions, normals):
    """Geometry and light factors of vertex-sensor pairs, on x, y, z components.

    ``vertex``, ``d_in`` (incoming direction), ``wall_n`` (surface normal at the vertex)
    are 3-tuples of (R, 1) arrays, ``kind`` (R, 1); ``positions`` and ``normals`` 3-tuples
    of sensor arrays broadcasting against them ((1, N) or (R, K)). Components are kept
    apart (structure of arrays) so that XLA fuses every pair's arithmetic into one loop.
    Returns (distance m, cos_in, factor): factor = redirection density x attenuation x
    acceptance x QE (per sr per unit weight, before the solid angle and efficiency).
    """
    offset = tuple(p - v for p, v in zip(positions, vertex, strict=True))
    distance = jnp.sqrt(jnp.maximum(_dot(offset, offset), 1e-12))
    inverse = 1.0 / distance
    cos_in = -_dot(offset, normals) * inverse
    cos_turn = _dot(offset, d_in) * inverse
    cos_out = _dot(offset, wall_n) * inverse
    density = _redirection(params, config, cos_turn, cos_out, _dot(d_in, wall_n), kind)
    factor = (
        density
        * jnp.exp(-interaction_rates(params)[3] * distance)
        * acceptance_at_cos(params.angular_acceptance, jnp.maximum(cos_in, 0.0))
        * params.quantum_efficiency
    )
    return distance, cos_in, factor


def _components(vectors):
    """(..., 3) -> 3-tuple of (..., 1) arrays (a trailing pair axis)."""
    return tuple(vectors[..., k, None] for k in range(3))


def _next_event(
    params, sensors, config, reference, vertex, weight, time, kind, d_in, wall_n, own_disc
):
    """NEE of one vertex per ray to every sensor: (N,) sums of c, c t, c t^2 (t - reference).

    ``own_disc`` (R,) is the sensor each vertex leaves out (N for none)."""
    distance, cos_in, factor = _pair_light(
        params,
        config,
        _components(vertex),
        _components(d_in),
        _components(wall_n),
        kind[:, None],
        tuple(sensors.positions[None, :, k] for k in range(3)),
        tuple(sensors.normals[None, :, k] for k in range(3)),
    )
    n = sensors.positions.shape[0]
    solid_angle = far_solid_angle(distance, cos_in, sensors.radius)
    contribution = weight[:, None] * factor * solid_angle * params.efficiency
    own = own_disc[:, None] == jnp.arange(n, dtype=own_disc.dtype)
    contribution = where(own, 0.0, contribution)
    relative = time[:, None] + travel_time(distance, params) + params.time_offset - reference
    return (
        jnp.sum(contribution, axis=0),
        jnp.sum(contribution * relative, axis=0),
        jnp.sum(contribution * relative * relative, axis=0),
    )


def _near_correction(
    params, sensors, config, reference, near_grid, vertex, weight, time, kind, d_in, wall_n,
    own_disc,
):
    """Exact-minus-far solid-angle correction of the NEE for the sensors near each vertex
    (the candidates of ``near_grid``, which lists every sensor within 4 radii): (N,) sums
    of c, c t, c t^2 like ``_next_event``; ``own_disc`` (R,) gets none."""
    n = sensors.positions.shape[0]
    candidates = grid_candidates(near_grid, vertex)  # (R, K)
    valid = candidates >= 0
    index = where(valid, candidates, 0)
    positions = sensors.positions[index]
    normals = sensors.normals[index]
    radius = sensors.radius[index]
    distance, cos_in, factor = _pair_light(
        params,
        config,
        _components(vertex),
        _components(d_in),
        _components(wall_n),
        kind[:, None],
        tuple(positions[..., k] for k in range(3)),
        tuple(normals[..., k] for k in range(3)),
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
    contribution = weight[:, None] * factor * delta * params.efficiency[index]
    relative = (
        time[:, None] + travel_time(distance, params) + params.time_offset[index] - reference[index]
    )
    zeros = jnp.zeros(n, dtype=contribution.dtype)
    flat = index.reshape(-1)
    return (
        zeros.at[flat].add(contribution.reshape(-1)),
        zeros.at[flat].add((contribution * relative).reshape(-1)),
        zeros.at[flat].add((contribution * relative * relative).reshape(-1)),
    )


def shifted_lattice(key, n: int, dtype):
    """(2, n) points of the Fibonacci lattice (i + 1/2) / n, frac(i / phi) shifted by one
    uniform random vector from ``key`` (mod 1): each point is uniform on the unit square,
    so estimates stay unbiased, and together they cover it far more evenly than
    independent points (randomised quasi-Monte Carlo for the emission directions)."""
    index = np.arange(n)
    lattice = np.stack([(index + 0.5) / n, np.mod(index * (math.sqrt(5.0) - 1.0) / 2.0, 1.0)])
    shift = jax.random.uniform(key, (2, 1), dtype=dtype)
    return jnp.mod(jnp.asarray(lattice, dtype) + shift, 1.0)


def _residual(params, shape_has_walls, weight, t_end, hit):
    """Expected photons that would undergo one more vertex on the traced segment."""
    _, rate_rayleigh, rate_mie, rate_total = interaction_rates(params)
    x = rate_total * t_end
    safe_rate = where(x > 0, rate_total, 1.0)
    interact_length = where(x > 0, -jnp.expm1(-x) / safe_rate, t_end)
    wall = params.wall_reflectivity if shape_has_walls else 0.0
    reflect = where(hit, params.sensor_reflectivity, wall)
    return jnp.sum(weight * ((rate_rayleigh + rate_mie) * interact_length + jnp.exp(-x) * reflect))


def _outgoing(params, config, kind, directions, normal, u, glass_direction):
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
    is_scatter = (kind == _SCATTER)[:, None]
    is_wall = (kind == _WALL)[:, None]
    directions = where(
        is_scatter, scatter_direction, where(is_wall, reflected, glass_direction)
    )
    directions = directions / jnp.linalg.norm(directions, axis=-1, keepdims=True)
    factor = where(
        kind == _SCATTER,
        scatter_weight,
        where(kind == _WALL, wall_weight, params.sensor_reflectivity),
    )
    return directions, factor


def _disc_point(normal, radius, u1, u2):
    """Offset (R, 3) m from a disc's centre of a point uniform on the disc (unit
    ``normal`` (R, 3), ``radius`` (R,) m) from uniforms u1, u2 (R,)."""
    e1, e2 = orthonormal_basis(normal)
    rho = (radius * jnp.sqrt(u1))[:, None]
    phi = (2.0 * math.pi * u2)[:, None]
    return rho * (jnp.cos(phi) * e1 + jnp.sin(phi) * e2)


def _specular_probes(params, shape, grid, sensors, reference, probes: _Probes, n_orders: int):
    """Light mirrored once by the wall into a sensor, from probe rays: (n_orders, N) sums
    of c, c t, c t^2 (t - reference) like ``_next_event``, by the order of the mirror
    vertex (slot k - 1 for a probe leaving a vertex of order k - 1; the source is order
    0).

    A probe leaves ``probes.origins`` (P, 3) m along ``probes.directions`` with expected
    photons ``probes.weight``; if it reaches the wall, not a sensor, it survives there
    with exp(-rate_total t) R_w f_s, is mirrored, and counts x exp(-rate_total t') QE
    eff_j A(theta) if the mirrored segment ends on sensor j, arriving at
    ``probes.time`` ns + the path's travel time + offset_j. A specular reflection is a
    delta function in direction that a next-event estimate cannot see; probes with no
    branch choices find it with far smaller weights than the rays' own continuations.
    Probes from the source count only paths focused below ``FOCUSING_LIMIT`` (the rest
    is ``mirror_light``); ``probes.order`` (P,) says which left the source (0).
    """
    n = sensors.positions.shape[0]
    origins, directions = probes.origins, probes.directions
    t_wall, _, on_sensor, alive = _trace(shape, grid, sensors, origins, directions)
    reaches_wall = alive & ~on_sensor
    weight = where(
        reaches_wall,
        probes.weight
        * jnp.exp(-interaction_rates(params)[3] * t_wall)
        * params.wall_reflectivity
        * params.wall_specular_fraction,
        0.0,
    )
    wall_point = origins + t_wall[:, None] * directions
    mirrored = specular_direction(directions, shape.inward_normal(wall_point))
    t_end, index, hit, _ = _trace(shape, grid, sensors, wall_point, mirrored)
    landing = wall_point + t_end[:, None] * mirrored
    focusing = jax.lax.stop_gradient(focusing_ratio(shape, origins, wall_point, landing))
    counts = hit & reaches_wall & ((probes.order > 0) | (focusing < FOCUSING_LIMIT))
    arrival = probes.time + travel_time(t_wall, params) - reference[index]
    sums = _detect_on_segment(
        params, sensors, weight, arrival, mirrored, t_end, index, counts,
        probes.order * n + index, n_orders * n,
    )
    return tuple(x.reshape(n_orders, n) for x in sums)


@pytree_dataclass
class _Probes:
    """Specular probe rays (P of them): origins (P, 3) m, unit directions (P, 3),
    expected photons (P,), time at the origin (P,) ns, and the order (P,) int of the
    vertex they leave (0: the source)."""

    origins: jax.Array
    directions: jax.Array
    weight: jax.Array
    time: jax.Array
    order: jax.Array


@pytree_dataclass
class _Rays:
    """The rays between two vertices: origins (R, 3) m, unit directions (R, 3),
    expected photons (R,), time at the origin (R,) ns, and the disc each origin lies on
    (R,) int (N for none)."""

    origins: jax.Array
    directions: jax.Array
    weight: jax.Array
    time: jax.Array
    on_disc: jax.Array


def _emitted_rays(source, key, n_rays: int, n_sensors: int, dtype) -> _Rays:
    """``n_rays`` rays leaving the source with N / n_rays photons each, directions from a
    shifted Fibonacci lattice through the source's inverse CDF."""
    u_emit = shifted_lattice(key, n_rays, dtype)
    return _Rays(
        origins=jnp.broadcast_to(source.position, (n_rays, 3)),
        directions=sample_directions(source, u_emit[0], u_emit[1]),
        weight=jnp.broadcast_to(source.n_photons / n_rays, (n_rays,)).astype(dtype),
        time=jnp.broadcast_to(source.time, (n_rays,)).astype(dtype),
        on_disc=jnp.full(n_rays, n_sensors, dtype=jnp.int32),
    )


def _source_probes(source, key, count: int, dtype) -> _Probes:
    """``count`` probes leaving the source in emission directions of their own (a
    shifted lattice from ``key``), N / count photons each, order 0."""
    emission = shifted_lattice(key, count, dtype)
    return _Probes(
        origins=jnp.broadcast_to(source.position, (count, 3)),
        directions=sample_directions(source, emission[0], emission[1]),
        weight=jnp.broadcast_to(source.n_photons / count, (count,)).astype(dtype),
        time=jnp.broadcast_to(source.time, (count,)).astype(dtype),
        order=jnp.zeros(count, jnp.int32),
    )


def _nee_in_blocks(nee_block, n: int, dtype, vertex_data):
    """Next-event sums (3 x (N,)) of R vertices, ``NEE_BLOCK`` rays at a time (memory ~
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

    zeros = tuple(jnp.zeros(n, dtype=dtype) for _ in range(3))
    return jax.lax.scan(accumulate, zeros, blocks)[0]


def _leaving(outgoing, sensors, u_all, vertex, index, kind, directions):
    """The continuation and the probes leaving the vertices, from one proposal
    (``outgoing``): ``u_all`` (8, 1 + K, R) uniforms, set 0 the continuation, sets
    1..K the probes. Off the glass the continuation is mirrored about the dome where the
    ray crossed the disc; a probe leaves a point drawn uniformly on the disc, mirrored
    about the dome there, as the NEE's ``dome_reflection_density`` assumes. Returns
    (origins (1 + K, R, 3) m, unit directions (1 + K, R, 3), weight factors
    (1 + K, R)); the continuation leaves the vertex itself."""
    centre, disc_normal = sensors.positions[index], sensors.normals[index]
    disc_radius = sensors.radius[index]
    glass = (kind == _GLASS)[:, None]

    def one(u, drawn):
        crossing = where(drawn, _disc_point(disc_normal, disc_radius, u[6], u[7]),
                             vertex - centre)
        dome = dome_normal(crossing, disc_normal, disc_radius)
        direction, factor = outgoing(u, specular_direction(directions, dome))
        origin = where(glass & drawn, centre + crossing, vertex)
        return origin, direction, factor

    return jax.vmap(one, in_axes=(1, 0))(u_all, jnp.arange(u_all.shape[1]) > 0)


def _vertex_step(params, shape, grid, sensors, config, nee, vertex_key, probe_key,
                 rays: _Rays, order):
    """One vertex per ray (scan body): trace the segment, propose the vertex (a bulk
    scatter with probability 1/2 at s uniform in [0, t_end], else the segment's end:
    wall, or sensor glass if a sensor was hit), next-event estimate to every sensor,
    the specular probes leaving it (``_vertex_probes``, when the detector has walls),
    and the continuation. Returns (next rays, (NEE sums, probes or None))."""
    dtype = rays.weight.dtype
    n = sensors.positions.shape[0]
    n_rays = rays.weight.shape[0]
    has_walls = shape.has_walls
    u = jax.random.uniform(
        jax.random.fold_in(vertex_key, order), (_UNIFORMS_PER_VERTEX, n_rays), dtype=dtype
    )
    directions = rays.directions
    t_end, index, hit, alive = _trace(shape, grid, sensors, rays.origins, directions)
    weight = where(alive, rays.weight, 0.0)
    scatter = u[0] < 0.5
    s = where(scatter, u[1] * t_end, t_end)
    weight = weight * jnp.exp(-interaction_rates(params)[3] * s) / 0.5
    weight = where(scatter, weight * t_end, weight)
    vertex = rays.origins + s[:, None] * directions
    time = rays.time + travel_time(s, params)
    kind = where(scatter, _SCATTER, where(hit, _GLASS, _WALL))
    wall_normal = shape.inward_normal(vertex) if has_walls else -directions
    glass_normal = sensors.normals[index]
    normal = where((kind == _GLASS)[:, None], glass_normal, wall_normal)
    if not has_walls:
        weight = where(kind == _WALL, 0.0, weight)
    # a vertex on a disc (glass, or the wall right under it after the glass sent the
    # ray below the disc's plane) never lights that disc: it lies in the disc's
    # plane, but rounding can tilt it into view, where the exact solid angle is 2 pi
    still_on_disc = (kind == _WALL) & (s == 0)
    own_disc = where(kind == _GLASS, index, where(still_on_disc, rays.on_disc, n))
    detected = nee(vertex, weight, time, kind, directions, normal, own_disc)
    u_all = u[:, None]
    if has_walls:  # probes: light of this vertex mirrored once by the wall into a sensor
        u_probe = jax.random.uniform(
            jax.random.fold_in(probe_key, order),
            (_UNIFORMS_PER_VERTEX, config.specular_probes, n_rays),
            dtype=dtype,
        )
        u_all = jnp.concatenate([u_all, u_probe], axis=1)
    outgoing = functools.partial(_outgoing, params, config, kind, directions, normal)
    origins, leaving, factor = _leaving(outgoing, sensors, u_all, vertex, index, kind,
                                        directions)
    probes = None
    if has_walls:
        count = config.specular_probes
        probes = _Probes(
            origins=origins[1:].reshape(-1, 3),
            directions=leaving[1:].reshape(-1, 3),
            weight=(weight * factor[1:] / count).reshape(-1),
            time=jnp.broadcast_to(time, factor[1:].shape).reshape(-1),
            order=jnp.full(count * n_rays, order, jnp.int32),
        )
    rays = _Rays(vertex, leaving[0], weight * factor[0], time, own_disc)
    return rays, (detected, probes)


def _moments(total, reference_time) -> tuple:
    """(charge, mean, variance) from sums of c, c (t - ref), c (t - ref)^2; mean and
    variance 0 where there is no light (mean then equals the reference)."""
    charge, first, second = total
    positive = charge > 0
    safe = where(positive, charge, 1.0)
    mean = where(positive, first / safe, 0.0)
    variance = where(positive, jnp.maximum(second / safe - mean * mean, 0.0), 0.0)
    return charge, mean + reference_time, variance


@functools.partial(jax.jit, static_argnames=("shape", "config"))
def indirect_light_jit(
    sensor_positions,
    sensor_normals,
    sensor_radius,
    grid: SensorGrid | None,
    params: Params,
    source,
    reference_time,
    key,
    near_grid: SensorGrid | None = None,
    mirror: MirrorPaths | None = None,
    *,
    shape: Shape,
    config: TransportConfig,
) -> IndirectLight:
    """``indirect_light`` on arrays (positions m, normals, radii m, one float dtype).

    ``near_grid`` (a ``near_grid_for`` grid) makes the solid angle of discs near a vertex
    exact (None: the far-field formula everywhere). ``reference_time`` (N,) ns is
    subtracted from arrival times before the moments are accumulated (float32 accuracy;
    the direct arrival time is a good choice). ``mirror``: the source's
    ``mirror.mirror_paths``, computed once for a source that stays put (a calibration
    run; they do not depend on ``Params``); None computes them here, differentiably in
    the source position. ``shape`` and ``config`` are static. Returns an
    ``IndirectLight``.

    The stages: rays leave the source (``_emitted_rays``); one ``lax.scan`` over the
    orders 1..n_bounces runs ``_vertex_step`` (trace, vertex, next-event estimate,
    probes, continuation); the probes of the source and of every order below the cap
    are traced together (``_specular_probes``); the segment after the last vertex gives
    the residual weight; the source's first-order mirror light is added by quadrature.
    """
    dtype = sensor_positions.dtype
    n = sensor_positions.shape[0]
    sensors = _Sensors(sensor_positions, sensor_normals, sensor_radius)
    emit_key, vertex_key, probe_key = jax.random.split(key, 3)
    rays = _emitted_rays(source, emit_key, config.n_rays, n, dtype)
    far = functools.partial(_next_event, params, sensors, config, reference_time)
    near = None
    if near_grid is not None:
        near = functools.partial(
            _near_correction, params, sensors, config, reference_time, near_grid
        )

    @jax.checkpoint
    def nee_block(*vertex_data):
        sums = far(*vertex_data)
        if near is None:
            return sums
        return tuple(a + b for a, b in zip(sums, near(*vertex_data), strict=True))

    step = functools.partial(
        _vertex_step, params, shape, grid, sensors, config,
        lambda *data: _nee_in_blocks(nee_block, n, dtype, data), vertex_key, probe_key,
    )
    orders = jnp.arange(1, config.n_bounces + 1)
    rays, (detected, probes) = jax.lax.scan(step, rays, orders)  # detected: 3 x (K, N)
    t_end, _, hit, alive = _trace(shape, grid, sensors, rays.origins, rays.directions)
    residual = _residual(params, shape.has_walls, where(alive, rays.weight, 0.0), t_end, hit)
    total = list(detected)
    if shape.has_walls and config.n_bounces > 0:
        # specular probes of the source and of the vertices below the cap (whose mirror
        # vertex, order k + 1, is within it), traced together
        below_cap = jax.tree.map(lambda x: x[:-1].reshape((-1,) + x.shape[2:]), probes)
        from_source = _source_probes(source, probe_key, config.specular_probes * config.n_rays,
                                     dtype)
        everything = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), from_source, below_cap)
        mirrored = _specular_probes(
            params, shape, grid, sensors, reference_time, everything, config.n_bounces
        )
        if mirror is None:
            mirror = mirror_paths(shape, grid, sensor_positions, sensor_normals,
                                  sensor_radius, source, near_grid)
        quadrature = mirror_light(params, mirror, source, reference_time)
        total = [t + m + jnp.zeros_like(t).at[0].set(q)
                 for t, m, q in zip(total, mirrored, quadrature, strict=True)]
    charge, mean, variance = _moments(total, reference_time)
    return IndirectLight(
        charge=charge, time_mean=mean, time_variance=variance, residual_weight=residual
    )


def indirect_light(
    detector: Detector,
    params: Params,
    source,
    *,
    config: TransportConfig | None = None,
    key=None,
    grid: SensorGrid | None = None,
    reference_time=None,
) -> IndirectLight:
    """Indirect (scattered and reflected) light per sensor and bounce order.

    Args:
        detector: sensors (positions m, inward normals, radii m) and boundary.
        params: detector parameters (lengths m, time offsets ns).
        source: an ``IsotropicSource``, ``LaserSource`` or ``DiffuserSource`` (position
            m, time ns).
        config: static transport settings (``n_rays``, ``n_bounces``, Rayleigh
            anisotropy; default ``TransportConfig()``).
        key: ``jax.random`` key fixing the rays' random numbers (default key 0).
        grid: sensor lookup grid (built from the detector when None and the detector
            has walls; pass it to avoid rebuilding).
        reference_time: (N,) ns subtracted from times while accumulating moments
            (default: straight-line arrival time from the source).

    Returns:
        ``IndirectLight`` (p.e., ns, ns^2, photons). Differentiable in every field of
        ``params`` and ``source``; new values never recompile.
    """
    dtype = jnp.result_type(params.absorption_length)

    cast = functools.partial(strict_array, dtype=dtype)

    config = TransportConfig() if config is None else config
    if key is None:
        key = jax.random.key(0)
    if grid is None and detector.shape.has_walls:
        grid = sensor_grid_for(detector)
    positions = cast(detector.sensor_positions)
    source = jax.tree.map(cast, source)
    if reference_time is None:
        distance = jnp.linalg.norm(positions - source.position, axis=-1)
        reference_time = source.time + travel_time(distance, params)
    return indirect_light_jit(
        positions,
        cast(detector.sensor_normals),
        cast(detector.sensor_radius),
        grid,
        params,
        source,
        cast(reference_time),
        key,
        near_grid_for(detector),
        shape=detector.shape,
        config=config,
    )


def sensor_grid_for(detector: Detector) -> SensorGrid:
    """The sensor lookup grid of a walled detector, built once per detector object."""
    if detector not in _GRIDS:
        _GRIDS[detector] = build_sensor_grid(detector)
    return _GRIDS[detector]


def near_grid_for(detector: Detector) -> SensorGrid | None:
    """Grid listing, for any point, every sensor within ``NEAR_RADII`` radii of it (walled
    detectors; None for open media), built once per detector object."""
    if not detector.shape.has_walls:
        return None
    if detector not in _NEAR_GRIDS:
        largest = float(np.max(np.asarray(detector.sensor_radius)))
        _NEAR_GRIDS[detector] = build_sensor_grid(detector, margin=(NEAR_RADII - 1) * largest)
    return _NEAR_GRIDS[detector]


#: Memo of near-sensor grids per detector object (a pure cache).
_NEAR_GRIDS: WeakKeyDictionary = WeakKeyDictionary()
#: Memo of lookup grids per detector object (a pure cache; detectors are immutable).
_GRIDS: WeakKeyDictionary = WeakKeyDictionary()
