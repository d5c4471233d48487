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
   glass: sensor_reflectivity x ``dome_reflection_density``) x Omega_j x QE x
   A(theta_in) x exp(-rate_total d_j), arriving at ray time + d_j n_g / c.
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
(``specular_probes.specular_probes``): from every vertex of order k < n_bounces,
``config.specular_probes`` rays leave in directions drawn from the same proposals as the
continuation (off the glass: from a point uniform on the disc, as the NEE's dome density
assumes), each with 1 / ``config.specular_probes`` of the weight; one that reaches the
wall survives with exp(-rate_total t) R_w f_s, is mirrored, and counts on the sensors
whose discs, widened by ``config.specular_smoothing`` in their own plane, its mirrored
ray crosses, with 1 / smoothing^2 of its weight (attributed to order k + 1). From the
source (k = 0) the probes are emission directions of their own, count on the physical
discs and only for paths focused below ``FOCUSING_LIMIT`` (the rest is
``mirror_light``). No branch choice is made along a probe, so each carries far less
weight than a continuing ray would; the variance of the mirrored light falls 5-7x on SK
at 8 probes on the physical discs, and the widened discs cut it several-fold more. The
vertices of the last order have no probes (their mirror vertex would be above the cap).

After the last vertex its outgoing segment is traced once more: the expected photons
that would undergo a further vertex (scatter or reflection) on it are the
``residual_weight``. Every path with <= n_bounces vertices is estimated without bias (up
to the disc solid angle approximation of the NEE, the acceptance taken at the disc
centre, glass reflections drawn for light crossing the disc uniformly, and the widened
discs' average of the mirrored light, ~10^-4 of a sensor's light on SK).

All of it is the light of a sensor of relative efficiency 1 before its time offset: the
sensor response (``photonflow.response``) applies both. The parts live in their own
modules: ``rays`` (emission, tracing, vertex proposal, continuation), ``next_event``
(the next-event estimates), ``specular_probes`` and ``mirror`` (the source's
first-order mirror light by quadrature).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..geometry.detector import Detector
from ..geometry.sensor_arrays import Sensors, sensors_for
from ..geometry.sensor_grid import SensorGrid
from ..geometry.shapes import Shape
from ..inline_jit import inline_jit
from ..numerics import strict_array, where
from ..params import Params
from ..pytree import pytree_dataclass
from .mirror import MirrorPaths, mirror_light, mirror_paths
from .next_event import near_correction_sums, nee_in_blocks, next_event_sums
from .optics import TransportConfig, travel_time
from .rays import emitted_rays, residual_weight, trace, vertex_step
from .specular_probes import source_probes, specular_probes

#: Share of an order's light below which its surface part (the total minus the scattered
#: part) is taken as none.
SURFACE_FLOOR = 1e-3


@pytree_dataclass
class IndirectLight:
    """Indirect light per sensor, split by the order k = 1..n_bounces of its last vertex.

    Attributes:
        charge: (n_bounces, N) expected p.e. (of a sensor of efficiency 1) whose last
            vertex is the k-th.
        time_mean: (n_bounces, N) charge-weighted mean arrival time, ns (ray time plus
            travel time; no time offset, transit-time spread or pulse width); the
            reference time where a sensor gets no light of that order.
        time_variance: (n_bounces, N) charge-weighted variance of those times, ns^2.
        residual_weight: scalar, expected photons that would undergo a further vertex
            after the cap (not followed).
        kind_charge, kind_time_mean, kind_time_variance: (2, n_bounces, N), the same
            light split by the kind of its last vertex: [0] a bulk scatter, [1] a
            surface (wall or sensor glass, and the mirrored light). Scattered and
            reflected light arrive at different times (a scatter near the source early,
            the far wall late), which one mean and variance per order blur.
    """

    charge: jax.Array
    time_mean: jax.Array
    time_variance: jax.Array
    residual_weight: jax.Array
    kind_charge: jax.Array
    kind_time_mean: jax.Array
    kind_time_variance: jax.Array


def _moments(total, reference_time) -> tuple:
    """(charge, mean, variance) from sums of c, c (t - ref), c (t - ref)^2; mean and
    variance 0 where there is no light (mean then equals the reference)."""
    charge, first, second = total
    positive = charge > 0
    safe = where(positive, charge, 1.0)
    mean = where(positive, first / safe, 0.0)
    variance = where(positive, jnp.maximum(second / safe - mean * mean, 0.0), 0.0)
    return charge, mean + reference_time, variance


