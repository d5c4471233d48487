"""Rays leaving a particle track, for the indirect light of the expected mode.

A ``TrackEmitter`` is what the weighted-ray estimator (``indirect.py``) needs of a track
instead of a point source: ``leaving(key, count, dtype)`` gives rays whose origins lie
along the track and whose directions follow its emission model. The fraction x = s / S
of the extent and the cosine to the track are drawn from a fixed proposal q(x) q(cos)
(the slice's marginal in x, and its angular profile mixed with 20 % of a uniform one so
that no angle is starved), by inverse CDF of a shifted Fibonacci lattice (cosine,
azimuth) and independent uniforms (x); each ray carries rho(s, cos) / (q(x) q(cos) S)
/ count photons. The proposal is held fixed (``stop_gradient``): the rays' geometry moves
with the track's position and direction, and the energy and every parameter enter
through the weights, as for point sources. There is no first-order mirror quadrature
for a track: its source probes count every mirrored path (``mirror_quadrature`` False).
Lengths m, times ns.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from ..constants import SPEED_OF_LIGHT
from ..emission import EmissionSlice
from ..pytree import pytree_dataclass, static_field
from .optics import deflect
from .rays import shifted_lattice

#: Share of the uniform density in the cosine proposal.
UNIFORM_SHARE = 0.2


@pytree_dataclass
class TrackEmitter:
    """A track as a light emitter for the weighted rays.

    Attributes:
        position: (3,) start, m. direction: (3,) unit vector. time: start, ns.
        emission: the track's ``EmissionSlice`` (its energy's emission model).
        length: light is emitted only for s <= length, m (the distance to the wall).
        mirror_quadrature: False (static): no first-order mirror quadrature.
    """

    position: jax.Array
    direction: jax.Array
    time: jax.Array
    emission: EmissionSlice
    length: jax.Array
    mirror_quadrature: bool = static_field(default=False)

    def leaving(self, key, count: int, dtype) -> dict:
        """``count`` rays leaving the track (module docstring): origins (count, 3) m, unit
        directions (count, 3), expected photons (count,) and times (count,) ns."""
        lattice_key, distance_key = jax.random.split(key)
        u = shifted_lattice(lattice_key, count, dtype)
        v = jax.random.uniform(distance_key, (count,), dtype)
        emission = self.emission
        fixed = jax.lax.stop_gradient(emission)
        x_grid, x_pdf = _padded_density(fixed.fraction, 0.0, 1.0, fixed.fraction_profile())
        c_grid, c_profile = _padded_density(fixed.cos, -1.0, 1.0, fixed.cos_profile())
        c_pdf = (1.0 - UNIFORM_SHARE) * c_profile + UNIFORM_SHARE * 0.5
        x, q_x = _inverse_cdf(x_grid, x_pdf, v)
        cos, q_cos = _inverse_cdf(c_grid, c_pdf, u[0])
        extent = fixed.extent
        s = x * extent
        proposal = q_x * q_cos
        weight = emission.density(s, cos) * extent / jnp.where(proposal > 0, proposal, 1.0)
        weight = jnp.where((proposal > 0) & (s <= self.length), weight, 0.0) / count
        origins = self.position + s[:, None] * self.direction
        directions = deflect(jnp.broadcast_to(self.direction, (count, 3)), cos,
                             2.0 * math.pi * u[1])
        offset, _ = emission.time_moments(s)
        time = self.time + s / SPEED_OF_LIGHT + offset
        return {"origins": origins, "directions": directions, "weight": weight, "time": time}


def _padded_density(knots, low, high, values):
    """A normalised piecewise-linear density on [low, high] through ``values`` at the
    knots, held constant beyond the end knots: (grid, pdf)."""
    grid = jnp.concatenate([jnp.full(1, low, knots.dtype), knots,
                            jnp.full(1, high, knots.dtype)])
    pdf = jnp.concatenate([values[:1], values, values[-1:]])
    pdf = jnp.maximum(pdf, 0.0)
    area = jnp.sum(0.5 * (pdf[1:] + pdf[:-1]) * (grid[1:] - grid[:-1]))
    return grid, pdf / jnp.where(area > 0, area, 1.0)


def _inverse_cdf(grid, pdf, u):
    """Samples of the piecewise-linear density (grid, pdf) at uniforms u, by inverting
    its CDF (exactly, the CDF is piecewise quadratic), and the density there."""
    cdf = jnp.concatenate([jnp.zeros(1, pdf.dtype),
                           jnp.cumsum(0.5 * (pdf[1:] + pdf[:-1]) * (grid[1:] - grid[:-1]))])
    u = u * cdf[-1]
    i = jnp.clip(jnp.searchsorted(cdf, u, side="right") - 1, 0, grid.shape[0] - 2)
    width = grid[i + 1] - grid[i]
    slope = (pdf[i + 1] - pdf[i]) / width
    remaining = u - cdf[i]
    # solve pdf_i t + slope t^2 / 2 = remaining for t in [0, width]
    root = jnp.sqrt(jnp.maximum(pdf[i] ** 2 + 2.0 * slope * remaining, 0.0))
    flat = jnp.abs(slope) * width < 1e-6 * jnp.maximum(pdf[i], 1e-30)
    safe_slope = jnp.where(flat, 1.0, slope)
    t = jnp.where(flat, remaining / jnp.maximum(pdf[i], 1e-30), (root - pdf[i]) / safe_slope)
    t = jnp.clip(t, 0.0, width)
    sample = grid[i] + t
    return sample, pdf[i] + slope * t
