"""Rays leaving a particle track, for the indirect light of the expected mode.

A ``TrackEmitter`` is what the weighted-ray estimator (``indirect.py``) needs of a track
instead of a point source: ``leaving(key, count, dtype)`` gives rays whose directions
follow its emission model and whose weights carry its light. The rays' geometry is
fixed by a *reference* track (held constant: ``stop_gradient``), the track itself
enters only through the weights, so the indirect light is a smooth function of the
track's position, direction, energy and time near the reference (a ray never starts
or stops hitting a disc as the track moves).

Proposal (reference track R, start x_R, direction d_R, its energy's emission slice):
the fraction x = s / S_R of the extent from the slice's marginal in x (mixed with 10 %
of a uniform density over [-3 w, 1.5 S_R + 3 w] / S_R, w the width of the soft ends
below, so that a longer track than the reference is covered), the cosine to d_R from its
angular profile mixed with 20 % of a uniform one (so that no angle is starved), a
uniform azimuth, and a lateral offset from a 2-D Gaussian of width sigma
(``kernel_width``: 0.25 m, or the detector's extent / 400 where that is less: 5 mm in
TAO, whose sphere focuses its mirror images of the track onto a few tiles): origin
x_R + s d_R + offset. Target (the track T being predicted): its emission smeared by the
same kernel, rho_T(s_T, cos_T) / 2 pi x K_sigma(r_T) x
Phi(s_T / sigma) Phi((L_T - s_T) / sigma), with s_T, r_T and cos_T the ray's origin
and direction in T's frame, L_T the light's extent up to the wall, Phi the normal CDF
and sigma replaced by w = min(sigma, L_T / 8) in it (soft ends of the track, narrow
enough on a short track to keep its light's total). Each ray carries target / proposal
/ count photons. At T = R this estimates the indirect light of the track smeared by
~sigma, which a scattered or reflected photon's path of metres does not resolve; as T
moves away from R by more than ~sigma or a few degrees the weights grow uneven
(noisier, not biased).
There is no first-order mirror quadrature for a track: its source probes count every
mirrored path (``mirror_quadrature`` False). Lengths m, times ns.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax.scipy.special import ndtr

from ..constants import SPEED_OF_LIGHT
from ..emission import EmissionSlice
from ..pytree import pytree_dataclass, static_field
from .optics import deflect, orthonormal_basis
from .rays import shifted_lattice

#: Share of the uniform density in the cosine proposal.
UNIFORM_SHARE = 0.2
#: Share of the uniform density in the proposal along the track.
UNIFORM_ALONG = 0.1
#: Width sigma (m) of the kernel that smears the track's light for its rays: ``SPREAD``,
#: or ``SPREAD_SHARE`` of the detector's extent in a smaller detector (a curved wall's
#: mirror images of the track, e.g. the focus of TAO's sphere, blur with the kernel).
SPREAD = 0.25
SPREAD_SHARE = 1.0 / 400.0


def kernel_width(shape) -> float:
    """The kernel width sigma (m) for a detector ``shape``: min(``SPREAD``,
    ``SPREAD_SHARE`` x its extent)."""
    return min(SPREAD, SPREAD_SHARE * float(shape.extent)) if shape.has_walls else SPREAD
#: The proposal along the track reaches this many times the reference's extent (a track
#: of higher energy than its reference emits further).
REACH = 1.5


@pytree_dataclass
class TrackEmitter:
    """A track as a light emitter for the weighted rays (module docstring).

    Attributes:
        position: (3,) start, m. direction: (3,) unit vector. time: start, ns.
        emission: the track's ``EmissionSlice`` (its energy's emission model).
        length: light is emitted only for s <= length, m (the distance to the wall).
        reference_position, reference_direction, reference_emission: the reference
            track that fixes the rays' geometry (used through ``stop_gradient``).
        spread: the kernel width sigma, m (static; ``kernel_width``).
        mirror_quadrature: False (static): no first-order mirror quadrature.
    """

    position: jax.Array
    direction: jax.Array
    time: jax.Array
    emission: EmissionSlice
    length: jax.Array
    reference_position: jax.Array
    reference_direction: jax.Array
    reference_emission: EmissionSlice
    spread: float = static_field(default=SPREAD)
    mirror_quadrature: bool = static_field(default=False)

    def leaving(self, key, count: int, dtype) -> dict:
        """``count`` rays leaving the track (module docstring): origins (count, 3) m, unit
        directions (count, 3), expected photons (count,) and times (count,) ns."""
        lattice_key, distance_key, spread_key = jax.random.split(key, 3)
        u = shifted_lattice(lattice_key, count, dtype)
        v = jax.random.uniform(distance_key, (count,), dtype)
        lateral = jax.random.normal(spread_key, (count, 2), dtype)
        fixed, start, axis = jax.lax.stop_gradient(
            (self.reference_emission, self.reference_position, self.reference_direction))
        pad = 3.0 * _end_width(fixed.extent, self.spread) / fixed.extent
        x_grid, x_pdf = _padded_density(fixed.fraction, -pad, REACH + pad,
                                        fixed.fraction_profile())
        x_pdf = (1.0 - UNIFORM_ALONG) * x_pdf + UNIFORM_ALONG / (REACH + 2.0 * pad)
        c_grid, c_profile = _padded_density(fixed.cos, -1.0, 1.0, fixed.cos_profile())
        c_pdf = (1.0 - UNIFORM_SHARE) * c_profile + UNIFORM_SHARE * 0.5
        x, q_x = _inverse_cdf(x_grid, x_pdf, v)
        cos, q_cos = _inverse_cdf(c_grid, c_pdf, u[0])
        first, second = orthonormal_basis(axis)
        origins = start + (x * fixed.extent)[:, None] * axis \
            + self.spread * (lateral[:, :1] * first + lateral[:, 1:] * second)
        directions = deflect(jnp.broadcast_to(axis, (count, 3)), cos, 2.0 * math.pi * u[1])
        kernel_reference = jnp.exp(-0.5 * jnp.sum(lateral * lateral, axis=1))
        proposal = q_x / fixed.extent * q_cos * kernel_reference

        # the track's smeared emission at each ray's origin and direction
        offset = origins - self.position
        s = offset @ self.direction
        across2 = jnp.maximum(jnp.sum(offset * offset, axis=1) - s * s, 0.0)
        extent = jnp.minimum(self.emission.extent, self.length)
        width = _end_width(extent, self.spread)
        ends = ndtr(s / width) * ndtr((extent - s) / width)
        inside = jnp.clip(s, 0.0, extent)
        target = self.emission.density(inside, directions @ self.direction) * ends \
            * jnp.exp(-0.5 * across2 / self.spread**2)
        weight = jnp.where(proposal > 0, target / jnp.where(proposal > 0, proposal, 1.0), 0.0)
        mean_offset, _ = self.emission.time_moments(inside)
        time = self.time + s / SPEED_OF_LIGHT + mean_offset
        return {"origins": origins, "directions": directions, "weight": weight / count,
                "time": time}


def _end_width(extent, spread):
    """Width (m) of the soft ends of a track's light: the kernel width ``spread``, or an
    eighth of the extent for short tracks (so that the soft ends keep the light's
    total)."""
    return jnp.minimum(spread, extent / 8.0)


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
