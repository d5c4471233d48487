"""Photon detection by a sensor, shared by both modes: the probability that a photon
arriving on a sensor's disc becomes a photoelectron.

A photon reaching sensor j at incidence theta is detected with probability
p_j = QE x efficiency_j x A(cos theta) (QE the sensor model's quantum efficiency,
efficiency_j the sensor's relative efficiency, A the angular acceptance,
``acceptance_at_cos``), reflected by the glass with probability R_s
(``sensor_reflectivity``), and absorbed otherwise. The expected mode weighs the light
arriving on a sensor by QE x A path by path and applies efficiency_j afterwards
(``expected.expected_response``). In the sampled mode detection and reflection are
exclusive outcomes of one uniform number (``sensor_fate``), which the photon loop draws
when a photon meets a sensor: it asks the response there rather than after the loop,
so that a reflected photon travels on.
"""

from __future__ import annotations

import math

from ..numerics import clip

#: Incidence angles (rad) of the ``angular_acceptance`` table: 0, 10, ..., 90 degrees.
ACCEPTANCE_ANGLES = tuple(math.radians(10.0 * i) for i in range(10))
_ACCEPTANCE_COS = tuple(math.cos(angle) for angle in ACCEPTANCE_ANGLES)


def acceptance_at_cos(table, cos_incidence):
    """Angular acceptance at incidence cos theta: the (10,) table at 0, 10, ..., 90 degrees,
    interpolated linearly in cos theta between its nodes (1 above 0 degrees is the first
    entry; below 90 degrees the last). Written as a sum of clipped ramps: no inverse
    trigonometry and no gathers, which keeps it cheap on every sensor-vertex pair, and
    differentiable in the table and in cos theta."""
    # unrolled on purpose: nine fused element-wise ramps. The same sum on a trailing
    # axis of nodes compiles faster but made the SK forward pass ~50 % slower (the
    # (rays, sensors, 9) intermediate of the next-event estimate).
    value = table[9]
    for i in range(9):
        upper, lower = _ACCEPTANCE_COS[i], _ACCEPTANCE_COS[i + 1]
        ramp = clip((cos_incidence - lower) * (1.0 / (upper - lower)), 0.0, 1.0)
        value = value + (table[i] - table[i + 1]) * ramp
    return value


def detection_probability(params, sensor, cos_incidence):
    """Probability that a photon arriving on sensor ``sensor`` (index array) at incidence
    cos theta becomes a photoelectron: QE x efficiency x acceptance (dimensionless)."""
    acceptance = acceptance_at_cos(params.angular_acceptance, cos_incidence)
    return params.quantum_efficiency * params.efficiency[sensor] * acceptance


def sensor_fate(params, sensor, cos_incidence, u):
    """(detected, reflected) of photons meeting sensor ``sensor`` (index array) at
    incidence cos theta, from one uniform u in [0, 1) each: detected if u < QE x
    efficiency x acceptance, reflected by the glass if not and u < that +
    ``sensor_reflectivity``, absorbed otherwise (exclusive outcomes)."""
    p_detect = detection_probability(params, sensor, cos_incidence)
    detected = u < p_detect
    return detected, ~detected & (u < p_detect + params.sensor_reflectivity)
