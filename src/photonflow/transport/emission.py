"""Photon emission directions of a point source, from explicit uniforms.

A source's angular density is axially symmetric about its axis (``source.axis``), so a
direction is the axis turned by a polar angle whose cosine comes from the inverse CDF of
the density in cos(theta) (``source.sample_cos``, u1) and an azimuth 2 pi u2
(``optics.deflect``). The inverse CDFs of the calibration sources are in
``photonflow.sources``.

Uniforms are arguments (reparameterised sampling), so a fixed set of them gives a
direction smooth in the source's parameters.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from .optics import deflect


def sample_directions(source, u1, u2):
    """Unit emission directions (..., 3) of ``source`` from uniforms u1, u2 (...,) in [0, 1).

    ``source`` is a ``photonflow.sources.PointSource`` (``IsotropicSource``,
    ``LaserSource``, ``DiffuserSource`` or any class with ``axis`` and ``sample_cos``);
    u1 sets the polar angle to the source axis (inverse CDF of its density), u2 the
    azimuth 2 pi u2 (rad). Works inside ``jit``.
    """
    u1 = jnp.asarray(u1)
    dtype = u1.dtype
    axis = jnp.broadcast_to(source.axis(dtype), u1.shape + (3,))
    cos_theta = source.sample_cos(u1)
    return deflect(axis, cos_theta, 2.0 * math.pi * jnp.asarray(u2, dtype))
