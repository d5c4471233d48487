"""Sampled (Monte Carlo) transport: individual photons with discrete interactions.

The physics is the one of ``optics.py``, step by step for a batch of photons at once:

1. emission at the source position, direction from ``emission.sample_directions``,
   time = source time + Gaussian jitter of sigma ``pulse_width`` (ns);
2. each step, for every photon still alive: the distance to the next bulk interaction
   s ~ Exp(total rate) (inf when every length is inf), the distance to the wall
   (``shape.ray_exit``) and the first sensor disc hit before the wall
   (``first_sensor_hit``); the nearest of the three happens:

   - bulk: absorbed with probability rate_abs / rate_total, else scattered (Rayleigh
     or Mie by their rate ratio) into a new direction (``deflect``, uniform azimuth);
   - sensor j: detected with probability QE x efficiency_j x acceptance(incidence)
     (exactly the factor of direct light by quadrature), reflected specularly off the
     glass with probability ``sensor_reflectivity``, absorbed otherwise (u < p_det:
     detected; p_det <= u < p_det + R: reflected);
   - wall: reflected with probability ``wall_reflectivity`` (specular with probability
     ``wall_specular_fraction``, else Lambertian about the inward normal), absorbed
     otherwise; in an open medium the world boundary is not a wall: the photon escapes.

   Scatterings and reflections are interaction vertices. A photon that already had
   ``config.n_bounces`` vertices and would scatter or reflect again is counted as
   ``capped`` (lost), so every photon ends within n_bounces + 1 steps.

Photons run in batches of ``config.batch_size`` inside one jitted ``lax.while_loop``
(compiled once per detector size, source type and config; the batch key is
``fold_in(key, batch_index)``) and are tallied on the host, so memory stays bounded
for any number of photons. Lengths in m, times in ns.
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
from ..geometry.detector import Detector
from ..geometry.sensor_grid import SensorGrid, build_sensor_grid, first_sensor_hit
from ..io.events import Event, Truth
from ..params import Params, validate_params
from ..response import DEFAULT_CONFIG, photoelectrons_to_event
from ..sources import DiffuserSource, IsotropicSource, LaserSource, check_source
from .emission import sample_directions
from .optics import (
    SPEED_OF_LIGHT,
    TransportConfig,
    acceptance_at_cos,
    deflect,
    dome_normal,
    interaction_rates,
    lambertian_direction,
    sample_henyey_greenstein_cos,
    sample_rayleigh_cos,
    specular_direction,
)

#: Photon fates (status codes of the transport loop).
ALIVE, DETECTED, ABSORBED_BULK, ABSORBED_WALL, ABSORBED_SENSOR, ESCAPED, CAPPED, UNUSED = range(8)
N_STATUS = 8
#: Distance (m) a reflected photon is moved along its new direction, off the surface.
NUDGE = 5e-6
#: Smallest batch used for small photon counts (batches are powers of two up to
#: ``config.batch_size``, so few sizes are ever compiled).
MIN_BATCH = 1 << 10
#: After the first step the survivors are followed in chunks this many times smaller
#: than the batch (most photons end on their first segment).
COMPACTION = 8
#: Uniform random numbers drawn per photon per step.
_N_UNIFORMS = 5


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


def _bulk_outcome(u_process, u_cos, u_phi, direction, rates, params, anisotropy):
    """Absorbed-or-not and the scattered direction of a bulk interaction."""
    absorption, rayleigh, _, total = rates
    pick = u_process * total
    absorbed = pick < absorption
    is_rayleigh = pick < absorption + rayleigh
    cos_theta = jnp.where(
        is_rayleigh,
        sample_rayleigh_cos(u_cos, anisotropy),
        sample_henyey_greenstein_cos(u_cos, params.mie_g),
    )
    return absorbed, deflect(direction, cos_theta, 2.0 * math.pi * u_phi)


def _sensor_outcome(u, direction, point, sensor, sensors, params):
    """(detected, reflected, new direction) of photons crossing sensor discs at ``point``;
    reflection is specular off the glass dome over the disc (``optics.dome_normal``)."""
    positions, normals, radius = sensors
    normal = normals[sensor]
    cos_incidence = jnp.clip(-jnp.sum(direction * normal, axis=-1), -1.0, 1.0)
    acceptance = acceptance_at_cos(params.angular_acceptance, cos_incidence)
    p_detect = params.quantum_efficiency * params.efficiency[sensor] * acceptance
    detected = u < p_detect
    reflected = ~detected & (u < p_detect + params.sensor_reflectivity)
    dome = dome_normal(point - positions[sensor], normal, radius[sensor])
    return detected, reflected, specular_direction(direction, dome)


def _wall_outcome(u_reflect, u_kind, u1, u2, direction, points, shape, params):
    """(reflected, new direction) of photons reaching the wall at ``points``."""
    normal = shape.inward_normal(points)
    reflected = u_reflect < params.wall_reflectivity
    specular = u_kind < params.wall_specular_fraction
    diffuse = lambertian_direction(normal, u1, u2)
    return reflected, jnp.where(specular[:, None], specular_direction(direction, normal), diffuse)


def _step_function(shape, config, sensors, grid, params, key):
    """The body of the transport ``while_loop`` for one batch (closure over constants)."""
    positions, normals, radius = sensors
    rates = interaction_rates(params)
    total = rates[3]
    has_walls = bool(shape.has_walls)

    def step(state):
        index, position, direction, path, vertices, status, sensor = state
        dtype = position.dtype
        alive = status == ALIVE
        u = jax.random.uniform(jax.random.fold_in(key, index), (_N_UNIFORMS,) + path.shape, dtype)

        t_wall = jnp.maximum(shape.ray_exit(position, direction), 0.0)
        hit, t_hit = first_sensor_hit(grid, positions, normals, radius, position, direction, t_wall)
        on_sensor = hit >= 0
        t_surface = jnp.where(on_sensor, t_hit, t_wall)
        free_path = -jnp.log1p(-u[0]) / jnp.where(total > 0, total, 1.0)
        s = jnp.where(total > 0, free_path, jnp.inf)

        bulk = s < t_surface
        distance = jnp.where(bulk, s, t_surface)
        point = position + distance[:, None] * direction
        path = jnp.where(alive, path + distance, path)
        bulk_sensor = jnp.where(on_sensor, hit, 0)

        absorbed_bulk, scattered_dir = _bulk_outcome(
            u[1], u[2], u[3], direction, rates, params, config.rayleigh_anisotropy
        )
        detected, sensor_reflected, sensor_dir = _sensor_outcome(
            u[1], direction, point, bulk_sensor, sensors, params
        )
        wall_reflected, wall_dir = _wall_outcome(
            u[1], u[2], u[3], u[4], direction, point, shape, params
        )

        at_sensor = ~bulk & on_sensor
        at_wall = ~bulk & ~on_sensor
        if not has_walls:  # the world boundary of an open medium: nothing comes back
            wall_reflected = jnp.zeros_like(at_wall)
        escapes = at_wall if not has_walls else jnp.zeros_like(at_wall)
        scatters = bulk & ~absorbed_bulk
        reflects = (at_sensor & sensor_reflected) | (at_wall & wall_reflected)
        vertex = scatters | reflects
        capped = vertex & (vertices >= config.n_bounces)

        outcome = jnp.select(
            [
                bulk & absorbed_bulk,
                at_sensor & detected,
                at_sensor & ~sensor_reflected,
                escapes,
                at_wall & ~wall_reflected,
                capped,
            ],
            [ABSORBED_BULK, DETECTED, ABSORBED_SENSOR, ESCAPED, ABSORBED_WALL, CAPPED],
            ALIVE,
        )
        new_status = jnp.where(alive, outcome, status)
        continues = alive & (new_status == ALIVE)
        new_dir = jnp.where(
            bulk[:, None], scattered_dir, jnp.where(at_sensor[:, None], sensor_dir, wall_dir)
        )
        new_dir = new_dir / jnp.linalg.norm(new_dir, axis=-1, keepdims=True)
        new_point = point + jnp.where(reflects, NUDGE, 0.0)[:, None] * new_dir
        return (
            index + 1,
            jnp.where(continues[:, None], new_point, position),
            jnp.where(continues[:, None], new_dir, direction),
            path,
            vertices + continues.astype(vertices.dtype),
            new_status,
            jnp.where(alive & (new_status == DETECTED), hit, sensor),
        )

    return step


@functools.partial(jax.jit, static_argnames=("shape", "config", "batch"))
def _transport_batch(
    key, batch_index, n_active, sensors, grid, params, source, *, shape, config, batch
):
    """Transport one batch; returns (status (B,), sensor (B,), arrival time (B,) ns)."""
    dtype = params.absorption_length.dtype
    batch_key = jax.random.fold_in(key, batch_index)
    emit_key, jitter_key, loop_key = jax.random.split(batch_key, 3)
    u = jax.random.uniform(emit_key, (2, batch), dtype)
    direction = sample_directions(source, u[0], u[1])
    emit_time = source.time + source.pulse_width * jax.random.normal(jitter_key, (batch,), dtype)
    position = jnp.broadcast_to(source.position, (batch, 3))
    status = jnp.where(jnp.arange(batch) < n_active, ALIVE, UNUSED).astype(jnp.int32)
    state = (
        jnp.zeros((), jnp.int32),
        position,
        direction,
        jnp.zeros(batch, dtype),
        jnp.zeros(batch, jnp.int32),
        status,
        jnp.full(batch, -1, jnp.int32),
    )

    def running(state):
        return jnp.any(state[5] == ALIVE) & (state[0] <= config.n_bounces)

    def follow(state, key):
        step = _step_function(shape, config, sensors, grid, params, key)
        return jax.lax.while_loop(running, step, state)

    step = _step_function(shape, config, sensors, grid, params, loop_key)

    # Most photons end on their first segment (absorbed, detected or at the wall):
    # follow the survivors of step 0 in chunks of batch / COMPACTION lanes, so that the
    # later steps do not spend their time on finished photons.
    state = step(state)
    if config.n_bounces > 0:
        state = _follow_survivors(state, follow, loop_key, batch)
    _, _, _, path, _, status, sensor = state
    return status, sensor, emit_time + path * params.group_index / SPEED_OF_LIGHT


def _follow_survivors(state, follow, key, batch: int):
    """Run ``follow`` (the transport loop) on the ALIVE lanes of ``state``, gathered into
    chunks of ``batch // COMPACTION`` lanes, and scatter the results back. Each chunk
    draws its random numbers from its own key (``fold_in(key, chunk + 1)``), so no two
    photons share a random stream."""
    chunk = max(batch // COMPACTION, 1)
    survivors = jnp.nonzero(state[5] == ALIVE, size=batch, fill_value=batch)[0]
    n_chunks = (jnp.sum(state[5] == ALIVE) + chunk - 1) // chunk
    fill = (0.0, 0.0, 0.0, 0, UNUSED, -1)

    def one_chunk(carry):
        done, state = carry
        lanes = jax.lax.dynamic_slice(survivors, (done * chunk,), (chunk,))
        sub = (state[0],) + tuple(
            jnp.take(x, lanes, axis=0, mode="fill", fill_value=v)
            for x, v in zip(state[1:], fill, strict=True)
        )
        sub = follow(sub, jax.random.fold_in(key, done + 1))
        merged = tuple(
            x.at[lanes].set(y, mode="drop") for x, y in zip(state[1:], sub[1:], strict=True)
        )
        return done + 1, (state[0],) + merged

    _, state = jax.lax.while_loop(lambda c: c[0] < n_chunks, one_chunk, (jnp.int32(0), state))
    return state


def as_key(key_or_seed):
    """A JAX PRNG key from a key (returned as is) or a non-negative integer seed."""
    if isinstance(key_or_seed, numbers.Integral) and not isinstance(key_or_seed, bool):
        if not 0 <= int(key_or_seed) < 2**63:
            raise ConfigError(f"seed = {int(key_or_seed)}: must be in [0, 2**63)")
        return jax.random.PRNGKey(int(key_or_seed))
    if isinstance(key_or_seed, jax.Array):
        return key_or_seed
    raise ConfigError(f"seed = {format_value(key_or_seed)}: must be an integer or a JAX key")


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
    if detector.shape.has_walls and grid is None:
        grid = build_sensor_grid(detector)
    if not detector.shape.has_walls:
        grid = None

    dtype = jnp.result_type(params.absorption_length)

    def cast(leaf):
        return jnp.asarray(leaf, dtype=dtype) + jnp.zeros((), dtype)  # drops weak typing

    sensors = (
        cast(detector.sensor_positions),
        cast(detector.sensor_normals),
        cast(detector.sensor_radius),
    )
    params_c = jax.tree.map(cast, params)
    source_c = jax.tree.map(cast, source)
    batch = batch_size_for(n_photons, config)
    n_batches = -(-n_photons // batch)

    def launch(index):
        n_active = min(batch, n_photons - index * batch)
        return _transport_batch(
            key,
            jnp.uint32(index),
            jnp.int32(n_active),
            sensors,
            grid,
            params_c,
            source_c,
            shape=detector.shape,
            config=config,
            batch=batch,
        )

    counts = np.zeros(N_STATUS, np.int64)
    hit_sensors, hit_times = [], []
    pending = launch(0)
    for index in range(n_batches):
        current = pending
        if index + 1 < n_batches:
            pending = launch(index + 1)  # dispatched before the host work on ``current``
        status, sensor, time = (np.asarray(a) for a in current)
        counts += np.bincount(status, minlength=N_STATUS)
        detected = status == DETECTED
        hit_sensors.append(sensor[detected])
        hit_times.append(time[detected].astype(np.float64))
    photon_sensor = np.concatenate(hit_sensors).astype(np.int32)
    return PhotonTally(
        n_pe=np.bincount(photon_sensor, minlength=detector.n_sensors).astype(np.int64),
        photon_sensor=photon_sensor,
        photon_time=np.concatenate(hit_times),
        source_time=float(np.asarray(source.time)),
        emitted=n_photons,
        detected=int(counts[DETECTED]),
        absorbed_bulk=int(counts[ABSORBED_BULK]),
        absorbed_wall=int(counts[ABSORBED_WALL]),
        absorbed_sensor=int(counts[ABSORBED_SENSOR]),
        escaped=int(counts[ESCAPED]),
        capped=int(counts[CAPPED] + counts[ALIVE]),
    )


_SOURCE_KINDS = {IsotropicSource: "isotropic", LaserSource: "laser", DiffuserSource: "diffuser"}


def source_truth(source, seed: int) -> Truth:
    """The ``Truth`` of a calibration-source event: kind, position (m), direction (unit;
    NaN for the isotropic source), time (ns) and the seed."""
    direction = getattr(source, "direction", None)
    return Truth(
        source_kind=_SOURCE_KINDS.get(type(source), type(source).__name__),
        position=np.asarray(source.position, dtype=np.float64),
        direction=(
            np.full(3, np.nan) if direction is None else np.asarray(direction, dtype=np.float64)
        ),
        time=float(np.asarray(source.time)),
        seed=int(seed),
    )


def _check_seed(seed) -> int:
    if not isinstance(seed, numbers.Integral) or isinstance(seed, bool) or not 0 <= seed < 2**63:
        raise ConfigError(f"seed = {format_value(seed)}: must be an integer in [0, 2**63)")
    return int(seed)


def _event(detector, params, source, seed, index, config, grid) -> Event:
    """Event ``index`` of ``seed``: transport and response keys split from
    ``fold_in(PRNGKey(seed), index)``."""
    transport_key, response_key = jax.random.split(
        jax.random.fold_in(jax.random.PRNGKey(seed), index)
    )
    tally = sample_photons(detector, params, source, transport_key, config=config, grid=grid)
    return photoelectrons_to_event(
        tally, params, response_key, config=config, truth=source_truth(source, seed)
    )


def _prepare(detector, params, source, seed, config):
    """Validate everything once; build the sensor grid of a walled detector."""
    seed = _check_seed(seed)
    check_config(config)
    validate_params(params, detector.n_sensors)
    check_source(source, detector)
    photon_count(source)
    grid = build_sensor_grid(detector) if detector.shape.has_walls else None
    return seed, grid


def sample(
    detector: Detector,
    params: Params,
    source,
    seed: int,
    *,
    config: TransportConfig = DEFAULT_CONFIG,
) -> Event:
    """One Monte Carlo event (pseudo-data) of a calibration source.

    Photon transport (``sample_photons``) followed by the sensor response
    (``photoelectrons_to_event``: transit-time spread, single-p.e. charges, dark noise,
    readout window, threshold). Positions m, times ns, charges p.e. The same seed gives
    the same event; ``sample(..., seed)`` equals the first event of
    ``sample_events(..., seed, n)``.

    Raises:
        ConfigError: source outside the detector, n_photons < 1 after rounding, NaN or
            out-of-domain parameters, bad config or seed (one line).
    """
    seed, grid = _prepare(detector, params, source, seed, config)
    return _event(detector, params, source, seed, 0, config, grid)


def sample_events(
    detector: Detector,
    params: Params,
    source,
    seed: int,
    n_events: int,
    *,
    config: TransportConfig = DEFAULT_CONFIG,
    progress: bool = False,
):
    """Yield ``n_events`` independent Monte Carlo events of the same source.

    Event i uses the key ``fold_in(PRNGKey(seed), i)``, so the same seed gives the same
    events in the same order. ``progress=True`` shows a rich progress bar. Input is
    validated before the first event (``ConfigError``, one line).
    """
    if not isinstance(n_events, numbers.Integral) or isinstance(n_events, bool) or n_events < 0:
        raise ConfigError(f"n_events = {format_value(n_events)}: must be an integer >= 0")
    seed, grid = _prepare(detector, params, source, seed, config)
    if not progress:
        for index in range(int(n_events)):
            yield _event(detector, params, source, seed, index, config, grid)
        return
    from rich.progress import Progress

    with Progress(transient=True) as bar:
        task = bar.add_task("sampling events", total=int(n_events))
        for index in range(int(n_events)):
            yield _event(detector, params, source, seed, index, config, grid)
            bar.advance(task)
