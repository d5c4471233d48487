"""Sensor response of the sampled mode, after detection: photoelectrons -> hits.

Which photons become photoelectrons is decided by ``detection.sensor_fate`` (inside
the sampled mode's photon loop, when a photon meets a sensor). Per
photoelectron: the arrival time gets the transit-time spread (Gaussian, sigma
``params.tts`` ns) and the sensor's ``time_offset`` (ns). Per sensor, dark noise adds
Poisson(dark_rate x T x 1e-9) photoelectrons uniform in the readout window of length
T ns (``config.window``, relative to the source time). Only photoelectrons inside the
window count; each carries a single-p.e. charge drawn from a Gaussian of mean 1 and
sigma ``spe_width`` truncated at zero (inverse-CDF truncation, so no charge is
negative and none is discarded). A sensor's hit has the summed charge (p.e.) and the
earliest photoelectron time (ns); hits with charge below ``config.charge_threshold``
are dropped.

This is host code (numpy); its randomness comes from a ``numpy.random.Generator``
seeded from a JAX key or an integer, so the same key gives the same hits.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError, format_value
from ..io.events import Event, Truth, make_event
from ..params import Params

if TYPE_CHECKING:
    from ..transport.optics import TransportConfig
    from ..transport.sampled import PhotonTally


def as_generator(key_or_seed) -> np.random.Generator:
    """A numpy ``Generator`` from a JAX key, a non-negative integer seed or a Generator."""
    if isinstance(key_or_seed, np.random.Generator):
        return key_or_seed
    if isinstance(key_or_seed, jax.Array):
        data = key_or_seed
        if jnp.issubdtype(data.dtype, jax.dtypes.prng_key):
            data = jax.random.key_data(data)
        return np.random.default_rng(np.asarray(data, dtype=np.uint32).ravel())
    if isinstance(key_or_seed, int | np.integer) and not isinstance(key_or_seed, bool):
        if key_or_seed < 0:
            raise ConfigError(f"seed = {int(key_or_seed)}: must be >= 0")
        return np.random.default_rng(int(key_or_seed))
    raise ConfigError(f"seed = {format_value(key_or_seed)}: must be an integer or a JAX key")


def single_pe_charges(rng: np.random.Generator, count: int, spe_width: float) -> np.ndarray:
    """``count`` single-photoelectron charges (p.e.): Normal(1, spe_width) truncated at 0
    (the model of ``photonflow.response.spe``, whose moments the likelihood uses).

    Drawn by inverse CDF restricted to q >= 0: q = 1 + w ndtri(F0 + u (1 - F0)) with
    F0 = Phi(-1 / w), so every draw is used and none is negative.
    """
    from scipy.special import ndtr, ndtri  # here: at import it cost every command 0.3 s

    width = float(spe_width)
    floor = ndtr(-1.0 / width)
    u = rng.random(count)
    return np.maximum(1.0 + width * ndtri(floor + u * (1.0 - floor)), 0.0)


def dark_photoelectrons(
    rng: np.random.Generator, n_sensors: int, dark_rate: float, window: tuple[float, float]
):
    """Dark-noise photoelectrons: (sensor ids, times ns), Poisson(dark_rate (Hz) x T x 1e-9)
    per sensor, uniform in the absolute ``window`` (start, end) ns of length T."""
    start, end = window
    counts = rng.poisson(float(dark_rate) * (end - start) * 1e-9, size=n_sensors)
    sensors = np.repeat(np.arange(n_sensors, dtype=np.int32), counts)
    return sensors, rng.uniform(start, end, size=sensors.size)


def earliest_per_sensor(sensors: np.ndarray, times: np.ndarray, n_sensors: int) -> np.ndarray:
    """(N,) earliest time (ns) per sensor of the given photoelectrons, inf where none."""
    first = np.full(n_sensors, np.inf)
    np.minimum.at(first, sensors, times)
    return first


def photoelectrons_to_event(
    tally: PhotonTally,
    params: Params,
    key_or_seed,
    *,
    config: TransportConfig | None = None,
    truth: Truth | None = None,
) -> Event:
    """Turn the detected photons of a ``PhotonTally`` into an ``Event`` of sensor hits.

    Args:
        tally: detected photons (sensor ids, arrival times ns) from ``sample_photons``.
        params: sensor parameters: ``tts`` (ns), ``time_offset`` (N,) ns, ``spe_width``
            (p.e.), ``dark_rate`` (Hz).
        key_or_seed: JAX key, integer seed or numpy Generator for the response's
            randomness.
        config: readout ``window`` (ns, relative to ``tally.source_time``) and
            ``charge_threshold`` (p.e.); default ``transport.optics.DEFAULT_CONFIG``.
        truth: attached to the event as is.

    Returns:
        An ``Event`` with sensor ids ascending, charge (p.e.) and time of the earliest
        photoelectron (ns), every hit inside the window and at or above the threshold.
    """
    rng = as_generator(key_or_seed)
    n_sensors = tally.n_sensors
    if config is None:  # imported here: transport imports this module
        from ..transport.optics import DEFAULT_CONFIG as config
    window = (tally.source_time + config.window[0], tally.source_time + config.window[1])
    offsets = np.asarray(params.time_offset, dtype=np.float64)
    sensors = np.asarray(tally.photon_sensor, dtype=np.int32)
    times = (
        np.asarray(tally.photon_time, dtype=np.float64)
        + rng.normal(0.0, float(params.tts), size=sensors.size)
        + offsets[sensors]
    )
    dark_sensors, dark_times = dark_photoelectrons(
        rng, n_sensors, float(params.dark_rate), window
    )
    sensors = np.concatenate([sensors, dark_sensors])
    times = np.concatenate([times, dark_times])
    inside = (times >= window[0]) & (times < window[1])
    sensors, times = sensors[inside], times[inside]

    charges = single_pe_charges(rng, sensors.size, float(params.spe_width))
    charge = np.bincount(sensors, weights=charges, minlength=n_sensors)
    first = earliest_per_sensor(sensors, times, n_sensors)
    hit = np.isfinite(first) & (charge >= config.charge_threshold)
    ids = np.flatnonzero(hit)
    return make_event(ids, charge[ids], first[ids], truth)
