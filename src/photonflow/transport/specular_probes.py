"""Specular probes: light of a vertex (or of the source) mirrored once by the wall into
a sensor, found by probe rays.

A specular reflection is a delta function in direction, which a next-event estimate
cannot see; a ray that happened to be mirrored into a sensor would carry its whole
weight there (heavy-tailed noise). So from every vertex of order k < n_bounces,
``config.specular_probes`` probe rays leave in directions drawn from the continuation's
proposals (``rays.vertex_step``), each with 1 / specular_probes of the weight; one that
reaches the wall survives with exp(-rate_total t) R_w f_s, is mirrored, and counts on
the sensors whose disc its mirrored ray crosses (attributed to order k + 1). A vertex's
probe counts on discs widened by ``config.specular_smoothing`` in their own plane, with
1 / smoothing^2 of its weight (an average of the mirrored flux over a wider disc: far
fewer sensors see zero or one probe; ``sensor_arrays.face_reach_for`` keeps the wider
disc off the next wall face). From the source (k = 0) the probes are emission directions
of their own, count on the physical discs and only for paths focused below
``FOCUSING_LIMIT`` (the rest is ``mirror.mirror_light``'s quadrature). The light is that
of a sensor of relative efficiency 1 before its time offset. Lengths m, times ns.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..geometry.sensor_arrays import Sensors
from ..geometry.sensor_grid import grid_candidates_xyz
from ..geometry.shapes import xyz
from ..numerics import where
from ..response.detection import acceptance_at_cos
from .mirror import FOCUSING_LIMIT, focusing_ratio
from .optics import interaction_rates, specular_direction, travel_time
from .rays import Probes, leaving_source, trace


def source_probes(source, key, count: int, dtype) -> Probes:
    """``count`` probes leaving the source in emission directions of their own (a
    shifted lattice from ``key``), N / count photons each, order 0."""
    return Probes(**leaving_source(source, key, count, dtype),
                  order=jnp.zeros(count, jnp.int32))


def specular_probes(params, shape, sensors: Sensors, reference, probes: Probes, n_orders: int,
                    source_quadrature: bool = True, smoothing: float = 1.0):
    """Light mirrored once by the wall into a sensor, from probe rays: (n_orders, N) sums
    of c, c t, c t^2 (t - reference) like ``next_event.next_event_sums``, by the order of the mirror
    vertex (slot k - 1 for a probe leaving a vertex of order k - 1; the source is order
    0).

    A probe leaves ``probes.origins`` (P, 3) m along ``probes.directions`` with expected
    photons ``probes.weight``; if it reaches the wall, not a sensor, it survives there
    with exp(-rate_total t) R_w f_s and is mirrored. The mirrored ray counts on sensor j
    x exp(-rate_total t') QE A(theta_in) if it crosses the plane of disc j (at distance t')
    within ``smoothing`` x r_j of its centre, with weight 1 / smoothing^2, arriving at
    ``probes.time`` ns + the path's travel time. With ``smoothing`` 1 that is the disc
    itself; a larger factor (probes that leave a vertex only, order > 0) averages the
    mirrored flux over a disc that much wider in the sensor's plane, capped by the
    sensor's ``face_reach`` (the wider disc never reaches across an edge of its wall
    face): the variance of a sensor's count falls ~ 1 / smoothing^2, and the bias is the
    flux's curvature over the wider disc, (smoothing r)^2 / 8 x its Laplacian. The discs
    are looked up around the mirrored ray's wall point in ``sensors.near_grid`` (every
    disc within ``NEAR_RADII`` radii); without it (or without ``face_reach``) the
    physical discs are used, looked up in ``sensors.grid``, or all tested without one.
    Probes from the source count only paths focused below ``FOCUSING_LIMIT`` (the rest
    is ``mirror_light``), or every path without ``source_quadrature`` (a track);
    ``probes.order`` (P,) says which left the source (0).
    """
    n = sensors.positions.shape[0]
    origins, directions = probes.origins, probes.directions
    t_wall, _, on_sensor, alive = trace(shape, sensors, origins, directions)
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
    t_exit = shape.ray_exit(wall_point, mirrored)
    landing = wall_point + where(jnp.isfinite(t_exit), t_exit, 0.0)[:, None] * mirrored
    focusing = jax.lax.stop_gradient(focusing_ratio(shape, origins, wall_point, landing))
    counted = (probes.order > 0) | (focusing < FOCUSING_LIMIT) if source_quadrature else True
    lookup = landing
    if sensors.standoff is not None:  # discs in front of the wall: look them up where
        # the ray crosses their layer (its wall point is standoff / cos away from them)
        cos_wall = jnp.maximum(-jnp.sum(mirrored * shape.inward_normal(landing), axis=-1),
                               MIN_LAYER_COS)
        lookup = landing - (sensors.standoff / cos_wall)[:, None] * mirrored
    index, crossed, t_plane, cos_in, factor = _crossings(
        sensors, wall_point, mirrored, lookup, probes.order, smoothing
    )
    counts = crossed & (reaches_wall & counted)[:, None]
    t_plane = where(counts, t_plane, 0.0)  # finite attenuation (and gradient) elsewhere
    rate_total = interaction_rates(params)[3]
    detected = where(
        counts,
        (weight[:, None] / (factor * factor))
        * jnp.exp(-rate_total * t_plane)
        * params.quantum_efficiency
        * acceptance_at_cos(params.angular_acceptance, jnp.maximum(cos_in, 0.0)),
        0.0,
    )
    arrival = ((probes.time + travel_time(t_wall, params))[:, None] - reference[index]
               + travel_time(t_plane, params))
    sums = _scatter_moments(detected, arrival, probes.order[:, None] * n + index, n_orders * n)
    return tuple(x.reshape(n_orders, n) for x in sums)


#: Smallest cosine of incidence on the wall at which a mirrored ray's crossing of the
#: sensors' layer (``Sensors.standoff``) is found (beyond it: 10 standoffs back). On
#: IWCD the lookup there finds 96 % of the mirrored light that testing every disc finds
#: (the wall point alone: 30 %); grazing rays cross the layer along a long stretch.
MIN_LAYER_COS = 0.1


def _crossings(sensors: Sensors, wall_point, mirrored, landing, order, smoothing):
    """The candidate discs (P, K) of mirrored rays leaving ``wall_point`` (P, 3) m along
    ``mirrored`` near ``landing`` (P, 3) m (the discs near it), and where each ray
    crosses each disc's plane: (index, crossed from the front within the widened
    radius, distance t m, cos of incidence, widening factor), all (P, K)."""
    n = sensors.positions.shape[0]
    lookup = sensors.near_grid if sensors.near_grid is not None else sensors.grid
    if lookup is None:  # no grids: every disc is a candidate
        candidates = jnp.broadcast_to(jnp.arange(n), order.shape + (n,))
    else:
        with jax.numpy_dtype_promotion("standard"):
            candidates = grid_candidates_xyz(lookup, xyz(landing))
    index = jnp.maximum(candidates, 0)  # (P, K)
    if sensors.near_grid is not None and sensors.face_reach is not None:
        widest = jnp.minimum(smoothing, sensors.face_reach[index])
        factor = where((order > 0)[:, None], widest, 1.0)
    else:
        factor = jnp.ones(index.shape, wall_point.dtype)
    origin = [c[:, None] for c in xyz(wall_point)]
    direction = [c[:, None] for c in xyz(mirrored)]
    normal = [sensors.normals[:, k][index] for k in range(3)]
    centre = [sensors.positions[:, k][index] for k in range(3)]
    # where the mirrored ray crosses each candidate disc's plane, from its front
    cos_in = -sum(d * m for d, m in zip(direction, normal, strict=True))
    front = cos_in > 1e-6
    t_plane = sum((o - c) * m for o, c, m in zip(origin, centre, normal, strict=True)) / where(
        front, cos_in, 1.0)
    offset2 = sum((o + t_plane * d - c) ** 2
                  for o, d, c in zip(origin, direction, centre, strict=True))
    reach = factor * sensors.radius[index]
    crossed = (candidates >= 0) & front & (t_plane > 0) & (offset2 < reach * reach)
    return index, crossed, t_plane, cos_in, factor


def _scatter_moments(detected, arrival, slot, size):
    """(size,) sums of c, c t, c t^2 of ``detected`` c at ``arrival`` t, scattered to
    ``slot``."""
    detected, arrival, slot = detected.reshape(-1), arrival.reshape(-1), slot.reshape(-1)
    zeros = jnp.zeros(size, dtype=detected.dtype)
    return (
        zeros.at[slot].add(detected),
        zeros.at[slot].add(detected * arrival),
        zeros.at[slot].add(detected * arrival * arrival),
    )
