"""Sampled (Monte Carlo) transport: individual photons with discrete interactions.

A point source's photons start at its position, direction from
``emission.sample_directions``, time = source time + Gaussian jitter of sigma
``pulse_width`` (ns) (``sample_photons``); a photon bundle's photons (e.g. a particle
track's, ``track_photons``) at their own positions, directions and times
(``sample_photon_bundle``); both then run the same loop: the physics of one step (bulk
interactions, sensors, the wall) and the loop over steps are in ``photon_loop.py``.

Photons run in batches of ``config.batch_size`` inside one jitted ``lax.while_loop``
(compiled once per detector size, source type or bundle, and config; the batch key is
``fold_in(key, batch_index)``) and are tallied on the host (``_tally_batches``), so
memory stays bounded for any number of photons. Lengths in m, times in ns.

Events (transport + sensor response) of sources and particle tracks: ``pseudo_data.py``;
the photons of a track: ``tracks.py``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError, format_value
from ..exported import call_exported
from ..geometry.detector import Detector
from ..geometry.sensor_arrays import Sensors, sensor_grid_for, sensors_for
from ..geometry.sensor_grid import SensorGrid
from ..geometry.shapes import xyz
from ..numerics import strict_array
from ..params import Params, validate_params
from ..sources import (
    DIRECTION_TOLERANCE,
    check_source,
)
from .emission import sample_directions
from .optics import DEFAULT_CONFIG, TransportConfig, check_config
from .photon_loop import (
    ABSORBED_BULK,
    ABSORBED_SENSOR,
    ABSORBED_WALL,
    ALIVE,
    CAPPED,
    DETECTED,
    ESCAPED,
    N_STATUS,
    _follow,
    _launch_photons,
)

#: Smallest batch used for small photon counts (batches are powers of two up to
#: ``config.batch_size``, so few sizes are ever compiled).
MIN_BATCH = 1 << 10


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

    program = functools.partial(
        _transport_source_batch, shape=detector.shape, config=config, batch=batch
    )

    def launch(index):
        return call_exported(
            "transport_source_batch",
            program,
            (detector.shape, config, batch),
            key,
            jax.device_put(np.uint32(index)),
            jax.device_put(np.int32(min(batch, n_photons - index * batch))),
            sensors,
            params_c,
            source_c,
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
    outside = ~inside_detector(detector, position)
    if outside.any():
        raise ConfigError(
            f"photons.position: {int(outside.sum())} outside the {detector.shape.describe()}"
        )
    return position, direction, time


def inside_detector(detector: Detector, position) -> np.ndarray:
    """(M,) bool: the points (M, 3) m lie inside the detector or on its wall (the one
    test of a bundle's photons, made on float64 positions)."""
    position = np.asarray(position, np.float64)
    return np.asarray(detector.shape.distance_to_wall(position)) >= 0


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

    program = functools.partial(
        _transport_bundle_batch, shape=detector.shape, config=config, batch=batch
    )

    def launch(index):
        start = index * batch
        return call_exported(
            "transport_bundle_batch",
            program,
            (detector.shape, config, batch),
            key,
            jnp.uint32(index),
            jnp.int32(min(batch, n_photons - start)),
            sensors,
            params_c,
            _padded(position, start, batch, 0.0, dtype),
            _padded(direction, start, batch, (0.0, 0.0, 1.0), dtype),
            _padded(time, start, batch, 0.0, dtype),
        )

    n_batches = -(-n_photons // batch)
    return _tally_batches(launch, n_batches, detector.n_sensors, source_time, n_photons)


def check_seed(seed) -> int:
    """``seed`` as an int; a one-line ``ConfigError`` unless it is an integer in [0, 2^63)."""
    if not isinstance(seed, numbers.Integral) or isinstance(seed, bool) or not 0 <= seed < 2**63:
        raise ConfigError(f"seed = {format_value(seed)}: must be an integer in [0, 2**63)")
    return int(seed)
