"""Expected mode for particle tracks: the light of a ``Track`` at every sensor, then the
sensor response.

The track's energy selects its emission model (``photonflow.emission``: the shipped
spline model of its particle in the detector's medium); the direct light comes by
quadrature in the angle to the track (``track_direct``), the indirect light (scattered
and reflected, by bounce order) from the weighted rays of ``indirect.py`` leaving the
track (``track_rays.TrackEmitter``: their geometry fixed by a reference track, so the
indirect light is smooth in the track). The light is a mixture of C + n_bounces arrival-time
components per sensor: C for the direct light (``track_direct.DIRECT_COMPONENTS``, each
moment-matched to a run of the quadrature's nodes), then one per bounce order as for
point sources; the sensor response (``response.expected_response``) then
applies efficiencies, offsets and the transit-time spread. Lengths m, times ns,
energies MeV.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..emission import SplineEmission
from ..geometry.sensor_arrays import Sensors
from ..numerics import where
from ..prediction import Prediction
from ..response.expected import SensorLight, expected_response
from .indirect import indirect_light_jit
from .track_direct import track_direct_light
from .track_rays import TrackEmitter


def track_sensor_light(sensors: Sensors, params, track, model: SplineEmission, spectral,
                       key=None, reference=None, *, shape, config):
    """The ``SensorLight`` of one track (a ``Track`` of one particle, leaves of the
    computation's dtype): (N, C + n_bounces) p.e. of sensors of efficiency 1 (C direct
    components, ``track_direct.DIRECT_COMPONENTS``, then by the order of the last
    vertex), with mean arrival times and variances (ns,
    ns^2). ``spectral``: the sensor's mean relative spectral response over the emitted
    spectrum (``cherenkov_spectral_factor``), which scales the QE at the reference
    wavelength; ``key`` fixes the rays (None: ``jax.random.key(0)``); ``shape`` and
    ``config`` static; ``reference``: the track that fixes the indirect light's rays
    (``track_rays``; None: the track itself, held fixed). Traced inline."""
    key = jax.random.key(0) if key is None else key
    rays_from = jax.tree.map(jax.lax.stop_gradient, track if reference is None else reference)
    emission = model.at(track.energy)
    params = params.replace(quantum_efficiency=params.quantum_efficiency * spectral)
    direction = track.direction / jnp.linalg.norm(track.direction)
    length = _inside_length(shape, track.position, direction)
    charge, mean, variance = track_direct_light(sensors, params, track.position, direction,
                                                track.time, emission, length)
    total = jnp.sum(charge, axis=1)
    reference = jnp.sum(charge * mean, axis=1) / where(total > 0, total, 1.0)
    reference = where(total > 0, reference, mean[:, 0])
    rays_emission = emission if reference is None else model.at(rays_from.energy)
    emitter = TrackEmitter(track.position, direction, track.time, emission, length,
                           rays_from.position,
                           rays_from.direction / jnp.linalg.norm(rays_from.direction),
                           rays_emission)  # held fixed by TrackEmitter
    indirect = indirect_light_jit(sensors, params, emitter, reference, key, shape=shape,
                                  config=config)
    charges = jnp.concatenate([charge, indirect.charge.T], axis=1)  # (N, C + n_bounces)
    means = jnp.concatenate([mean, indirect.time_mean.T], axis=1)
    variances = jnp.concatenate([variance, indirect.time_variance.T], axis=1)
    has_light = charges > 0
    return SensorLight(
        charge=charges,
        time_mean=where(has_light, means, reference[:, None]),
        time_variance=where(has_light, variances, 0.0),
        residual_weight=indirect.residual_weight,
        window=tuple(float(x) for x in config.window),
    )


def _inside_length(shape, position, direction):
    """Distance (m) from the track's start to the wall along its direction (a large
    number in an open medium)."""
    if not shape.has_walls:
        return jnp.asarray(1e9, position.dtype)
    exit_distance = shape.ray_exit(position[None], direction[None])[0]
    return jnp.where(jnp.isfinite(exit_distance), jnp.maximum(exit_distance, 0.0), 1e9)


@functools.partial(jax.jit, static_argnames=("shape", "config"))
def track_expected_jit(sensors: Sensors, params, track, model: SplineEmission, spectral,
                       key=None, reference=None, *, shape, config) -> Prediction:
    """``expected`` of one track on arrays (``track_sensor_light`` then the sensor
    response); ``shape`` and ``config`` static. Returns a ``Prediction``."""
    light = track_sensor_light(sensors, params, track, model, spectral, key, reference,
                               shape=shape, config=config)
    return expected_response(light, params)
