"""The sensor response of the expected mode: applied once, after a transport that does
not depend on it (issue 23: the transport returns light before the response)."""

from __future__ import annotations

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import photonflow as pf
from photonflow.geometry.sensor_arrays import sensors_for
from photonflow.response.expected import SensorLight, expected_response
from photonflow.transport.expected import sensor_light
from photonflow.transport.optics import TransportConfig

pytestmark = pytest.mark.compile_bound

RESPONSE_FIELDS = ("efficiency", "time_offset", "tts", "dark_rate", "spe_width")


def test_expected_response_on_hand_made_light():
    """Charge x efficiency, means + offset, widths sqrt(variance + tts^2), weights the
    components' shares; a sensor without light gets all weight on component 0."""
    light = SensorLight(
        charge=jnp.array([[3.0, 1.0], [0.0, 0.0]]),
        time_mean=jnp.array([[10.0, 14.0], [20.0, 20.0]]),
        time_variance=jnp.array([[0.25, 4.0], [0.25, 0.25]]),
        residual_weight=jnp.array(0.5),
        window=(-10.0, 90.0),
    )
    params = SimpleNamespace(  # the response fields of a two-sensor detector
        efficiency=jnp.array([0.5, 2.0]), time_offset=jnp.array([1.0, -3.0]), tts=1.5,
        dark_rate=jnp.array(1e3), spe_width=jnp.array(0.3),
    )
    prediction = expected_response(light, params)
    np.testing.assert_allclose(prediction.charge, [2.0, 0.0])
    np.testing.assert_allclose(prediction.time_weight, [[0.75, 0.25], [1.0, 0.0]])
    np.testing.assert_allclose(prediction.time_mean, [[11.0, 15.0], [17.0, 17.0]])
    np.testing.assert_allclose(
        prediction.time_sigma, np.sqrt([[0.25 + 2.25, 6.25], [2.5, 2.5]]), rtol=1e-6
    )
    assert prediction.window == (-10.0, 90.0)
    assert float(prediction.residual_weight) == 0.5


def test_transport_does_not_depend_on_the_response_fields():
    """The derivatives of every output of the transport with respect to efficiency, time
    offset, tts, dark rate and single-p.e. width are exactly zero, while those with
    respect to the optics are not: the response is applied after the transport only."""
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    source = pf.IsotropicSource(position=[0.3, -0.2, 0.5], n_photons=1e5, pulse_width=0.5)
    config = TransportConfig(n_rays=64)
    sensors = sensors_for(detector)
    weights = jnp.asarray(np.random.default_rng(3).random((detector.n_sensors, 3)))

    @jax.jit
    @jax.grad
    def gradient(p):
        light = sensor_light(sensors, p, source, jax.random.key(1),
                             shape=detector.shape, config=config)
        return jnp.sum(weights * (light.charge + light.time_mean + light.time_variance))

    grad = gradient(params)
    for name in RESPONSE_FIELDS:
        assert np.all(np.asarray(getattr(grad, name)) == 0.0), name
    assert float(grad.absorption_length) != 0.0
    assert float(grad.wall_reflectivity) != 0.0


def test_expected_mode_applies_the_response_once():
    """``expected`` at efficiencies e, offsets o and tts t against the same source at
    efficiency 1, offset 0 and tts t0: charges scale by e, means shift by o, variances by
    t^2 - t0^2, and the mixture weights are unchanged."""
    detector = pf.load_detector("TOY_CYLINDER")
    rng = np.random.default_rng(1)
    plain = pf.default_params(detector).replace(tts=0.4)
    changed = plain.replace(
        efficiency=rng.uniform(0.5, 1.5, detector.n_sensors),
        time_offset=rng.normal(0.0, 3.0, detector.n_sensors),
        tts=1.7,
    )
    source = pf.IsotropicSource(position=[0.0, 0.0, 1.0], n_photons=1e5, pulse_width=0.5)
    before = pf.expected(detector, plain, source)
    after = pf.expected(detector, changed, source)
    np.testing.assert_allclose(after.charge, before.charge * changed.efficiency, rtol=1e-6)
    np.testing.assert_allclose(after.time_weight, before.time_weight, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(
        after.time_mean, before.time_mean + changed.time_offset[:, None], atol=1e-4
    )
    np.testing.assert_allclose(
        after.time_sigma**2, before.time_sigma**2 + 1.7**2 - 0.4**2, rtol=1e-5
    )
