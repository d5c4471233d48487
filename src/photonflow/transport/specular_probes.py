"""Specular probes: light of a vertex (or of the source) mirrored once by the wall into
a sensor, found by probe rays.

A specular reflection is a delta function in direction, which a next-event estimate
cannot see; a ray that happened to be mirrored into a sensor would carry its whole
weight there (heavy-tailed noise). So from every vertex of order k < n_bounces,
``config.specular_probes`` probe rays leave in directions drawn from the continuation's
proposals (``rays.vertex_step``), each with 1 / specular_probes of the weight; one that
reaches the wall survives with exp(-rate_total t) R_w f_s, is mirrored, and counts on
the sensor its mirrored segment ends on (attributed to order k + 1). From the source
(k = 0) the probes are emission directions of their own and count only paths focused
below ``FOCUSING_LIMIT`` (the rest is ``mirror.mirror_light``'s quadrature). The light
is that of a sensor of relative efficiency 1 before its time offset. Lengths m, times
ns.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..geometry.sensor_arrays import Sensors
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
                    source_quadrature: bool = True):
    """Light mirrored once by the wall into a sensor, from probe rays: (n_orders, N) sums
    of c, c t, c t^2 (t - reference) like ``next_event.next_event_sums``, by the order of the mirror
    vertex (slot k - 1 for a probe leaving a vertex of order k - 1; the source is order
    0).

    A probe leaves ``probes.origins`` (P, 3) m along ``probes.directions`` with expected
    photons ``probes.weight``; if it reaches the wall, not a sensor, it survives there
    with exp(-rate_total t) R_w f_s, is mirrored, and counts x exp(-rate_total t') QE
    A(theta) if the mirrored segment ends on sensor j, arriving at ``probes.time`` ns +
    the path's travel time. A specular reflection is a
    delta function in direction that a next-event estimate cannot see; probes with no
    branch choices find it with far smaller weights than the rays' own continuations.
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
    t_end, index, hit, _ = trace(shape, sensors, wall_point, mirrored)
    landing = wall_point + t_end[:, None] * mirrored
    focusing = jax.lax.stop_gradient(focusing_ratio(shape, origins, wall_point, landing))
    counted = (probes.order > 0) | (focusing < FOCUSING_LIMIT) if source_quadrature else True
    counts = hit & reaches_wall & counted
    arrival = probes.time + travel_time(t_wall, params) - reference[index]
    sums = detect_on_segment(
        params, sensors, weight, arrival, mirrored, t_end, index, counts,
        probes.order * n + index, n_orders * n,
    )
    return tuple(x.reshape(n_orders, n) for x in sums)


def detect_on_segment(params, sensors: Sensors, weight, time, directions, t_end, index,
                      counts, slot, size):
    """Scatter-add the detections of rays whose segment ends on sensor ``index`` (where
    ``counts``) into ``size`` slots at ``slot`` (the sensor, or order x N + sensor):
    (size,) sums of c, c t, c t^2 (c p.e. of a sensor of efficiency 1) with t = ``time``
    + the segment's travel time (ns)."""
    rate_total = interaction_rates(params)[3]
    cos_in = -jnp.sum(directions * sensors.normals[index], axis=-1)
    detected = (
        weight
        * jnp.exp(-rate_total * t_end)
        * params.quantum_efficiency
        * acceptance_at_cos(params.angular_acceptance, cos_in)
    )
    detected = where(counts, detected, 0.0)
    arrival = time + travel_time(t_end, params)
    zeros = jnp.zeros(size, dtype=weight.dtype)
    return (
        zeros.at[slot].add(detected),
        zeros.at[slot].add(detected * arrival),
        zeros.at[slot].add(detected * arrival * arrival),
    )