@inline_jit(static_argnames=("shape", "config"))
def indirect_light_jit(
    sensors: Sensors,
    params: Params,
    source,
    reference_time,
    key,
    mirror: MirrorPaths | None = None,
    *,
    shape: Shape,
    config: TransportConfig,
) -> IndirectLight:
    """``indirect_light`` on arrays: the detector's ``Sensors`` (its ``near_grid`` makes
    the solid angle of discs near a vertex exact; None: the far-field formula
    everywhere), ``params`` and ``source`` of one float dtype. ``reference_time`` (N,)
    ns is subtracted from arrival times before the moments are accumulated (float32
    accuracy; the direct arrival time is a good choice). ``mirror``: the source's
    ``mirror.mirror_paths``, computed once for a source that stays put (a calibration
    run; they do not depend on ``Params``); None computes them here, differentiably in
    the source position. ``shape`` and ``config`` are static. Returns an
    ``IndirectLight``.

    The stages: rays leave the source (``rays.emitted_rays``); one ``lax.scan`` over
    the orders 1..n_bounces runs ``rays.vertex_step`` (trace, vertex, next-event
    estimate, probes, continuation); the probes of the source and of every order below
    the cap are traced together (``specular_probes``); the segment after the last vertex
    gives the residual weight; the source's first-order mirror light is added by
    quadrature (``mirror.mirror_light``).
    """
    dtype = sensors.positions.dtype
    n = sensors.n
    emit_key, vertex_key, probe_key = jax.random.split(key, 3)
    rays = emitted_rays(source, emit_key, config.n_rays, n, dtype)
    # rematerialised in the backward pass: the (block, N) pair arrays are recomputed
    # rather than stored
    nee_block = jax.checkpoint(
        functools.partial(_nee_parts, params, sensors, config, reference_time)
    )
    step = functools.partial(
        vertex_step, params, shape, sensors, config,
        lambda *data: nee_in_blocks(nee_block, n, dtype, data), vertex_key, probe_key,
    )
    orders = jnp.arange(1, config.n_bounces + 1)
    rays, (detected, probes) = jax.lax.scan(step, rays, orders)  # detected: 6 x (K, N)
    t_end, _, hit, alive = trace(shape, sensors, rays.origins, rays.directions)
    residual = residual_weight(
        params, shape.has_walls, where(alive, rays.weight, 0.0), t_end, hit
    )
    total, scattered = list(detected[:3]), detected[3:]
    if shape.has_walls and config.n_bounces > 0:
        # specular probes of the source and of the vertices below the cap (whose mirror
        # vertex, order k + 1, is within it), traced together
        below_cap = jax.tree.map(lambda x: x[:-1].reshape((-1,) + x.shape[2:]), probes)
        from_source = source_probes(source, probe_key, config.specular_probes * config.n_rays,
                                    dtype)
        everything = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), from_source, below_cap)
        quadrature = getattr(source, "mirror_quadrature", True)
        mirrored = specular_probes(
            params, shape, sensors, reference_time, everything, config.n_bounces, quadrature,
            config.specular_smoothing,
        )
        total = [t + m for t, m in zip(total, mirrored, strict=True)]
        if quadrature:
            if mirror is None:
                mirror = mirror_paths(shape, sensors, source)
            light = mirror_light(params, mirror, source, reference_time)
            total = [t + jnp.zeros_like(t).at[0].set(q)
                     for t, q in zip(total, light, strict=True)]
    charge, mean, variance = _moments(total, reference_time)
    # the surface part as the difference: kept where it is more than SURFACE_FLOOR of the
    # total (below, its moments would be rounding noise)
    surface = [t - c for t, c in zip(total, scattered, strict=True)]
    kept = surface[0] > SURFACE_FLOOR * total[0]
    surface = [where(kept, x, 0.0) for x in surface]
    kinds = [jnp.stack(x) for x in zip(_moments(scattered, reference_time),
                                       _moments(surface, reference_time), strict=True)]
    return IndirectLight(
        charge=charge, time_mean=mean, time_variance=variance, residual_weight=residual,
        kind_charge=kinds[0], kind_time_mean=kinds[1], kind_time_variance=kinds[2],
    )


def _nee_parts(params, sensors: Sensors, config, reference_time, *vertex_data):
    """Next-event sums of a block of vertices: far-field solid angles, plus the exact
    correction for discs near a vertex where ``sensors`` has a near grid."""
    sums = next_event_sums(params, sensors, config, reference_time, *vertex_data)
    if sensors.near_grid is None:
        return sums
    near = near_correction_sums(params, sensors, config, reference_time, *vertex_data)
    return tuple(a + b for a, b in zip(sums, near, strict=True))


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
        params: detector parameters (lengths m).
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
        ``IndirectLight`` (p.e. of sensors of efficiency 1, ns before time offsets,
        ns^2, photons). Differentiable in every field of ``params`` and ``source``; new
        values never recompile.
    """
    dtype = jnp.result_type(params.absorption_length)
    cast = functools.partial(strict_array, dtype=dtype)
    config = TransportConfig() if config is None else config
    if key is None:
        key = jax.random.key(0)
    sensors = sensors_for(detector, dtype, grid)
    source = jax.tree.map(cast, source)
    if reference_time is None:
        offset = sensors.positions - source.position
        reference_time = source.time + travel_time(jnp.sqrt(jnp.sum(offset**2, axis=-1)), params)
    return indirect_light_jit(
        sensors, params, source, cast(reference_time), key, shape=detector.shape, config=config
    )
