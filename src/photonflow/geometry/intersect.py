"""Ray intersections with the boundary and with sensor discs, vectorised.

A sensor is a flat disc (centre c, inward unit normal n, radius r) that detects light
arriving on its front face, i.e. travelling against its normal (d . n < 0).
The per-pair routine ``disc_hit_distance`` is written for one ray and one disc and
lifted to arrays with ``vmap``. It is float32-safe at 40 m: the in-plane miss
distance is computed from the centre-relative vector, never from two large
nearly-equal hit coordinates.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..inline_jit import inline_jit
from ..numerics import where
from .detector import Detector
from .shapes import Shape


def disc_hit_distance_xyz(origin, direction, centre, normal, radius):
    """The ray-disc test on x, y, z components: each vector argument is a 3-sequence of
    arrays that broadcast together (e.g. rays (R, 1) against candidate discs (R, K)).

    Returns the distance (m) to the disc's front face, ``inf`` where the ray misses it.
    Written component-wise (structure of arrays) so that XLA fuses it into one loop; it
    is float32-safe at 40 m because the in-plane miss distance is computed from the
    centre-relative vector, never from two large nearly-equal hit coordinates.
    """
    to_centre = [c - o for c, o in zip(centre, origin, strict=True)]
    cos_incidence = sum(d * n for d, n in zip(direction, normal, strict=True))
    facing = cos_incidence < 0
    safe_cos = where(facing, cos_incidence, -1.0)
    t = sum(w * n for w, n in zip(to_centre, normal, strict=True)) / safe_cos
    miss2 = sum((t * d - w) ** 2 for d, w in zip(direction, to_centre, strict=True))
    hit = facing & (t > 0) & (miss2 <= radius * radius)
    return where(hit, t, jnp.inf)


def disc_hit_distance(origin, direction, centre, normal, radius):
    """Distance (m) along one ray to one sensor disc's front face, ``inf`` if it misses.

    origin (3,) m, direction (3,) unit, centre (3,) m, normal (3,) unit (inward),
    radius () m.
    """

    def parts(vector):
        return [vector[..., k] for k in range(3)]

    return disc_hit_distance_xyz(
        parts(origin), parts(direction), parts(centre), parts(normal), radius
    )


def _first_disc_hit(origin, direction, centres, normals, radii):
    distances = jax.vmap(disc_hit_distance, in_axes=(None, None, 0, 0, 0))(
        origin, direction, centres, normals, radii
    )
    index = jnp.argmin(distances)
    distance = distances[index]
    return where(jnp.isfinite(distance), index, -1).astype(jnp.int32), distance


@inline_jit(static_argnames=("batch_size",))
def ray_sensor_hits(
    origins, directions, sensor_positions, sensor_normals, sensor_radius, batch_size: int = 256
):
    """First sensor disc hit by each ray (brute force over all sensors).

    Args:
        origins: (R, 3) ray origins, m.
        directions: (R, 3) unit directions.
        sensor_positions, sensor_normals, sensor_radius: (N, 3), (N, 3), (N,) as in
            ``Detector``.
        batch_size: rays processed at once (memory ~ batch_size x N).

    Returns:
        ``(sensor_index, distance)``: (R,) int32 index of the nearest disc hit (-1 for
        none) and (R,) distance to it in m (inf for none).
    """

    def one(ray):
        return _first_disc_hit(ray[0], ray[1], sensor_positions, sensor_normals, sensor_radius)

    rays = jnp.stack([origins, directions], axis=1)
    return jax.lax.map(one, rays, batch_size=batch_size)


def detector_ray_hits(detector: Detector, origins, directions, batch_size: int = 256):
    """``ray_sensor_hits`` for a ``Detector``'s sensors. Returns (sensor_index, distance m)."""
    dtype = jnp.asarray(origins).dtype
    return ray_sensor_hits(
        jnp.asarray(origins),
        jnp.asarray(directions, dtype=dtype),
        jnp.asarray(detector.sensor_positions, dtype=dtype),
        jnp.asarray(detector.sensor_normals, dtype=dtype),
        jnp.asarray(detector.sensor_radius, dtype=dtype),
        batch_size=batch_size,
    )


def ray_boundary(shape: Shape, origins, directions):
    """Entering and leaving distances (m) of rays with a detector boundary.

    Thin vectorised wrapper over ``Shape.ray_interval``: origins and directions
    (..., 3); returns ``(t_enter, t_exit)``, each (...,); a miss gives (inf, -inf).
    """
    return shape.ray_interval(jnp.asarray(origins), jnp.asarray(directions))
