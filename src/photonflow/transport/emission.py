"""Photon emission directions of the calibration sources, from explicit uniforms.

Each source's angular density is axially symmetric about an axis (z for the
isotropic source, ``direction`` for the laser and the diffuser), so a direction is the
axis turned by a polar angle whose cosine comes from the inverse CDF of the density in
cos(theta) and an azimuth 2 pi u2 (``optics.deflect``):

- isotropic: cos(theta) = 2 u1 - 1 (density 1 / (4 pi) per sr);
- laser: uniform in the cone of half-angle alpha, cos(theta) = 1 - u1 (1 - cos alpha);
- diffuser: density (1 + a cos theta) / (4 pi), CDF
  F(c) = ((c + 1) + a (c^2 - 1) / 2) / 2, inverted in closed (cancellation-free) form.

Uniforms are arguments (reparameterised sampling), so a fixed set of them gives a
direction smooth in the source's parameters.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from ..numerics import clip
from ..sources import DiffuserSource, IsotropicSource, LaserSource
from .optics import deflect


def isotropic_cos(u):
    """cos(theta) of an isotropic direction from a uniform u in [0, 1)."""
    return 2.0 * u - 1.0


def cone_cos(u, opening_angle):
    """cos(theta) uniform in solid angle within a cone of half-angle ``opening_angle`` (rad)."""
    return 1.0 - u * (1.0 - jnp.cos(opening_angle))


def linear_anisotropy_cos(u, anisotropy):
    """cos(theta) with density (1 + a cos theta) / 2 in cos(theta), a in [-1, 1] (inverse CDF).

    Solves (a / 2) c^2 + c + 1 - a / 2 - 2 u = 0 by the root
    c = 2 (2u - 1 + a/2) / (1 + sqrt(1 - 2 a (1 - a/2 - 2u))), exact for a = 0 too.
    """
    half = 0.5 * anisotropy
    discriminant = jnp.maximum(1.0 - 4.0 * half * (1.0 - half - 2.0 * u), 0.0)
    return clip(2.0 * (2.0 * u - 1.0 + half) / (1.0 + jnp.sqrt(discriminant)), -1.0, 1.0)


def _axis(vector, dtype):
    axis = jnp.asarray(vector, dtype=dtype)
    return axis / jnp.linalg.norm(axis)


def sample_directions(source, u1, u2):
    """Unit emission directions (..., 3) of ``source`` from uniforms u1, u2 (...,) in [0, 1).

    ``source`` is an ``IsotropicSource``, ``LaserSource`` or ``DiffuserSource``; u1 sets
    the polar angle to the source axis (inverse CDF of its density), u2 the azimuth
    2 pi u2 (rad). Works inside ``jit``.
    """
    u1 = jnp.asarray(u1)
    dtype = u1.dtype
    if isinstance(source, IsotropicSource):
        axis = jnp.array([0.0, 0.0, 1.0], dtype)
        cos_theta = isotropic_cos(u1)
    elif isinstance(source, LaserSource):
        axis = _axis(source.direction, dtype)
        cos_theta = cone_cos(u1, jnp.asarray(source.opening_angle, dtype))
    elif isinstance(source, DiffuserSource):
        axis = _axis(source.direction, dtype)
        cos_theta = linear_anisotropy_cos(u1, jnp.asarray(source.anisotropy, dtype))
    else:
        raise TypeError(f"no emission sampler for {type(source).__name__}")
    axis = jnp.broadcast_to(axis, u1.shape + (3,))
    return deflect(axis, cos_theta, 2.0 * math.pi * jnp.asarray(u2, dtype))
