"""Expected mode for particle tracks: the light of a ``Track`` at every sensor, then the
sensor response.

The track's energy selects its emission model (``photonflow.emission``: the shipped
spline model of its particle in the detector's medium); the direct light comes by
quadrature in the angle to the track (``track_direct``), the indirect light (scattered
and reflected, by bounce order) from the weighted rays of ``indirect.py`` leaving the
track (``track_rays.TrackEmitter``: their geometry fixed by a reference track, so the
indirect light is smooth in the track). The light is a mixture of C + 2 n_bounces
arrival-time components per sensor: C for the direct light
(``track_direct.DIRECT_COMPONENTS``, each moment-matched to the light of a stretch of
the track), then per kind of last vertex (bulk scatter, surface) one per bounce order,
exponentially modified (``_skewed_indirect``: scattered light starts no earlier than
direct light can arrive, and trails off); in a scintillator, its isotropic scintillation
light (``emission.ScintillationModel``) through the same quadrature and rays, each of its
components split into one exponentially modified component per decay time. The sensor
response (``response.expected_response``) then applies efficiencies, offsets and the
transit-time spread. Lengths m, times ns, energies MeV.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..constants import SPEED_OF_LIGHT
from ..emission import SplineEmission
from ..emission.moments import TabulatedSlice
from ..geometry.sensor_arrays import Sensors
from ..inline_jit import inline_jit
from ..numerics import safe_sqrt, where
from ..prediction import Prediction
from ..response.expected import SensorLight, expected_response
from .indirect import indirect_light_jit
from .track_direct import DIRECT_COMPONENTS, LIGHT_FLOOR, mixed_moments, track_direct_light
from .track_moments import tabulated_direct_light
from .track_rays import TrackEmitter, kernel_width


def track_sensor_light(sensors: Sensors, params, track, model: SplineEmission, spectral,
                       key=None, reference=None, scintillation=None, *, shape, config):
    """The ``SensorLight`` of one track (a ``Track`` of one particle, leaves of the
    computation's dtype): (N, C + 2 n_bounces) p.e. of sensors of efficiency 1 (C direct
    components, ``track_direct.DIRECT_COMPONENTS``, then by the kind of the last vertex
    (bulk scatter, surface) and its order, the indirect ones with exponential tails:
    ``_skewed_indirect``), with mean arrival times, variances and decay times (ns, ns^2,
    ns). ``spectral``: the sensor's mean relative spectral response over the emitted
    spectrum (``cherenkov_spectral_factor``), which scales the QE at the reference wavelength;
    ``key`` fixes the rays (None: ``jax.random.key(0)``); ``shape`` and ``config``
    static; ``reference``: the track that fixes the indirect light's rays
    (``track_rays``; None: the track itself, held fixed). ``scintillation``: None, or
    (the medium's ``ScintillationModel``, its ``scintillation_spectral_factor``): the
    isotropic scintillation light is added as ``SCINTILLATION_COMPONENTS`` x (number of
    decay times) exponentially modified components (``time_tau``). Traced inline."""
    key = jax.random.key(0) if key is None else key
    rays_from = jax.tree.map(jax.lax.stop_gradient, track if reference is None else reference)
    direction = track.direction / jnp.linalg.norm(track.direction)
    length = _inside_length(shape, track.position, direction)
    emission = model.at(track.energy)
    rays_emission = emission if reference is None else model.at(rays_from.energy)
    charges, means, variances, residual, start = _emitted_light(
        sensors, params.replace(quantum_efficiency=params.quantum_efficiency * spectral),
        track, direction, length, emission, rays_emission, rays_from, key,
        shape=shape, config=config)
    onset = earliest_arrival(sensors, params, track.position, direction, track.time, length)
    charges, means, variances, tau = _skewed_indirect(charges, means, variances, onset)
    if scintillation is not None:
        scintillator, factor = scintillation
        light = scintillator.at(track.energy)
        rays_light = light if reference is None else scintillator.at(rays_from.energy)
        parts = _emitted_light(
            sensors, params.replace(quantum_efficiency=params.quantum_efficiency * factor),
            track, direction, length, light, rays_light, rays_from,
            jax.random.fold_in(key, 1), shape=shape, config=config)
        delayed = _decayed(*parts[:3], scintillator.decay_times, scintillator.decay_weights)
        tau = jnp.concatenate([tau, delayed[3]], axis=1)
        charges, means, variances = (jnp.concatenate([a, b], axis=1) for a, b in
                                     zip((charges, means, variances), delayed[:3],
                                         strict=True))
        residual = residual + parts[3]
    has_light = charges > LIGHT_FLOOR
    return SensorLight(
        charge=charges,
        time_mean=where(has_light, means, start[:, None]),
        time_variance=where(has_light, variances, 0.0),
        residual_weight=residual,
        window=tuple(float(x) for x in config.window),
        time_tau=tau,
    )


#: Indirect components whose exponential delay would be below this (ns) stay Gaussian.
SHORTEST_TAIL = 0.1


def earliest_arrival(sensors: Sensors, params, position, direction, time, length):
    """(N,) the earliest time (ns) any light of the track can reach each sensor centre:
    min over the track's points s in [0, length] (m) of t0 + s / c + n_g |p - x(s)| / c,
    reached where the sensor is seen at cos = 1 / n_g from the track (light made later
    along the track, delayed at emission, or bent by a scatter or a reflection only
    comes later)."""
    offset = sensors.positions - position
    along = offset @ direction
    across = safe_sqrt(jnp.sum(offset * offset, axis=1) - along * along)
    n_g = params.group_index
    s = jnp.clip(along - across / safe_sqrt(n_g * n_g - 1.0), 0.0, length)
    return time + (s + n_g * safe_sqrt((along - s) ** 2 + across * across)) / SPEED_OF_LIGHT


def _skewed_indirect(charge, mean, variance, onset):
    """The indirect components (after the ``DIRECT_COMPONENTS``) as exponentially
    modified Gaussians with the skewness of a gamma distribution that starts at
    ``onset`` (N,) ns (``earliest_arrival``): scattered and reflected light cannot
    arrive before it, and a symmetric shape puts a share of the light there.

    A component of mean m and spread s, with d = m - onset, is the gamma distribution of
    that mean and variance starting at the onset (shape k = d^2 / s^2, skewness 2 s / d)
    matched in its first three moments: exponential delay tau = s (s / d)^(1/3),
    Gaussian variance s^2 - tau^2 and mean m - tau. A spread wider than d (k < 1, a
    shape falling from the onset) is an exponential from the onset, tau = d. Before the
    transit-time spread. Returns (charge, mean, variance, tau) (N, K)."""
    indirect = slice(DIRECT_COMPONENTS, None)
    spread = safe_sqrt(variance[:, indirect])
    delay = jnp.maximum(mean[:, indirect] - onset[:, None], SHORTEST_TAIL)
    narrow = spread < delay
    ratio = where(narrow & (spread > 0.0), spread / delay, 1.0)
    tau = where(narrow, spread * jnp.cbrt(ratio), delay)
    tail = tau > SHORTEST_TAIL
    tau = where(tail, tau, 0.0)
    mean = mean.at[:, indirect].add(-tau)
    gaussian = where(narrow, jnp.maximum(variance[:, indirect] - tau * tau, 0.0), 0.0)
    variance = variance.at[:, indirect].set(where(tail, gaussian, variance[:, indirect]))
    return charge, mean, variance, jnp.concatenate([jnp.zeros_like(mean[:, :DIRECT_COMPONENTS]),
                                                    tau], axis=1)


#: Transport components of the scintillation light before its decay delays: the direct
#: light's components merged in pairs, and its indirect light as one.
SCINTILLATION_COMPONENTS = DIRECT_COMPONENTS // 2 + 1


def _emitted_light(sensors, params, track, direction, length, emission, rays_emission,
                   rays_from, key, *, shape, config):
    """(charge, mean, variance) (N, C + 2 n_bounces) of the light of one emission slice
    (direct components, then by kind of last vertex and bounce order), the residual
    weight of its rays and the sensors' mean direct arrival time (N,) ns (the time of
    light from the track's start where there is no direct light)."""
    direct = (tabulated_direct_light if isinstance(emission, TabulatedSlice)
              else track_direct_light)
    charge, mean, variance = direct(sensors, params, track.position, direction, track.time,
                                    emission, length)
    total = jnp.sum(charge, axis=1)
    lit = total > LIGHT_FLOOR
    start = jnp.sum(charge * mean, axis=1) / where(lit, total, 1.0)
    start = where(lit, start, mean[:, 0])
    emitter = TrackEmitter(track.position, direction, track.time, emission, length,
                           rays_from.position,
                           rays_from.direction / jnp.linalg.norm(rays_from.direction),
                           rays_emission, spread=kernel_width(shape))  # held fixed
    indirect = indirect_light_jit(sensors, params, emitter, start, key, shape=shape,
                                  config=config)
    # (N, C + 2 n_bounces): the direct components, then by the kind of the last vertex
    # (bulk scatter, surface) and its order
    by_kind = [x.reshape(-1, x.shape[-1]).T for x in
               (indirect.kind_charge, indirect.kind_time_mean, indirect.kind_time_variance)]
    charges, means, variances = (jnp.concatenate([a, b], axis=1) for a, b in
                                 zip((charge, mean, variance), by_kind, strict=True))
    return charges, means, variances, indirect.residual_weight, start


def _decayed(charge, mean, variance, decay_times, decay_weights):
    """The scintillation light's components (N, C + 2 n_bounces) merged into
    ``SCINTILLATION_COMPONENTS`` (moment-matched), each split into one exponentially
    modified component per decay time: (charge, mean, variance, tau) (N, 3 x ...)."""
    pairs = [mixed_moments(charge[:, k:k + 2], mean[:, k:k + 2], variance[:, k:k + 2], axis=1)
             for k in range(0, DIRECT_COMPONENTS, 2)]
    pairs.append(mixed_moments(charge[:, DIRECT_COMPONENTS:], mean[:, DIRECT_COMPONENTS:],
                        variance[:, DIRECT_COMPONENTS:], axis=1))
    merged = [jnp.stack(x, axis=1) for x in zip(*pairs, strict=True)]  # 3 x (N, S)
    lit = merged[0] > LIGHT_FLOOR
    merged[1] = where(lit, merged[1], mean[:, :1])
    outputs = [[], [], [], []]
    for tau, weight in zip(decay_times, decay_weights, strict=True):
        outputs[0].append(weight * merged[0])
        outputs[1].append(merged[1])
        outputs[2].append(merged[2])
        outputs[3].append(jnp.full_like(merged[0], tau))
    return tuple(jnp.concatenate(x, axis=1) for x in outputs)


def _inside_length(shape, position, direction):
    """Distance (m) from the track's start to the wall along its direction (a large
    number in an open medium)."""
    if not shape.has_walls:
        return jnp.asarray(1e9, position.dtype)
    exit_distance = shape.ray_exit(position[None], direction[None])[0]
    return jnp.where(jnp.isfinite(exit_distance), jnp.maximum(exit_distance, 0.0), 1e9)


@inline_jit(static_argnames=("shape", "config"))
def track_expected_jit(sensors: Sensors, params, track, model: SplineEmission, spectral,
                       key=None, reference=None, scintillation=None, *, shape,
                       config) -> Prediction:
    """``expected`` of one track on arrays (``track_sensor_light`` then the sensor
    response); ``shape`` and ``config`` static. Returns a ``Prediction``."""
    light = track_sensor_light(sensors, params, track, model, spectral, key, reference,
                               scintillation, shape=shape, config=config)
    return expected_response(light, params)
