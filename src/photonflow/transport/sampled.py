"""Sampled (Monte Carlo) transport: individual photons with discrete interactions.

The physics is the one of ``optics.py``, step by step for a batch of photons at once:

1. emission: a point source's photons start at its position, direction from
   ``emission.sample_directions``, time = source time + Gaussian jitter of sigma
   ``pulse_width`` (ns) (``sample_photons``); a photon bundle's photons (e.g. a particle
   track's, ``track_photons``) at their own positions, directions and times
   (``sample_photon_bundle``); both then run the same loop (``_follow``);
2. each step, for every photon still alive: the distance to the next bulk interaction
   s ~ Exp(total rate) (inf when every length is inf), the distance to the wall
   (``shape.ray_exit``) and the first sensor disc hit before the wall
   (``first_sensor_hit``); the nearest of the three happens:

   - bulk: absorbed with probability rate_abs / rate_total, else scattered (Rayleigh
     or Mie by their rate ratio) into a new direction (``deflect``, uniform azimuth);
   - sensor j: the sensor response decides (``response.detection.sensor_fate``, the
     one definition of detection): detected with probability QE x efficiency_j x
     acceptance(incidence) (exactly the factor of direct light by quadrature),
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

Photons run in batches of ``config.batch_size`` inside one jitted ``lax.while_loop``
(compiled once per detector size, source type or bundle, and config; the batch key is
``fold_in(key, batch_index)``) and are tallied on the host (``_tally_batches``), so
memory stays bounded for any number of photons. Each step follows only the photons
still alive, gathered into chunks of batch / ``COMPACTION`` lanes, and works on x, y, z
component arrays (structure of arrays), which XLA on CPU fuses into a few loops per
chunk. Lengths in m, times in ns.

Events (transport + sensor response) of sources and particle tracks: ``pseudo_data.py``;
the photons of a track: ``tracks.py``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError, format_value
from ..geometry.detector import Detector
from ..geometry.sensor_arrays import Sensors, sensor_grid_for, sensors_for
from ..geometry.sensor_grid import SensorGrid, first_sensor_hit_xyz
from ..geometry.shapes import xyz
from ..numerics import clip, strict_array, where
from ..params import Params, validate_params
from ..response.detection import sensor_fate
from ..sources import (
    DIRECTION_TOLERANCE,
    check_source,
)
from .emission import sample_directions
from .optics import (
    DEFAULT_CONFIG,
    TransportConfig,
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
#: Smallest batch used for small photon counts (batches are powers of two up to
#: ``config.batch_size``, so few sizes are ever compiled).
MIN_BATCH = 1 << 10
#: Each step follows the photons still alive in chunks this many times smaller than the
#: batch: most photons end on their first segment, and a chunk's working set (its
#: candidate-sensor tests above all) stays in the CPU caches.
COMPACTION = 8


@dataclasses.dataclass(frozen=True)
class PhotonTally:
    """What became of the photons of one source pulse.

    Attributes:
        n_pe: (N,) int64 detected photons (photoelectrons) per sensor.
        photon_sensor: (D,) int32 sensor index of each detected photon.
        photon_time: (D,) float64 arrival time of each detected photon, ns (emission
            time incl. pulse jitter + path length x n_g / c; no transit-time spread
            and no sensor time offset yet).
        source_time: the source's nominal time, ns (origin of the readout window).
        emitted: photons emitted.
        detected: photons detected (= D = n_pe.sum()).
        absorbed_bulk, absorbed_wall, absorbed_sensor: photons absorbed in the medium,
            by the wall and by a sensor without being detected.
        escaped: photons that left an open medium's world volume.
        capped: photons that would have needed more than ``n_bounces`` vertices.
    """

    n_pe: np.ndarray
    photon_sensor: np.ndarray
    photon_time: np.ndarray
    source_time: float
    emitted: int
    detected: int
    absorbed_bulk: int
    absorbed_wall: int
    absorbed_sensor: int
    escaped: int
    capped: int

    @property
    def absorbed(self) -> int:
        """All absorbed photons: bulk + wall + sensor."""
        return self.absorbed_bulk + self.absorbed_wall + self.absorbed_sensor

    @property
    def lost(self) -> int:
        """Photons neither detected nor absorbed: escaped + capped."""
        return self.escaped + self.capped

    @property
    def n_sensors(self) -> int:
        """Number of sensors N."""
        return int(self.n_pe.shape[0])


def check_config(config: TransportConfig) -> TransportConfig:
    """Raise a one-line ``ConfigError`` for an unusable ``TransportConfig``; return it."""

    def bad(name, value, rule):
        return ConfigError(f"config.{name} = {format_value(value)}: {rule}")

    for name in ("n_bounces", "batch_size"):
        value = getattr(config, name)
        minimum = 0 if name == "n_bounces" else 1
        if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < minimum:
            raise bad(name, value, f"must be an integer >= {minimum}")
    start, end = (float(x) for x in config.window)
    if not (math.isfinite(start) and math.isfinite(end) and start < end):
        raise bad("window", config.window, "must be finite (start, end) ns with start < end")
    for name in ("charge_threshold", "rayleigh_anisotropy"):
        if not math.isfinite(float(getattr(config, name))):
            raise bad(name, getattr(config, name), "must be finite")
    return config


def photon_count(source) -> int:
    """``source.n_photons`` rounded to an integer; ``ConfigError`` if that is not >= 1."""
    value = float(np.asarray(source.n_photons))
    count = round(value) if math.isfinite(value) else 0
    if count < 1:
        raise ConfigError(f"source.n_photons = {format_value(value)}: rounds to {count} photons")
    return int(count)


def batch_size_for(n_photons: int, config: TransportConfig) -> int:
    """Photons per batch: the power of two >= n_photons, at least ``MIN_BATCH``, at most
    ``config.batch_size``."""
    fitted = max(MIN_BATCH, 1 << max(int(n_photons) - 1, 0).bit_length())
    return int(min(config.batch_size, fitted))


# ---- one step of the transport loop (pure functions on batches) -------------------------
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


@functools.partial(jax.jit, static_argnames=("shape", "config", "batch"))
def _transport_source_batch(
    key, batch_index, n_active, sensors: Sensors, params, source, *, shape, config, batch
):
    """Emit and transport one batch of a point source (keys split from
    ``fold_in(key, batch_index)``: emission directions, pulse jitter, loop)."""
    dtype = params.absorption_length.dtype
    batch_key = jax.random.fold_in(key, batch_index)
    emit_key, jitter_key, loop_key = jax.random.split(batch_key, 3)
    u = jax.random.uniform(emit_key, (2, batch), dtype)
    direction = xyz(sample_directions(source, u[0], u[1]))
    emit_time = source.time + source.pulse_width * jax.random.normal(jitter_key, (batch,), dtype)
    position = tuple(jnp.full(batch, source.position[k], dtype) for k in range(3))
    photons = _launch_photons(shape, position, direction, n_active, batch, dtype)
    return _follow(loop_key, photons, emit_time, sensors, params, shape, config, batch)


@functools.partial(jax.jit, static_argnames=("shape", "config", "batch"))
def _transport_bundle_batch(
    key, batch_index, n_active, sensors: Sensors, params, position, direction, emit_time,
    *, shape, config, batch,
):
    """Transport one batch of given photons: position (B, 3) m, unit direction (B, 3),
    emission time (B,) ns, the first ``n_active`` real (loop key ``fold_in(key,
    batch_index)``)."""
    photons = _launch_photons(
        shape, xyz(position), xyz(direction), n_active, batch, params.absorption_length.dtype
    )
    loop_key = jax.random.fold_in(key, batch_index)
    return _follow(loop_key, photons, emit_time, sensors, params, shape, config, batch)


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


def as_key(key_or_seed):
    """A JAX PRNG key from a key (returned as is) or a non-negative integer seed."""
    if isinstance(key_or_seed, numbers.Integral) and not isinstance(key_or_seed, bool):
        if not 0 <= int(key_or_seed) < 2**63:
            raise ConfigError(f"seed = {int(key_or_seed)}: must be in [0, 2**63)")
        return jax.random.PRNGKey(int(key_or_seed))
    if isinstance(key_or_seed, jax.Array):
        return key_or_seed
    raise ConfigError(f"seed = {format_value(key_or_seed)}: must be an integer or a JAX key")


def grid_for(detector: Detector, grid: SensorGrid | None) -> SensorGrid | None:
    """The sensor grid the loop uses: ``grid`` (when None the detector's, built once per
    detector object by ``sensor_grid_for``) for a walled detector, None for an open
    medium."""
    if not detector.shape.has_walls:
        return None
    return sensor_grid_for(detector) if grid is None else grid


def _device_constants(detector: Detector, params: Params, grid: SensorGrid | None):
    """(dtype, the detector's ``Sensors`` with lookup ``grid`` (None: its own; none in an
    open medium) and no near grid, params) in the params' float dtype without weak
    typing, as the jitted batches take them."""
    dtype = jnp.result_type(params.absorption_length)
    grid = grid if detector.shape.has_walls else None
    sensors = sensors_for(detector, dtype, grid, near=False)
    return dtype, sensors, jax.tree.map(functools.partial(strict_array, dtype=dtype), params)


def _tally_batches(launch, n_batches: int, n_sensors: int, source_time: float, emitted: int):
    """Run ``launch(index) -> (status, sensor, time)`` for every batch and tally them; each
    batch is dispatched before the host work on the previous one."""
    counts = np.zeros(N_STATUS, np.int64)
    hit_sensors, hit_times = [np.zeros(0, np.int32)], [np.zeros(0)]
    pending = launch(0) if n_batches else None
    for index in range(n_batches):
        current = pending
        if index + 1 < n_batches:
            pending = launch(index + 1)
        status, sensor, time = (np.asarray(a) for a in current)
        counts += np.bincount(status, minlength=N_STATUS)
        detected = status == DETECTED
        hit_sensors.append(sensor[detected])
        hit_times.append(time[detected].astype(np.float64))
    photon_sensor = np.concatenate(hit_sensors).astype(np.int32)
    return PhotonTally(
        n_pe=np.bincount(photon_sensor, minlength=n_sensors).astype(np.int64),
        photon_sensor=photon_sensor,
        photon_time=np.concatenate(hit_times),
        source_time=float(source_time),
        emitted=int(emitted),
        detected=int(counts[DETECTED]),
        absorbed_bulk=int(counts[ABSORBED_BULK]),
        absorbed_wall=int(counts[ABSORBED_WALL]),
        absorbed_sensor=int(counts[ABSORBED_SENSOR]),
        escaped=int(counts[ESCAPED]),
        capped=int(counts[CAPPED] + counts[ALIVE]),
    )


def sample_photons(
    detector: Detector,
    params: Params,
    source,
    key,
    *,
    config: TransportConfig = DEFAULT_CONFIG,
    grid: SensorGrid | None = None,
) -> PhotonTally:
    """Follow ``source.n_photons`` photons one by one through the detector (Monte Carlo).

    Args:
        detector: geometry and sensors (m).
        params: optical and sensor parameters (lengths m, times ns); validated.
        source: an ``IsotropicSource``, ``LaserSource`` or ``DiffuserSource`` (position
            m, time ns); validated with ``check_source``. ``n_photons`` is rounded to an
            integer (any size: photons run in batches of ``config.batch_size``).
        key: JAX PRNG key or integer seed.
        config: ``TransportConfig`` (``n_bounces`` caps the vertices per photon).
        grid: the detector's ``SensorGrid`` (built here when None and the detector has
            walls; pass it to save the build when sampling many pulses).

    Returns:
        A ``PhotonTally`` with detected + absorbed + lost == emitted exactly.

    Raises:
        ConfigError: bad source, parameters or config (one line).
    """
    check_config(config)
    validate_params(params, detector.n_sensors)
    check_source(source, detector)
    n_photons = photon_count(source)
    key = as_key(key)
    dtype, sensors, params_c = _device_constants(detector, params, grid)
    source_c = jax.tree.map(functools.partial(strict_array, dtype=dtype), source)
    batch = batch_size_for(n_photons, config)

    def launch(index):
        return _transport_source_batch(
            key,
            jax.device_put(np.uint32(index)),
            jax.device_put(np.int32(min(batch, n_photons - index * batch))),
            sensors,
            params_c,
            source_c,
            shape=detector.shape,
            config=config,
            batch=batch,
        )

    n_batches = -(-n_photons // batch)
    source_time = float(np.asarray(source.time))
    return _tally_batches(launch, n_batches, detector.n_sensors, source_time, n_photons)


def check_bundle(photons, detector: Detector):
    """(position (M, 3) m, direction (M, 3) unit, time (M,) ns) float64 arrays of a
    photon bundle; a one-line ``ConfigError`` for bad shapes, non-finite values,
    directions off unit length by more than ``DIRECTION_TOLERANCE`` or photons outside
    the detector."""
    position = np.asarray(photons.position, np.float64)
    direction = np.asarray(photons.direction, np.float64)
    time = np.asarray(photons.time, np.float64)
    count = time.shape[0] if time.ndim == 1 else -1
    for name, value, shape, text in (
        ("position", position, (count, 3), "(M, 3)"),
        ("direction", direction, (count, 3), "(M, 3)"),
        ("time", time, (count,), "(M,)"),
    ):
        if value.shape != shape:
            raise ConfigError(f"photons.{name}: shape {value.shape}, expected {text}")
        if not np.isfinite(value).all():
            raise ConfigError(f"photons.{name}: {int((~np.isfinite(value)).sum())} not finite")
    off_unit = np.abs(np.linalg.norm(direction, axis=-1) - 1.0) > DIRECTION_TOLERANCE
    if off_unit.any():
        raise ConfigError(f"photons.direction: {int(off_unit.sum())} not unit vectors")
    outside = np.asarray(detector.shape.distance_to_wall(position)) < 0
    if outside.any():
        raise ConfigError(
            f"photons.position: {int(outside.sum())} outside the {detector.shape.describe()}"
        )
    return position, direction, time


def _padded(array: np.ndarray, start: int, batch: int, fill, dtype) -> jax.Array:
    """``array[start:start + batch]`` padded with ``fill`` rows to ``batch`` rows."""
    rows = array[start : start + batch]
    pad = np.broadcast_to(np.asarray(fill, array.dtype), (batch - rows.shape[0],) + rows.shape[1:])
    return jnp.asarray(np.concatenate([rows, pad]), dtype)


def sample_photon_bundle(
    detector: Detector,
    params: Params,
    photons,
    key,
    *,
    source_time: float = 0.0,
    config: TransportConfig = DEFAULT_CONFIG,
    grid: SensorGrid | None = None,
) -> PhotonTally:
    """Follow given photons one by one through the detector (Monte Carlo).

    The transport loop, fates and tally are those of ``sample_photons``; each photon
    starts at its own position, direction and time instead of a point source's.

    Args:
        detector: geometry and sensors (m).
        params: optical and sensor parameters (lengths m, times ns); validated. The
            transport is single-wavelength: every photon gets these values.
        photons: anything with ``position`` (M, 3) m, ``direction`` (M, 3) unit and
            ``time`` (M,) ns (e.g. ``photonflow.generator.Photons``), every photon
            inside the detector; M may be 0. Checked with ``check_bundle``.
        key: JAX PRNG key or integer seed; batch b draws from ``fold_in(key, b)``.
        source_time: origin of the readout window, ns (a track's start time).
        config: ``TransportConfig``; photons run in batches of at most ``batch_size``.
        grid: the detector's ``SensorGrid`` (built here when None).

    Returns:
        A ``PhotonTally`` with emitted = M and detected + absorbed + lost == emitted.

    Raises:
        ConfigError: bad photons, parameters or config (one line).
    """
    check_config(config)
    validate_params(params, detector.n_sensors)
    position, direction, time = check_bundle(photons, detector)
    key = as_key(key)
    dtype, sensors, params_c = _device_constants(detector, params, grid)
    n_photons = int(time.shape[0])
    batch = batch_size_for(n_photons, config)

    def launch(index):
        start = index * batch
        return _transport_bundle_batch(
            key,
            jnp.uint32(index),
            jnp.int32(min(batch, n_photons - start)),
            sensors,
            params_c,
            _padded(position, start, batch, 0.0, dtype),
            _padded(direction, start, batch, (0.0, 0.0, 1.0), dtype),
            _padded(time, start, batch, 0.0, dtype),
            shape=detector.shape,
            config=config,
            batch=batch,
        )

    n_batches = -(-n_photons // batch)
    return _tally_batches(launch, n_batches, detector.n_sensors, source_time, n_photons)


def check_seed(seed) -> int:
    """``seed`` as an int; a one-line ``ConfigError`` unless it is an integer in [0, 2^63)."""
    if not isinstance(seed, numbers.Integral) or isinstance(seed, bool) or not 0 <= seed < 2**63:
        raise ConfigError(f"seed = {format_value(seed)}: must be an integer in [0, 2**63)")
    return int(seed)
