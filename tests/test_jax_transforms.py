"""The public functions that take ``Params`` work as JAX users write them: under
``jax.jit``, ``jax.grad`` and ``jax.vmap``, with the detector prepared once, and a second
call with new values does not compile again (issue 22). The gradient with respect to a
source's position under ``jit`` is test_robustness.py's."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import photonflow as pf
from photonflow.transport.expected import expected_jit

pytestmark = pytest.mark.compile_bound

CONFIG = pf.TransportConfig(n_rays=64)


@pytest.fixture(scope="module")
def toy():
    detector = pf.load_detector("TOY_CYLINDER")
    params = pf.default_params(detector)
    source = pf.IsotropicSource(position=[0.3, 0.0, 0.5], n_photons=1e5)
    event = pf.sample(detector, params, source, seed=5, config=CONFIG)
    return detector, params, source, event


def _compilations(function) -> int:
    return function._cache_size()


def test_expected_under_jit_equals_the_eager_call_and_compiles_once(toy):
    detector, params, source, _ = toy
    predict = jax.jit(lambda p: pf.expected(detector, p, source, config=CONFIG))
    eager = pf.expected(detector, params, source, config=CONFIG)
    np.testing.assert_allclose(predict(params).charge, eager.charge, rtol=2e-5)
    changed = predict(params.replace(absorption_length=40.0)).charge
    assert _compilations(predict) == 1
    assert float(changed.sum()) < float(eager.charge.sum())  # shorter absorption, less light


def test_eager_expected_reuses_its_compiled_program(toy):
    """Calling ``expected`` again with other values (parameters, source position,
    photons) neither prepares the detector nor compiles again."""
    detector, params, source, _ = toy
    pf.expected(detector, params, source, config=CONFIG)
    before = _compilations(expected_jit)
    moved = pf.IsotropicSource(position=[-0.4, 0.2, -0.3], n_photons=3e5)
    pf.expected(detector, params.replace(scattering_length=50.0), moved, config=CONFIG)
    assert _compilations(expected_jit) == before
    assert pf.expected_function(detector, config=CONFIG) is pf.expected_function(
        detector, config=CONFIG)


def test_grad_of_nll_through_expected_matches_a_finite_difference(toy):
    detector, params, source, event = toy

    def loss(length):
        p = params.replace(absorption_length=length)
        return pf.nll(pf.expected(detector, p, source, config=CONFIG), event)

    gradient = jax.jit(jax.grad(loss))(jnp.float32(25.0))
    step = 0.5
    numeric = (loss(jnp.float32(25.0 + step)) - loss(jnp.float32(25.0 - step))) / (2 * step)
    assert np.isfinite(float(gradient))
    np.testing.assert_allclose(float(gradient), float(numeric), rtol=0.02)


def test_vmap_over_a_batch_of_sources_equals_one_call_each(toy):
    """A batch of sources is a source whose leaves have a leading axis (stack them with
    ``jax.tree.map``); ``vmap`` maps ``expected`` over it."""
    detector, params, source, _ = toy
    other = pf.IsotropicSource(position=[-0.5, 0.4, -1.0], n_photons=2e5)
    batch = jax.tree.map(lambda *leaves: jnp.stack(leaves), source, other)
    charges = jax.vmap(lambda s: pf.expected(detector, params, s, config=CONFIG).charge)(batch)
    for row, single in zip(charges, (source, other), strict=True):
        np.testing.assert_allclose(
            row, pf.expected(detector, params, single, config=CONFIG).charge, rtol=2e-4,
            atol=1e-6)


def test_nll_and_sensor_nll_under_jit_and_vmap(toy):
    detector, params, source, event = toy
    prediction = pf.expected(detector, params, source, config=CONFIG)
    total = jax.jit(lambda pr: pf.nll(pr, event))(prediction)
    np.testing.assert_allclose(float(total), float(pf.nll(prediction, event)), rtol=1e-6)
    scaled = jax.vmap(lambda s: pf.nll(pf.Prediction(
        charge=prediction.charge * s, time_weight=prediction.time_weight,
        time_mean=prediction.time_mean, time_sigma=prediction.time_sigma,
        dark_rate=prediction.dark_rate, spe_width=prediction.spe_width,
        window=prediction.window), event))(jnp.asarray([0.5, 1.0, 2.0]))
    np.testing.assert_allclose(float(scaled[1]), float(total), rtol=1e-6)
    assert float(scaled[0]) != float(scaled[2])


def test_params_transforms_under_jit_and_grad(toy):
    _, params, _, _ = toy
    round_trip = jax.jit(lambda p: pf.Params.from_unconstrained(p.to_unconstrained()))(params)
    np.testing.assert_allclose(round_trip.absorption_length, params.absorption_length,
                               rtol=1e-5)
    slope = jax.grad(lambda u: pf.Params.from_unconstrained(
        params.to_unconstrained().replace(absorption_length=u)).absorption_length)(
        jnp.log(params.absorption_length))
    np.testing.assert_allclose(float(slope), float(params.absorption_length), rtol=1e-5)


def test_concrete_bad_sources_are_refused_like_sample(toy):
    """Outside ``jit`` the expected mode checks its inputs as the sampled mode does."""
    detector, params, _, _ = toy
    for bad, field in (
        (pf.IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=-1e5), "n_photons"),
        (pf.IsotropicSource(position=[10.0, 0.0, 0.0], n_photons=1e5), "position"),
        (pf.IsotropicSource(position=[np.nan, 0.0, 0.0], n_photons=1e5), "position"),
    ):
        for mode in (pf.expected, lambda d, p, s: pf.sample(d, p, s, seed=1)):
            with pytest.raises(pf.ConfigError, match=f"source.{field}"):
                mode(detector, params, bad)
    with pytest.raises(pf.ConfigError, match="params.absorption_length"):
        pf.expected(detector, params.replace(absorption_length=-1.0),
                    pf.IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=1e5))
