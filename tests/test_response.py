"""Sensor response: single-p.e. charges, earliest time, dark noise, window, threshold."""

import numpy as np
import pytest
from scipy.stats import truncnorm

from photonflow.geometry import preset_detector
from photonflow.params import default_params
from photonflow.response import photoelectrons_to_event, single_pe_charges
from photonflow.transport.optics import TransportConfig
from photonflow.transport.sampled import PhotonTally

DETECTOR = preset_detector("TOY_SPHERE")


def quiet_params(**changes):
    """Default parameters without dark noise and without time smearing, plus changes."""
    params = default_params(DETECTOR).replace(dark_rate=0.0, tts=1e-6)
    return params.replace(**changes) if changes else params


def tally_of(sensors, times, source_time=0.0):
    sensors = np.asarray(sensors, dtype=np.int32)
    n_pe = np.bincount(sensors, minlength=DETECTOR.n_sensors)
    return PhotonTally(
        n_pe=n_pe, photon_sensor=sensors, photon_time=np.asarray(times, dtype=np.float64),
        source_time=source_time, emitted=len(sensors), detected=len(sensors), absorbed_bulk=0,
        absorbed_wall=0, absorbed_sensor=0, escaped=0, capped=0,
    )


def truncated_moments(width):
    dist = truncnorm(-1.0 / width, np.inf, loc=1.0, scale=width)
    return dist.mean(), dist.var()


@pytest.mark.parametrize("width", [0.3, 1.03])
def test_single_pe_charges_follow_the_truncated_gaussian(width):
    charges = single_pe_charges(np.random.default_rng(1), 200_000, width)
    assert charges.min() >= 0
    mean, var = truncated_moments(width)
    assert abs(charges.mean() - mean) < 5 * np.sqrt(var / charges.size)
    assert abs(charges.var() / var - 1) < 0.02


def test_charge_of_n_pe_is_a_sum_of_n_truncated_gaussians():
    n, width, trials = 7, 0.6, 3000
    params = quiet_params(spe_width=width)
    tally = tally_of(np.full(n, 5), np.linspace(10.0, 20.0, n))
    charges = np.array([
        photoelectrons_to_event(tally, params, seed).charge[0] for seed in range(trials)
    ])
    mean, var = truncated_moments(width)
    assert abs(charges.mean() - n * mean) < 5 * np.sqrt(n * var / trials)
    assert abs(charges.var() / (n * var) - 1) < 5 * np.sqrt(2 / trials)


def test_time_is_the_earliest_photon_with_offset():
    params = quiet_params(time_offset=np.zeros(DETECTOR.n_sensors, np.float32).copy())
    offsets = np.zeros(DETECTOR.n_sensors, np.float32)
    offsets[3] = 5.0
    params = params.replace(time_offset=offsets)
    tally = tally_of([3, 3, 3, 8, 8], [40.0, 12.0, 30.0, 7.0, 9.0])
    event = photoelectrons_to_event(tally, params, 0)
    np.testing.assert_array_equal(event.sensor_ids, [3, 8])
    np.testing.assert_allclose(event.time, [17.0, 7.0], atol=1e-3)
    assert event.charge[0] > 0 and event.charge[1] > 0


def test_dark_hits_are_poisson_with_mean_rate_times_window():
    rate, window = 2.0e5, (-100.0, 900.0)  # 0.2 p.e. per sensor per window
    params = quiet_params(dark_rate=rate, spe_width=0.3)
    config = TransportConfig(window=window)
    mu = rate * (window[1] - window[0]) * 1e-9
    empty = tally_of([], [])
    events = [photoelectrons_to_event(empty, params, seed, config=config) for seed in range(200)]
    n_sensors = DETECTOR.n_sensors * len(events)
    hit_fraction = sum(e.n_hits for e in events) / n_sensors
    p = 1 - np.exp(-mu)
    assert abs(hit_fraction - p) < 5 * np.sqrt(p * (1 - p) / n_sensors)
    mean_charge = sum(float(e.charge.sum()) for e in events) / n_sensors
    q_mean, q_var = truncated_moments(0.3)
    assert abs(mean_charge - mu * q_mean) < 5 * np.sqrt(mu * (q_var + q_mean**2) / n_sensors)
    times = np.concatenate([e.time for e in events])
    assert times.min() >= window[0] and times.max() < window[1]
    # earliest of k ~ Poisson(mu) (k >= 1) uniform times: mean start + T / (k + 1)
    k = np.arange(1, 30)
    weights = mu**k / np.cumprod(k) * np.exp(-mu) / p
    expected = window[0] + (window[1] - window[0]) * np.sum(weights / (k + 1))
    assert abs(times.mean() - expected) < 5 * 1000 / np.sqrt(12 * times.size)


def test_threshold_removes_low_charge_hits():
    sensors = np.repeat(np.arange(50), np.arange(50) % 4 + 1)
    tally = tally_of(sensors, np.zeros(sensors.size))
    params = quiet_params(spe_width=0.2)
    everything = photoelectrons_to_event(tally, params, 3)
    cut = photoelectrons_to_event(tally, params, 3, config=TransportConfig(charge_threshold=2.5))
    assert everything.n_hits == 50
    assert 0 < cut.n_hits < 50
    assert cut.charge.min() >= 2.5
    kept = np.isin(everything.sensor_ids, cut.sensor_ids)
    np.testing.assert_array_equal(everything.sensor_ids[kept], cut.sensor_ids)
    assert everything.charge[~kept].max() < 2.5


def test_events_are_sorted_and_in_window():
    rng = np.random.default_rng(5)
    sensors = rng.integers(0, DETECTOR.n_sensors, 2000)
    times = rng.uniform(-300.0, 1500.0, 2000)
    params = default_params(DETECTOR).replace(dark_rate=1e5)
    config = TransportConfig(window=(-50.0, 400.0))
    event = photoelectrons_to_event(tally_of(sensors, times, source_time=10.0), params, 1,
                                    config=config)
    assert event.n_hits > 100
    assert np.all(np.diff(event.sensor_ids) > 0)
    assert event.time.min() >= -40.0 and event.time.max() < 410.0


def test_same_key_same_event():
    tally = tally_of(np.arange(20), np.arange(20.0))
    params = default_params(DETECTOR)
    a = photoelectrons_to_event(tally, params, 11)
    b = photoelectrons_to_event(tally, params, 11)
    c = photoelectrons_to_event(tally, params, 12)
    np.testing.assert_array_equal(a.charge, b.charge)
    np.testing.assert_array_equal(a.time, b.time)
    assert not np.array_equal(a.charge, c.charge)
