"""The inline numerical helpers (photonflow.numerics) against their jnp counterparts:
same values, dtypes, weak types and gradients, and no nested jitted program in the
trace (the reason they exist)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from photonflow.numerics import clip, hypot, where

X = jnp.array([-2.0, -0.5, 0.0, 0.25, 3.0], dtype=jnp.float32)


def _nested_jits(function, *args) -> int:
    return sum(e.primitive.name in ("jit", "pjit") for e in jax.make_jaxpr(function)(*args).eqns)


@pytest.mark.parametrize("case", [
    lambda x: (x > 0, x, 0.0),
    lambda x: (x > 0, 1.0, x),
    lambda x: (True, x, 2.0 * x),
    lambda x: ((x > 0)[:, None], x, jnp.ones((5, 1), x.dtype)),
    lambda x: (jnp.array([1, 0, 2, 0, 3]), x, -x),
    lambda x: (x > 0, jnp.arange(5), 5),
])
def test_where_matches_jnp_where(case):
    ours, theirs = where(*case(X)), jnp.where(*case(X))
    assert ours.dtype == theirs.dtype and ours.shape == theirs.shape
    assert ours.aval.weak_type == theirs.aval.weak_type
    np.testing.assert_array_equal(np.asarray(ours), np.asarray(theirs))


def test_gradients_match_and_the_trace_has_no_nested_program():
    pairs = [
        (lambda x: where(x > 0, x * x, 3.0 * x), lambda x: jnp.where(x > 0, x * x, 3.0 * x)),
        (lambda x: clip(x, -1.0, 1.0), lambda x: jnp.clip(x, -1.0, 1.0)),
        (lambda x: hypot(x, 0.5 * x + 1.0), lambda x: jnp.hypot(x, 0.5 * x + 1.0)),
    ]
    for ours, theirs in pairs:
        np.testing.assert_allclose(ours(X), theirs(X), rtol=1e-6)
        ours_grad = jax.grad(lambda x, f=ours: f(x).sum())(X)
        theirs_grad = jax.grad(lambda x, f=theirs: f(x).sum())(X)
        np.testing.assert_allclose(ours_grad, theirs_grad, rtol=1e-6)
        assert _nested_jits(ours, X) == 0
        assert _nested_jits(theirs, X) >= 1  # what the helper avoids


def test_hypot_edges():
    x = jnp.array([0.0, 3.0, 1e-20, 1e20, jnp.inf, 2.0], dtype=jnp.float32)
    y = jnp.array([0.0, 4.0, 1e-20, 1e20, 1.0, -jnp.inf], dtype=jnp.float32)
    np.testing.assert_allclose(hypot(x, y), jnp.hypot(x, y), rtol=1e-6)
    assert np.isfinite(float(jax.grad(lambda a: hypot(a, 0.0))(0.0)))  # on the axis
