"""Source light mirrored once by the wall into a sensor, by quadrature (no sampling noise).

A specular reflection is a delta function in direction: a next-event estimate cannot see
it, and rays find it only when a mirrored ray happens to hit a sensor, with a large
weight (on SK at 1,024 rays ~23 p.e. per hit against ~0.3 p.e. of mirrored light per
sensor on average). The first-order path, source s -> wall point P -> sensor j, is
therefore computed like direct light, for every node x of a 7-point rule on disc j
(Radon's degree-5 rule: the centre and six points at sqrt(2/3) r):

    mu_j = N R_w f_s sum_x w_x sum_P S(omega_P) cos_in(x) / A_P(x)
           x QE A(theta_in) exp(-rate_total L) [P not covered by a sensor]

(light of a sensor of efficiency 1: the sensor response applies eff_j), with
L = |P - s| + |x - P| the path length, omega_P the emission direction toward P, A_P the
area per steradian of the reflected ray tube at x (m^2/sr; photons per m^2 across the
ray = S / A_P) and the indicator that the photon reaches the black wall at P
rather than a sensor disc. The reflection points P and the ray tubes' areas A_P per
wall shape (planar faces, a cylinder's barrel, a sphere): ``mirror_geometry.py``; the
share of the wall under other sensor discs, each disc mapped onto the wall whole as an
ellipse: ``mirror_cover.py``.

Near caustics (a curved wall focusing the ray tube below ``FOCUSING_LIMIT`` of a flat
mirror's, e.g. the axis of a cylinder for a source on it) a node rule is poor: those
paths are left to the rays. Everywhere else the ray estimator of ``indirect.py`` leaves
out its detections after a first-order mirror vertex (it still follows those rays), so
the sum stays unbiased.

The light, the covered part included, is differentiable in the source position;
``Params`` enter only through the weights (``mirror_light``). Lengths m, times ns.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..geometry.sensor_arrays import Sensors
from ..numerics import where
from ..params import Params
from ..pytree import pytree_dataclass
from ..response.detection import acceptance_at_cos
from .mirror_cover import uncovered_share
from .mirror_geometry import disc_nodes, focusing_ratio, reflection_points
from .optics import interaction_rates, travel_time

#: Paths whose ray tube is focused below this fraction of a flat mirror's are left to
#: the rays (``focusing_ratio``).
FOCUSING_LIMIT = 0.25


@pytree_dataclass
class MirrorPaths:
    """The first-order mirror paths of one source (``mirror_paths``): the part of
    ``mirror_light`` that does not depend on ``Params``, for T = 7 N quadrature nodes
    (disc by disc) and M reflection slots per node.

    Attributes:
        weight: (T, M) m^2/sr-normalised light per emitted photon and unit specular
            reflectivity R_w f_s, before QE, acceptance and attenuation: the
            emission density toward the wall point (1/sr) x cos_in / the ray tube's area
            per sr (m^2/sr) x the node's area (m^2) x the share of it over bare wall;
            0 where the path does not count (no reflection, the wall under a disc, the
            disc facing away, or focused below ``FOCUSING_LIMIT``: left to the rays).
        cos_in: (T, M) cosine of the incidence on the disc at the node.
        path: (T, M) m, source -> wall -> node.
    """

    weight: jax.Array
    cos_in: jax.Array
    path: jax.Array


def mirror_paths(shape, sensors: Sensors, source) -> MirrorPaths:
    """The first-order mirror paths from ``source`` to every sensor (``MirrorPaths``).

    Args:
        shape: the walled ``Shape`` (``Cylinder``, ``Sphere`` or ``Box``).
        sensors: the detector's ``Sensors`` (m). The wall under other discs, across a
            disc's whole mirrored patch, is found with its ``near_grid`` (every disc
            within a few radii of a point); without one, with its ``grid`` (only the
            discs within r + ``BASE_MARGIN`` of a point, too few for patches larger
            than that).
        source: a calibration source (position m, ``emission_density``).

    Differentiable in the source position (the roots by their implicit-function
    derivative, the covered share chord by chord). For a fixed source (a calibration
    run) it can be computed once and passed to ``mirror_light`` at every ``Params``.
    """
    sensor_positions, sensor_normals, sensor_radius = (
        sensors.positions, sensors.normals, sensors.radius
    )
    n = sensor_positions.shape[0]
    nodes, node_area = disc_nodes(sensor_positions, sensor_normals, sensor_radius)
    per_disc = nodes.shape[1]
    targets = nodes.reshape(-1, 3)
    receiver = jnp.repeat(jnp.arange(n), per_disc)
    points, valid = reflection_points(shape, source.position, nodes)
    # slots without a reflection get a harmless point inside (finite values and gradients)
    harmless = 0.5 * (source.position + targets)[:, None, :]
    points = where(valid[..., None], points, harmless)
    focusing = focusing_ratio(shape, source.position, points, targets[:, None])

    incoming = points - source.position
    l_in = jnp.linalg.norm(incoming, axis=-1)
    emission = incoming / l_in[..., None]
    outgoing = targets[:, None] - points
    l_out = jnp.linalg.norm(outgoing, axis=-1)
    cos_in = -jnp.sum(outgoing * sensor_normals[receiver][:, None], axis=-1) / l_out
    uncovered = uncovered_share(
        sensors.grid if sensors.near_grid is None else sensors.near_grid,
        sensor_positions, sensor_normals, sensor_radius,
        points.reshape(n, per_disc, -1, 3),
        valid.reshape(n, per_disc, -1),
    ).reshape(points.shape[:2])
    counts = valid & (uncovered > 0) & (cos_in > 0)
    counts = counts & (jax.lax.stop_gradient(focusing) >= FOCUSING_LIMIT)

    path = l_in + l_out
    safe_tube = where(counts, focusing * path * path, 1.0)  # ray-tube area per sr
    weight = (
        source.emission_density(emission)
        * jnp.maximum(cos_in, 0.0)
        / safe_tube
        * node_area.reshape(-1)[:, None]
        * uncovered
    )
    return MirrorPaths(weight=where(counts, weight, 0.0), cos_in=cos_in, path=path)


def mirror_light(params: Params, paths: MirrorPaths, source, reference_time):
    """First-order specular light from the source per sensor (see the module docstring).

    Args:
        params: detector parameters (reflectivities, lengths m).
        paths: the source's ``mirror_paths``.
        source: the same source (photons, time ns).
        reference_time: (N,) ns subtracted from arrival times.

    Returns:
        (N,) sums of c, c t and c t^2: c expected p.e. of a sensor of efficiency 1, t
        arrival time minus the reference (ns; before the sensor's time offset, the
        transit-time spread and the pulse width).
    """
    n = reference_time.shape[0]
    receiver = jnp.repeat(jnp.arange(n), paths.weight.shape[0] // n)
    rate_total = interaction_rates(params)[3]
    detected = (
        source.n_photons
        * params.wall_reflectivity
        * params.wall_specular_fraction
        * paths.weight
        * params.quantum_efficiency
        * acceptance_at_cos(params.angular_acceptance, jnp.maximum(paths.cos_in, 0.0))
        * jnp.exp(-rate_total * paths.path)
    )
    relative = source.time + travel_time(paths.path, params) - reference_time[receiver][:, None]
    return tuple(jnp.sum((detected * relative**k).reshape(n, -1), axis=1) for k in range(3))
