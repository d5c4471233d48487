"""``inline_jit``: a compiled program of its own when called from Python (or under an
eager ``grad``), no nested program inside another function's ``jit``; the same values
and gradients either way."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from photonflow.inline_jit import inline_jit
from photonflow.transport.expected import expected_jit


@inline_jit(static_argnames=("power",))
def _scaled_power(x, scale, *, power):
    return scale * jnp.sin(x) ** power


def _nested_jits(function, *args) -> int:
    """Nested jitted programs in the trace of ``function`` (a trace is what a ``jit``
    around it would see)."""
    return sum(e.primitive.name in ("jit", "pjit") for e in jax.make_jaxpr(function)(*args).eqns)


def test_inlined_inside_a_jit_and_compiled_from_python():
    x = jnp.linspace(0.1, 1.0, 5)
    outer = jax.jit(lambda x: _scaled_power(x, 2.0, power=3) + 1.0)
    assert _nested_jits(lambda x: _scaled_power(x, 2.0, power=3) + 1.0, x) == 0
    before = _scaled_power._cache_size()
    eager = _scaled_power(x, 2.0, power=3)
    assert _scaled_power._cache_size() == before + 1  # compiled from Python
    np.testing.assert_allclose(outer(x), eager + 1.0, rtol=1e-6)
    reference = 2.0 * np.sin(np.asarray(x, np.float64)) ** 3
    np.testing.assert_allclose(eager, reference, rtol=1e-6)


def test_gradients_are_the_same_inlined_and_nested():
    x = jnp.linspace(0.1, 1.0, 5)
    loss = lambda x: jnp.sum(_scaled_power(x, 2.0, power=3))  # noqa: E731
    eager = jax.grad(loss)(x)  # no jit around: the nested program, differentiated
    inlined = jax.jit(jax.grad(loss))(x)
    analytic = 6.0 * np.sin(np.asarray(x)) ** 2 * np.cos(np.asarray(x))
    np.testing.assert_allclose(eager, analytic, rtol=1e-5)
    np.testing.assert_allclose(inlined, analytic, rtol=1e-5)


def test_the_transport_keeps_jits_attributes():
    """The decorated transport still has the jitted function's API (``lower``, cache)."""
    assert callable(expected_jit.lower) and isinstance(expected_jit._cache_size(), int)
    assert expected_jit.__name__ == "expected_jit" and "Prediction" in expected_jit.__doc__
