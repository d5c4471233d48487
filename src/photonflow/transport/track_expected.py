"""Expected mode for particle tracks: the light of a ``Track`` at every sensor, then the
sensor response.

The track's energy selects its emission model (``photonflow.emission``: the shipped
spline model of its particle in the detector's medium); the direct light comes by
quadrature in the angle to the track (``track_direct``), the indirect light (scattered
and reflected, by bounce order) from the weighted rays of ``indirect.py`` leaving the
track (``track_rays.TrackEmitter``). The light is a mixture of 1 + n_bounces arrival-time
components per sensor as for point sources (component 0 direct, moment-matched to the
quadrature nodes' times); the sensor response (``response.expected_response``) then
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
                       key=None, *, shape, config):
    """The ``SensorLight`` of one track (a ``Track`` of one particle, leaves of the
    computation's dtype): (N, 1 + n_bounces) p.e. of sensors of efficiency 1 (direct,
    then by the order of the last vertex), with mean arrival times and variances (ns,
    ns^2). ``spectral``: the sensor's mean relative spectral response over the emitted
    spectrum (``cherenkov_spectral_factor``), which scales the QE at the reference
    wavelength; ``key`` fixes the rays (None: ``jax.random.key(0)``); ``shape`` and
    ``config`` static. Traced inline."""
    key = jax.random.key(0) if key is None else key
    emission = model.at(track.energy)
    params = params.replace(quantum_efficiency=params.quantum_efficiency * spectral)
    direction = track.direction / jnp.linalg.norm(track.direction)
    charge, mean, variance = track_direct_light(sensors, params, track.position, direction,
                                                track.time, emission)
    emitter = TrackEmitter(track.position, direction, track.time, emission)
    indirect = indirect_light_jit(sensors, params, emitter, mean, key, shape=shape,
                                  config=config)
    charges = jnp.concatenate([charge[None], indirect.charge], axis=0).T  # (N, K)
    means = jnp.concatenate([mean[None], indirect.time_mean], axis=0).T
    variances = jnp.concatenate([variance[None], indirect.time_variance], axis=0).T
    has_light = charges > 0
    return SensorLight(
        charge=charges,
        time_mean=where(has_light, means, mean[:, None]),
        time_variance=where(has_light, variances, 0.0),
        residual_weight=indirect.residual_weight,
        window=tuple(float(x) for x in config.window),
    )


@functools.partial(jax.jit, static_argnames=("shape", "config"))
def track_expected_jit(sensors: Sensors, params, track, model: SplineEmission, spectral,
                       key=None, *, shape, config) -> Prediction:
    """``expected`` of one track on arrays (``track_sensor_light`` then the sensor
    response); ``shape`` and ``config`` static. Returns a ``Prediction``."""
    light = track_sensor_light(sensors, params, track, model, spectral, key, shape=shape,
                               config=config)
    return expected_response(light, params)
