"""Expected mode for particle tracks: the light of a ``Track`` at every sensor, then the
sensor response.

The track's energy selects its emission model (``photonflow.emission``: the shipped
spline model of its particle in the detector's medium); the direct light comes by
quadrature in the angle to the track (``track_direct``). The light is one arrival-time
component per sensor (direct light, moment-matched); the sensor response
(``response.expected_response``) then applies efficiencies, offsets and the
transit-time spread as for point sources. Lengths m, times ns, energies MeV.
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
from .track_direct import track_direct_light


def track_sensor_light(sensors: Sensors, params, track, model: SplineEmission, spectral,
                       window):
    """The ``SensorLight`` of one track (a ``Track`` of one particle, leaves of the
    computation's dtype): (N, 1) direct light, p.e. of sensors of efficiency 1, with its
    mean arrival time and variance (ns, ns^2). ``spectral``: the sensor's mean relative
    spectral response over the emitted spectrum (``cherenkov_spectral_factor``), which
    scales the QE at the reference wavelength. Traced inline."""
    emission = model.at(track.energy)
    params = params.replace(quantum_efficiency=params.quantum_efficiency * spectral)
    direction = track.direction / jnp.linalg.norm(track.direction)
    charge, mean, variance = track_direct_light(sensors, params, track.position, direction,
                                                track.time, emission)
    return SensorLight(
        charge=charge[:, None],
        time_mean=mean[:, None],
        time_variance=where(charge > 0, variance, 0.0)[:, None],
        residual_weight=jnp.zeros((), charge.dtype),
        window=window,
    )


@functools.partial(jax.jit, static_argnames=("window",))
def track_expected_jit(sensors: Sensors, params, track, model: SplineEmission, spectral, *,
                       window) -> Prediction:
    """``expected`` of one track on arrays (``track_sensor_light`` then the sensor
    response); ``window`` (t0, t1) ns static. Returns a ``Prediction``."""
    light = track_sensor_light(sensors, params, track, model, spectral, window)
    return expected_response(light, params)
