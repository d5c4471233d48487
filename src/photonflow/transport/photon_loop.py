"""The photon-by-photon transport loop of the sampled (Monte Carlo) mode (``sampled.py``):
one step of a batch of photons with discrete interactions, and the loop over steps.

The physics is the one of ``optics.py``, step by step for a batch of photons at once:

1. launch (``_launch_photons``): the photons of a batch start at their emission
   positions and directions (a point source's or a photon bundle's, drawn by
   ``sampled.py``); lanes past the batch's photon count are ``UNUSED``;
2. each step (``_step_function``), for every photon still alive: the distance to the next
   bulk interaction s ~ Exp(total rate) (inf when every length is inf), the distance to
   the wall (``shape.ray_exit``) and the first sensor disc hit before the wall
   (``first_sensor_hit``); the nearest of the three happens:

   - bulk: absorbed with probability rate_abs / rate_total, else scattered (Rayleigh
     or Mie by their rate ratio) into a new direction (``deflect``, uniform azimuth);
   - sensor j: the sensor response decides (``response.detection.sensor_fate``, the
     one definition of detection): detected with probability QE x efficiency_j x
     acceptance(incidence) (direct light by quadrature applies the same QE x
     acceptance, and the expected mode's response the same efficiency),
     reflected specularly off the glass with probability ``sensor_reflectivity``,
     absorbed otherwise (u < p_det: detected; p_det <= u < p_det + R: reflected).
     Detection and reflection are exclusive outcomes of one uniform, so the loop asks
     the response at the moment a photon meets a sensor;
   - wall: reflected with probability ``wall_reflectivity`` (specular with probability
     ``wall_specular_fraction``, else Lambertian about the inward normal), absorbed
     otherwise; in an open medium the world boundary is not a wall: the photon escapes.

   Scatterings and reflections are interaction vertices. A photon that already had
   ``config.n_bounces`` vertices and would scatter or reflect again is counted as
   ``capped`` (lost), so every photon ends within n_bounces + 1 steps.

The loop (``_follow``) is one ``lax.while_loop``; each step follows only the photons
still alive, gathered into chunks of batch / ``COMPACTION`` lanes (``_step_in_chunks``),
and works on x, y, z component arrays (structure of arrays), which XLA on CPU fuses into
a few loops per chunk. Lengths in m, times in ns.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..geometry.sensor_arrays import Sensors
from ..geometry.sensor_grid import first_sensor_hit_xyz
from ..geometry.shapes import xyz
from ..numerics import clip, where
from ..response.detection import sensor_fate
from .optics import (
    deflect_xyz,
    dome_normal_xyz,
    dot_xyz,
    interaction_rates,
    sample_henyey_greenstein_cos,
    sample_rayleigh_cos,
    specular_direction_xyz,
    travel_time,
)

#: Photon fates (status codes of the transport loop).
ALIVE, DETECTED, ABSORBED_BULK, ABSORBED_WALL, ABSORBED_SENSOR, ESCAPED, CAPPED, UNUSED = range(8)
N_STATUS = 8
#: Distance (m) a reflected photon is moved along its new direction, off the surface.
NUDGE = 5e-6
#: Each step follows the photons still alive in chunks this many times smaller than the
#: batch: most photons end on their first segment, and a chunk's working set (its
#: candidate-sensor tests above all) stays in the CPU caches.
COMPACTION = 8


# Vectors are x, y, z component tuples of (B,) arrays (structure of arrays): XLA on CPU
# fuses the component-wise arithmetic of a step into a few loops over the batch.


class PhotonState(NamedTuple):
    """A batch of photons in the transport loop, each field (B,).

    Attributes:
        position: (x, y, z) of the current vertex, m.
        direction: (x, y, z) unit direction of flight.
        wall: distance from the vertex to the wall along the direction, m (computed
            where the direction is set, so that each step's sensor lookup reads it
            from memory: XLA would otherwise recompute it per candidate sensor).
        path: path length travelled so far, m.
        vertices: scatterings and reflections so far.
        status: fate code (``ALIVE`` while in flight).
        sensor: index of the sensor that detected the photon, else -1.
    """

    position: tuple
    direction: tuple
    wall: jax.Array
    path: jax.Array
    vertices: jax.Array
    status: jax.Array
    sensor: jax.Array


#: Values of the lanes of a chunk that hold no photon (a unit direction keeps their
#: arithmetic finite; their results are dropped).
_EMPTY = PhotonState((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.0, 0.0, 0, UNUSED, -1)


def _uniforms(key, count: int, shape, dtype):
    """``count`` independent arrays of uniforms in [0, 1) of ``shape`` (one PRNG draw)."""
    return tuple(jax.random.uniform(key, (count,) + tuple(shape), dtype))


def _wall_distance(shape, position, direction):
    """Distance (m, >= 0) from ``position`` along unit ``direction`` to the wall."""
    t_wall = shape.ray_exit(jnp.stack(position, -1), jnp.stack(direction, -1))
    return jnp.maximum(t_wall, 0.0)


def _bulk_turn(u_process, u_cos, rates, params, anisotropy):
    """(absorbed, cos of the scattering angle) of a bulk interaction: absorbed with
    probability rate_abs / rate_total, else Rayleigh or Mie by their rate ratio."""
    absorption, rayleigh, _, total = rates
    pick = u_process * total
    cos_theta = where(
        pick < absorption + rayleigh,
        sample_rayleigh_cos(u_cos, anisotropy),
        sample_henyey_greenstein_cos(u_cos, params.mie_g),
    )
    return pick < absorption, cos_theta


def _sensor_response(u, direction, point, sensor, sensors: Sensors, params):
    """(detected, reflected, mirror normal) of photons crossing disc ``sensor`` at
    ``point`` (m), from the sensor response's ``sensor_fate`` of one uniform u; the
    mirror is the glass dome over the disc."""
    normal = tuple(sensors.normals[:, k][sensor] for k in range(3))
    centre = tuple(sensors.positions[:, k][sensor] for k in range(3))
    cos_incidence = clip(-dot_xyz(direction, normal), -1.0, 1.0)
    detected, reflected = sensor_fate(params, sensor, cos_incidence, u)
    offset = tuple(p - c for p, c in zip(point, centre, strict=True))
    return detected, reflected, dome_normal_xyz(offset, normal, sensors.radius[sensor])


def _wall_response(u, params):
    """(reflected, specular) of photons reaching the wall from one uniform u: reflected
    if u < R (``wall_reflectivity``), specularly if moreover u < R x
    ``wall_specular_fraction`` (u / R is uniform given a reflection), else Lambertian."""
    reflectivity = params.wall_reflectivity
    return u < reflectivity, u < reflectivity * params.wall_specular_fraction


def _new_direction(direction, bulk, cos_scatter, on_sensor, dome, specular, wall, u_cos, u_phi):
    """Unit direction after an interaction, one per photon: a turn about an axis (bulk
    scattering by ``cos_scatter``; Lambertian reflection, cos = sqrt(u_cos), about the
    inward ``wall`` normal) at azimuth 2 pi u_phi, or a mirror image (about the sensor's
    ``dome`` normal, or the wall's for a specular reflection)."""
    turns = bulk | (~on_sensor & ~specular)
    axis = tuple(where(bulk, d, n) for d, n in zip(direction, wall, strict=True))
    cos_theta = where(bulk, cos_scatter, jnp.sqrt(u_cos))
    turned = deflect_xyz(axis, cos_theta, 2.0 * math.pi * u_phi)
    mirror = tuple(where(on_sensor, m, n) for m, n in zip(dome, wall, strict=True))
    mirrored = specular_direction_xyz(direction, mirror)
    new = tuple(where(turns, t, m) for t, m in zip(turned, mirrored, strict=True))
    length = jnp.sqrt(dot_xyz(new, new))
    return tuple(c / length for c in new)


def _fate(bulk, absorbed, on_sensor, detected, sensor_reflected, wall_reflected, has_walls):
    """Status code after a segment ends: ``ALIVE`` for a scattering or a reflection."""
    at_wall = where(wall_reflected, ALIVE, ABSORBED_WALL if has_walls else ESCAPED)
    at_sensor = where(detected, DETECTED, where(sensor_reflected, ALIVE, ABSORBED_SENSOR))
    surface = where(on_sensor, at_sensor, at_wall)
    return where(bulk, where(absorbed, ABSORBED_BULK, ALIVE), surface)


def _step_function(shape, config, sensors: Sensors, params):
    """``step(key, photons) -> photons``: one segment and its interaction for photons that
    are all ALIVE (``_step_in_chunks`` passes only those, and drops the results of its
    fill lanes); closure over constants. Uniforms per photon, from ``key``: the free path,
    the process (bulk kind, detection, reflection), the polar angle and the azimuth."""
    rates = interaction_rates(params)
    total = rates[3]
    has_walls = bool(shape.has_walls)

    def step(key, photons):
        position, direction = photons.position, photons.direction
        u_free, u_process, u_cos, u_phi = _uniforms(key, 4, photons.path.shape, photons.path.dtype)

        t_wall = photons.wall
        hit, t_hit = first_sensor_hit_xyz(
            sensors.grid, sensors.positions, sensors.normals, sensors.radius, position,
            direction, t_wall,
        )
        on_sensor = hit >= 0
        t_surface = where(on_sensor, t_hit, t_wall)
        free_path = -jnp.log1p(-u_free) / where(total > 0, total, 1.0)
        bulk = where(total > 0, free_path, jnp.inf) < t_surface
        distance = where(bulk, free_path, t_surface)
        point = tuple(p + distance * d for p, d in zip(position, direction, strict=True))

        absorbed, cos_scatter = _bulk_turn(
            u_process, u_cos, rates, params, config.rayleigh_anisotropy
        )
        detected, sensor_reflected, dome = _sensor_response(
            u_process, direction, point, where(on_sensor, hit, 0), sensors, params
        )
        wall_reflected, specular = _wall_response(u_process, params)
        if not has_walls:  # the world boundary of an open medium: nothing comes back
            wall_reflected = jnp.zeros_like(wall_reflected)
        wall_normal = xyz(shape.inward_normal(jnp.stack(point, -1)))

        new_dir = _new_direction(
            direction, bulk, cos_scatter, on_sensor, dome, specular, wall_normal, u_cos, u_phi
        )

        outcome = _fate(
            bulk, absorbed, on_sensor, detected, sensor_reflected, wall_reflected, has_walls
        )
        capped = (outcome == ALIVE) & (photons.vertices >= config.n_bounces)
        status = where(capped, CAPPED, outcome)
        nudge = where(bulk, 0.0, NUDGE)  # reflected photons leave the surface
        position = tuple(p + nudge * d for p, d in zip(point, new_dir, strict=True))
        # Written unconditionally: what a photon that ended carries is never read again.
        return PhotonState(
            position=position,
            direction=new_dir,
            wall=_wall_distance(shape, position, new_dir),
            path=photons.path + distance,
            vertices=photons.vertices + 1,
            status=status,
            sensor=where(status == DETECTED, hit, -1),
        )

    return step


def _launch_photons(shape, position, direction, n_active, batch: int, dtype) -> PhotonState:
    """The ``batch`` lanes of a fresh batch: the first ``n_active`` ALIVE at their emission
    ``position`` (m) and unit ``direction`` (x, y, z tuples of (B,)), the rest UNUSED."""
    return PhotonState(
        position=position,
        direction=direction,
        wall=_wall_distance(shape, position, direction),
        path=jnp.zeros(batch, dtype),
        vertices=jnp.zeros(batch, jnp.int32),
        status=where(jnp.arange(batch) < n_active, ALIVE, UNUSED).astype(jnp.int32),
        sensor=jnp.full(batch, -1, jnp.int32),
    )


def _follow(loop_key, photons, emit_time, sensors: Sensors, params, shape, config, batch: int):
    """Run the transport loop on a launched batch until no photon is ALIVE (at most
    ``n_bounces`` + 1 steps); returns (status (B,), sensor (B,), arrival time (B,) ns)."""
    step = _step_function(shape, config, sensors, params)

    def running(carry):
        index, photons = carry
        return (index <= config.n_bounces) & jnp.any(photons.status == ALIVE)

    def advance(carry):  # step ``index`` draws from fold_in(loop_key, index)
        index, photons = carry
        step_key = jax.random.fold_in(loop_key, index)
        return index + 1, _step_in_chunks(photons, step, step_key, max(batch // COMPACTION, 1))

    _, photons = jax.lax.while_loop(running, advance, (jnp.int32(0), photons))
    return photons.status, photons.sensor, emit_time + travel_time(photons.path, params)



def _step_in_chunks(photons, step, key, chunk: int):
    """Apply ``step(key, photons)`` to the ALIVE photons only, gathered into chunks of
    ``chunk`` lanes (after the first step most photons have ended), and scatter the
    results back. Chunk c draws its random numbers from ``fold_in(key, c)``."""
    batch = photons.status.shape[0]
    lanes, n_alive = _alive_lanes(photons.status == ALIVE, -(-batch // chunk) * chunk)
    n_chunks = (n_alive + chunk - 1) // chunk

    def one_chunk(c, photons):
        these = jax.lax.dynamic_slice(lanes, (c * chunk,), (chunk,))
        sub = jax.tree.map(
            lambda x, empty: jnp.take(x, these, axis=0, mode="fill", fill_value=empty),
            photons,
            _EMPTY,
        )
        sub = step(jax.random.fold_in(key, c), sub)
        return jax.tree.map(lambda x, y: x.at[these].set(y, mode="drop"), photons, sub)

    return jax.lax.fori_loop(0, n_chunks, one_chunk, photons)


def _alive_lanes(alive, size: int):
    """(indices of the True entries of ``alive`` in order, padded with ``len(alive)`` to
    ``size`` >= len(alive) entries; their count). ``jnp.nonzero`` with a log-depth scan
    for the ranks: its cumsum lowers to a reduce-window that is twice as slow on CPU."""
    n = alive.shape[0]
    rank = jax.lax.associative_scan(jnp.add, alive.astype(jnp.int32))
    lanes = (
        jnp.full(size, n, jnp.int32)
        .at[where(alive, rank - 1, size)]
        .set(jnp.arange(n, dtype=jnp.int32), mode="drop")
    )
    return lanes, rank[-1]
