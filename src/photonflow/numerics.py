"""Numerical helpers shared by the geometry and the transport (no physics)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def safe_sqrt(x):
    """sqrt(max(x, 0)) with a finite (zero) gradient at and below 0 (units of sqrt(x))."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


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
