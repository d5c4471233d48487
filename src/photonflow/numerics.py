"""Numerical helpers shared by the geometry and the transport (no physics)."""

from __future__ import annotations

import jax.numpy as jnp


def safe_sqrt(x):
    """sqrt(max(x, 0)) with a finite (zero) gradient at and below 0 (units of sqrt(x))."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)
