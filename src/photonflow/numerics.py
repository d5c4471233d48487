"""Numerical helpers shared by the geometry and the transport (no physics)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def safe_sqrt(x):
    """sqrt(max(x, 0)) with a finite (zero) gradient at and below 0 (units of sqrt(x))."""
    positive = x > 0
    return where(positive, jnp.sqrt(where(positive, x, 1.0)), 0.0)


def smoothstep(x):
    """3 x^2 - 2 x^3 of ``x`` clipped to [0, 1] (dimensionless): a C1 step from 0 to 1."""
    x = jnp.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def default_float_dtype() -> np.dtype:
    """JAX's default float dtype: float32, or float64 when 64-bit mode is on."""
    return np.dtype(jax.dtypes.canonicalize_dtype(np.float64))


def strict_array(value, dtype=None) -> jax.Array:
    """``value`` (unit kept) as a strongly typed JAX array of ``dtype`` (default JAX's
    default float), as jitted programs expect it (a weakly typed argument would compile
    a second program).

    Concrete values are converted on the host and placed with ``jax.device_put``:
    ``jnp.asarray`` of a numpy array or a Python number, and each cast or addition on
    concrete arrays, compiles a small program of its own (tens of milliseconds per shape
    and dtype in every new process). A concrete JAX array that already has the dtype and
    strong typing is returned as it is; a tracer is cast inside its trace.
    """
    dtype = default_float_dtype() if dtype is None else np.dtype(dtype)
    if isinstance(value, jax.Array) and value.dtype == dtype and not value.aval.weak_type:
        return value  # nothing to do: no operation, traced or eager
    if isinstance(value, jax.core.Tracer):
        value = jnp.asarray(value, dtype=dtype)
        return value + jnp.zeros((), dtype) if value.aval.weak_type else value
    return jax.device_put(np.asarray(value, dtype=dtype))


def where(condition, x, y) -> jax.Array:
    """``jnp.where(condition, x, y)`` (same promotion and broadcasting, units of x and y),
    traced inline.

    ``jnp.where`` is a jitted function: every use becomes a nested program in the trace,
    which JAX linearises, transposes and lowers one by one. The transport uses it some
    550 times, so the inline form takes about 0.3 s off a process's first gradient and
    about 1 s off its compilation (XLA's default CPU emitters, toy detector). Written here
    because JAX offers no inline variant of ``where``.
    """
    x, y = jnp.asarray(x), jnp.asarray(y)
    dtype = jnp.result_type(x, y)
    x, y = (v if v.dtype == dtype else v.astype(dtype) for v in (x, y))
    condition = jnp.asarray(condition)
    if condition.dtype != jnp.bool_:
        condition = condition != 0
    shape = jnp.broadcast_shapes(condition.shape, x.shape, y.shape)
    return jax.lax.select(*(jnp.broadcast_to(v, shape) for v in (condition, x, y)))


def clip(x, lower, upper) -> jax.Array:
    """``jnp.clip(x, lower, upper)`` (units of x), traced inline: ``jnp.clip`` is a jitted
    function and becomes a nested program at every use (see ``where``)."""
    return jnp.minimum(jnp.maximum(x, lower), upper)


def hypot(x, y) -> jax.Array:
    """sqrt(x^2 + y^2) without overflow or underflow (units of x and y), traced inline:
    ``jnp.hypot`` is a jitted function (see ``where``). The larger magnitude is factored
    out; at x = y = 0 the value is 0 with a finite gradient, and an infinite input gives
    inf."""
    x, y = jnp.abs(x), jnp.abs(y)
    big, small = jnp.maximum(x, y), jnp.minimum(x, y)
    zero = big == 0
    ratio = small / where(zero, jnp.ones_like(big), big)
    scaled = where(zero, big, big * jnp.sqrt(1.0 + ratio * ratio))
    return where(big == jnp.inf, big, scaled)  # (jnp.isinf is jitted too)
