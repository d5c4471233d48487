"""The indirect light of a track with its rays held fixed: the likelihood is smooth in
the track (autodiff against finite differences), and the held indirect light
(``held_indirect_function``) is, at the held track, the full prediction with the rays
fixed there, in value and gradient; away from it its error is of second order in the
move. One module, so that the predictor these tests share compiles once."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import photonflow as pf
from photonflow.likelihood import dense_nll, hit_arrays
from photonflow.transport.expected import held_indirect_function

pytestmark = pytest.mark.compile_bound

#: (x, y, z m, t ns, theta, phi rad, log E/MeV): 0.5 m from the toy barrel (radius 2 m)
#: heading along it, and from near the axis towards the top cap's edge.
POINTS = (np.array([1.5, 0.0, -0.5, 0.0, 0.5 * np.pi, 0.5 * np.pi, np.log(600.0)]),
          np.array([0.1, 0.0, 0.0, 1.0, np.arctan2(1.9, 2.0), 0.0, np.log(400.0)]))
#: A move in all seven coordinates (m, ns, rad, log E).
MOVE = np.array([0.02, -0.015, 0.01, 0.3, 0.01, -0.015, 0.03])


def _track_of(x, particle="mu-", numpy=jnp):
    """(x, y, z m, t ns, theta, phi rad, log E/MeV) -> Track."""
    direction = numpy.stack([numpy.sin(x[4]) * numpy.cos(x[5]),
                             numpy.sin(x[4]) * numpy.sin(x[5]), numpy.cos(x[4])])
    return pf.Track(particle, x[:3], direction, numpy.exp(x[6]), x[3])


@pytest.fixture(scope="module")
def toy():
    detector = pf.load_detector("TOY_CYLINDER")
    return detector, pf.default_params(detector)


@pytest.fixture(scope="module")
def events(toy):
    """A muon sampled at each of ``POINTS`` (seed 5)."""
    detector, params = toy
    return [pf.sample(detector, params, _track_of(p, numpy=np), seed=5) for p in POINTS]


def _functions(detector, params):
    """float64 params, and the predictor and the holder of the indirect light (128 rays,
    2 bounces) that every test here shares."""
    params = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), params)
    config = pf.TransportConfig(n_rays=128, n_bounces=2)
    predict = pf.expected_function(detector, jnp.float64, config=config)
    hold = held_indirect_function(detector, jnp.float64, config=config)
    return params, predict, hold


def _nll(prediction, hits):
    """``pf.nll`` on an event's dense (N,) arrays (``hit_arrays``): one program for every
    event."""
    return dense_nll(prediction, *hits, prediction.dark_rate, prediction.spe_width,
                     prediction.window)


def test_autodiff_matches_finite_differences_with_the_indirect_light(toy, events):
    """With the rays' reference track held fixed, the full likelihood (direct + 2 bounces
    of indirect light, charge + first-hit time) of a sampled event is a smooth function
    of the 7 track parameters: autodiff agrees with central differences (float64) within
    1 % of each derivative (or 1e-3 of the largest), at a vertex 0.5 m from the barrel
    and for a direction grazing a cap edge. The default reference (the track itself)
    gives the same value and gradient."""
    detector, params = toy
    with jax.enable_x64(True):
        params, predict, _ = _functions(detector, params)

        def loss(x, reference, hits):
            return _nll(predict(params, _track_of(x), None, reference), hits)

        def own_loss(x, hits):
            return _nll(predict(params, _track_of(x)), hits)

        value_and_grad = jax.jit(jax.value_and_grad(loss))
        steps = [1e-5] * 4 + [1e-6] * 3
        for k, (point, event) in enumerate(zip(POINTS, events, strict=True)):
            event = hit_arrays(event, detector.n_sensors, jnp.float64)
            start = jnp.asarray(point + np.array([0.03, -0.02, 0.02, 0.5, 0.02, -0.03, 0.05]))
            reference = _track_of(start)
            value, gradient = value_and_grad(start, reference, event)
            if k == 0:  # the default reference: the same value and gradient
                own_value, own_gradient = jax.value_and_grad(own_loss)(start, event)
                assert float(own_value) == pytest.approx(float(value), rel=1e-12)
                np.testing.assert_allclose(own_gradient, gradient, rtol=1e-9, atol=1e-9)
            central = np.array([(value_and_grad(start + h * e, reference, event)[0]
                                 - value_and_grad(start - h * e, reference, event)[0]) / (2 * h)
                                for e, h in zip(np.eye(7), steps, strict=True)])
            gradient = np.asarray(gradient)
            assert np.all(np.isfinite(gradient))
            np.testing.assert_allclose(gradient, central, rtol=0.01,
                                       atol=1e-3 * np.max(np.abs(gradient)))


def test_held_light_is_the_full_prediction_at_the_held_track(toy, events):
    """Toy cylinder, float64, at a vertex 0.5 m from the barrel and a direction grazing a
    cap edge: the event likelihood (charge + first-hit time) with the indirect light
    held at the track equals the full one with its rays there (1e-9 relative), and so
    does its gradient in the 7 track parameters (1e-6 of the largest component)."""
    detector, params = toy
    with jax.enable_x64(True):
        params, predict, hold = _functions(detector, params)

        def loss(x, held, hits):
            return _nll(predict(params, _track_of(x), held=held), hits)

        def full_loss(x, hits):  # rays fixed at the track itself
            return _nll(predict(params, _track_of(x)), hits)

        for point, event in zip(POINTS, events, strict=True):
            hits = hit_arrays(event, detector.n_sensors, jnp.float64)
            x = jnp.asarray(point + MOVE)
            held = hold(params, _track_of(x))
            value, gradient = jax.value_and_grad(loss)(x, held, hits)
            full_value, full_gradient = jax.value_and_grad(full_loss)(x, hits)
            assert float(value) == pytest.approx(float(full_value), rel=1e-9)
            gradient, full_gradient = np.asarray(gradient), np.asarray(full_gradient)
            assert np.all(np.isfinite(gradient))
            np.testing.assert_allclose(gradient, full_gradient, rtol=0,
                                       atol=1e-6 * np.max(np.abs(full_gradient)))


def test_held_light_errs_at_second_order_in_the_move(toy):
    """Toy cylinder, float64: held at a track, the prediction at a track moved by 0.1
    ``MOVE`` (2 mm, 0.06 degrees, 0.3 %: within the toy's ray kernel of 1 cm, the scale
    on which the full prediction's ray weights change) differs from the full prediction
    with the rays fixed at the held track by an amount that falls 3.5-4.5x when the
    move halves (second order: 4x), in the sensors' expected charges (the sum of the
    absolute differences) and in their mean arrival times; without the slopes the
    error falls about 2x (first order)."""
    detector, params = toy
    with jax.enable_x64(True):
        params, predict, hold = _functions(detector, params)
        x = jnp.asarray(POINTS[0])
        track = _track_of(x)
        held = hold(params, track)
        flat = hold(params, track, slopes=False)

        def errors(h, held):
            moved = _track_of(x + h * jnp.asarray(MOVE))
            full = predict(params, moved, None, track)
            approx = predict(params, moved, held=held)
            charge = float(jnp.sum(jnp.abs(full.charge - approx.charge)))
            lit = full.charge > 1e-3
            mean_full = jnp.sum(full.time_weight * full.time_mean, axis=1)
            mean_approx = jnp.sum(approx.time_weight * approx.time_mean, axis=1)
            time = float(jnp.sum(jnp.where(lit, jnp.abs(mean_full - mean_approx), 0.0)))
            return np.array([charge, time])

        ratio = errors(0.1, held) / errors(0.05, held)
        assert np.all((ratio > 3.5) & (ratio < 4.5)), ratio
        flat_ratio = errors(0.1, flat)[0] / errors(0.05, flat)[0]
        assert 1.6 < flat_ratio < 2.6, flat_ratio


def test_held_light_carries_scintillation_near_the_wall():
    """TAO (scintillator: Cherenkov and scintillation light, one held part each), a
    1 GeV muon 5 cm inside the sphere heading inward: the held prediction at the held
    track equals the full one (1e-5 relative in float32)."""
    detector = pf.load_detector("TAO")
    params = pf.default_params(detector)
    config = pf.TransportConfig(n_rays=128, n_bounces=1)
    predict = pf.expected_function(detector, config=config)
    hold = held_indirect_function(detector, config=config)
    radius = float(detector.shape.radius)
    x = jnp.asarray([radius - 0.05, 0.0, 0.0, 0.0, 0.5 * np.pi, np.pi, np.log(1000.0)],
                    jnp.float32)
    held = hold(params, _track_of(x), slopes=False)  # the slopes: the toy tests above
    assert len(held) == 2
    full = predict(params, _track_of(x)).charge
    approx = predict(params, _track_of(x), held=held).charge
    np.testing.assert_allclose(approx, full, rtol=1e-5, atol=1e-5 * float(jnp.max(full)))
