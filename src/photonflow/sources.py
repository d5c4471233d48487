"""Calibration light sources: immutable pytrees whose continuous fields are all leaves.

Every source emits ``n_photons`` photons from a point ``position`` (m) at time ``time``
(ns) with a pulse of width ``pulse_width`` (ns, Gaussian sigma; it spreads arrival
times, it does not shift their mean). Its angular density is axially symmetric about
an axis, and the transport asks every source the same four things (``PointSource``), so
a new source plugs in without a change to the transport:

- ``axis(dtype)``: the (3,) unit axis of the density (z for the isotropic source);
- ``sample_cos(u)``: cos(theta) to the axis from uniforms u in [0, 1) (inverse CDF of
  the density in cos theta; reparameterised, so smooth in the source's fields);
- ``emission_density(directions)``: photons per steradian per emitted photon,
  normalised to 1 over the sphere;
- ``disc_fraction(centre, normal, radius)``: the fraction of the photons emitted
  towards each of a set of discs (the density integrated exactly over the disc's solid
  angle, by the rim integrals of ``geometry.solid_angle``).

Python numbers, lists and numpy arrays given to a constructor are converted to JAX
arrays of the default float dtype (float32 unless 64-bit mode is on); JAX arrays and
tracers are kept as given, so the classes work inside ``jit``, ``grad`` and ``vmap``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np

from .errors import ConfigError, format_value
from .geometry.detector import Detector
from .geometry.solid_angle import (
    disc_cone_solid_angle,
    disc_cosine_moment,
    disc_solid_angle,
    versine,
)
from .numerics import clip, strict_array, where
from .pytree import pytree_dataclass

#: Allowed deviation of a direction's length from 1 in ``check_source``.
DIRECTION_TOLERANCE = 1e-3


def _as_leaves(obj) -> None:
    """Convert plain-Python / numpy field values of a source to JAX float arrays."""
    for field in dataclasses.fields(obj):
        value = getattr(obj, field.name)
        if isinstance(value, (int, float, list, tuple, np.ndarray, np.generic)):
            object.__setattr__(obj, field.name, strict_array(value))


def _unit(vector):
    """``vector / |vector|`` along the last axis."""
    vector = jnp.asarray(vector)
    return vector / jnp.linalg.norm(vector, axis=-1, keepdims=True)


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


@runtime_checkable
class PointSource(Protocol):
    """What the transport needs of a point source (the module docstring): its fields
    ``position`` (3,) m, ``n_photons``, ``time`` ns and ``pulse_width`` ns, and the four
    methods below. ``IsotropicSource``, ``LaserSource`` and ``DiffuserSource`` are
    point sources. The transport of both modes needs nothing else; ``check_source``
    and the event files' truth read the fields of a dataclass, so a new source is best
    a ``pytree_dataclass`` too (tests/test_source_interface.py has one)."""

    position: jax.Array
    n_photons: jax.Array
    time: jax.Array
    pulse_width: jax.Array

    def axis(self, dtype=None) -> jax.Array:
        """(3,) unit axis of the angular density, in ``dtype``."""

    def sample_cos(self, u) -> jax.Array:
        """cos(theta) to the axis from uniforms u in [0, 1) (inverse CDF)."""

    def emission_density(self, unit_directions) -> jax.Array:
        """Photons per steradian per emitted photon for directions (..., 3)."""

    def disc_fraction(self, centre, normal, radius) -> jax.Array:
        """(...,) fraction of the photons emitted towards discs: centres (..., 3) m, unit
        normals (..., 3), radii (...,) m."""


@pytree_dataclass
class IsotropicSource:
    """A point source emitting uniformly over 4 pi.

    Attributes:
        position: (3,) emission point, m.
        n_photons: number of photons emitted per pulse.
        time: emission time, ns.
        pulse_width: Gaussian sigma of the emission time, ns.
    """

    position: jax.Array
    n_photons: jax.Array
    time: jax.Array = 0.0
    pulse_width: jax.Array = 0.0

    def __post_init__(self):
        _as_leaves(self)

    def axis(self, dtype=None):
        """(3,) axis of the angular density: z (the density has no preferred direction)."""
        return jnp.array([0.0, 0.0, 1.0], dtype)

    def sample_cos(self, u):
        """cos(theta) = 2u - 1 from uniforms u in [0, 1)."""
        return isotropic_cos(jnp.asarray(u))

    def emission_density(self, unit_directions):
        """Photons per steradian per emitted photon, 1 / (4 pi), for directions (..., 3)."""
        unit_directions = jnp.asarray(unit_directions)
        return jnp.full(unit_directions.shape[:-1], 1.0 / (4.0 * math.pi), unit_directions.dtype)

    def disc_fraction(self, centre, normal, radius):
        """Omega / (4 pi) per disc (``disc_solid_angle``); centres (..., 3) m, unit
        normals (..., 3), radii (...,) m."""
        return disc_solid_angle(self.position, centre, normal, radius) / (4.0 * math.pi)


@pytree_dataclass
class LaserSource:
    """A laser: uniform emission into a cone of half-angle ``opening_angle`` about ``direction``.

    Attributes:
        position: (3,) emission point, m.
        direction: (3,) cone axis, unit vector (normalised again where used).
        n_photons: number of photons emitted per pulse.
        opening_angle: half-angle alpha of the uniform cone, rad, in (0, pi].
        time: emission time, ns.
        pulse_width: Gaussian sigma of the emission time, ns.

    The cone has a hard edge: the density is 1 / (2 pi (1 - cos alpha)) inside and 0
    outside, so it is differentiable in ``opening_angle`` (through the normalisation)
    but its derivative with respect to ``direction`` is zero except on the edge.
    """

    position: jax.Array
    direction: jax.Array
    n_photons: jax.Array
    opening_angle: jax.Array
    time: jax.Array = 0.0
    pulse_width: jax.Array = 0.0

    def __post_init__(self):
        _as_leaves(self)

    def axis(self, dtype=None):
        """(3,) unit cone axis (``direction`` normalised)."""
        return _unit(jnp.asarray(self.direction, dtype))

    def sample_cos(self, u):
        """cos(theta) uniform in solid angle inside the cone, from uniforms u in [0, 1)."""
        u = jnp.asarray(u)
        return cone_cos(u, jnp.asarray(self.opening_angle, u.dtype))

    def emission_density(self, unit_directions):
        """Photons per steradian per emitted photon for directions (..., 3): 1/(2 pi (1 - cos
        alpha)) inside the cone, 0 outside."""
        cos_angle = jnp.sum(jnp.asarray(unit_directions) * _unit(self.direction), axis=-1)
        cos_alpha = jnp.cos(self.opening_angle)
        inside = cos_angle >= cos_alpha
        return where(inside, 1.0 / (2.0 * math.pi * (1.0 - cos_alpha)), 0.0)

    def disc_fraction(self, centre, normal, radius):
        """Omega(disc image inside the cone) / (2 pi (1 - cos alpha)) per disc
        (``disc_cone_solid_angle``: smooth in the position, direction and opening angle,
        also for discs on the cone's edge); centres (..., 3) m, unit normals, radii m."""
        inside = disc_cone_solid_angle(
            self.position, self.direction, self.opening_angle, centre, normal, radius
        )
        return inside / (2.0 * math.pi * versine(self.opening_angle))


@pytree_dataclass
class DiffuserSource:
    """A diffuser ball with a linear anisotropy: density (1 + a cos theta) / (4 pi).

    theta is the angle to ``direction``; ``anisotropy`` a in [-1, 1] (0 = isotropic).

    Attributes:
        position: (3,) emission point, m.
        n_photons: number of photons emitted per pulse.
        direction: (3,) axis of the anisotropy, unit vector (normalised again where used).
        anisotropy: a in [-1, 1], dimensionless.
        time: emission time, ns.
        pulse_width: Gaussian sigma of the emission time, ns.
    """

    position: jax.Array
    n_photons: jax.Array
    direction: jax.Array
    anisotropy: jax.Array = 0.0
    time: jax.Array = 0.0
    pulse_width: jax.Array = 0.0

    def __post_init__(self):
        _as_leaves(self)

    def axis(self, dtype=None):
        """(3,) unit axis of the anisotropy (``direction`` normalised)."""
        return _unit(jnp.asarray(self.direction, dtype))

    def sample_cos(self, u):
        """cos(theta) with density (1 + a cos theta) / 2 in cos theta, from uniforms u."""
        u = jnp.asarray(u)
        return linear_anisotropy_cos(u, jnp.asarray(self.anisotropy, u.dtype))

    def emission_density(self, unit_directions):
        """Photons per steradian per emitted photon, (1 + a cos theta) / (4 pi), for (..., 3)."""
        cos_angle = jnp.sum(jnp.asarray(unit_directions) * _unit(self.direction), axis=-1)
        return (1.0 + self.anisotropy * cos_angle) / (4.0 * math.pi)

    def disc_fraction(self, centre, normal, radius):
        """(Omega + a M) / (4 pi) per disc, M the disc's cosine moment about the axis
        (``disc_cosine_moment``); centres (..., 3) m, unit normals, radii m."""
        omega = disc_solid_angle(self.position, centre, normal, radius)
        moment = disc_cosine_moment(self.position, self.direction, centre, normal, radius)
        return (omega + self.anisotropy * moment) / (4.0 * math.pi)


Source = IsotropicSource | LaserSource | DiffuserSource


def _field_error(name: str, value, rule: str) -> ConfigError:
    return ConfigError(f"source.{name} = {format_value(value)}: {rule}")


def check_source(source: Source, detector: Detector) -> Source:
    """Validate a source against a detector; raise a one-line ``ConfigError`` if bad.

    Checks: no NaN field; position (m) inside the detector boundary; n_photons > 0;
    pulse_width >= 0; a direction of unit length; a laser opening angle in (0, pi];
    a diffuser anisotropy in [-1, 1]. Returns ``source`` unchanged.
    """
    values = {
        f.name: np.asarray(getattr(source, f.name), dtype=np.float64)
        for f in dataclasses.fields(source)
    }

    def show(name):
        value = values[name]
        return np.round(value, 4).tolist() if value.ndim else float(value)

    for name, value in values.items():
        if np.isnan(value).any():
            raise _field_error(name, show(name), "is NaN")
    for name, value in values.items():
        if not np.isfinite(value).all():
            raise _field_error(name, show(name), "not finite")
    if values["position"].shape != (3,):
        raise ConfigError(f"source.position: shape {values['position'].shape}, expected (3,)")
    distance = float(np.asarray(detector.shape.distance_to_wall(values["position"])))
    if distance < 0:
        raise _field_error(
            "position",
            show("position"),
            f"outside the {detector.shape.describe()} by {-distance:.3g} m",
        )
    if not values["n_photons"] > 0:
        raise _field_error("n_photons", show("n_photons"), "must be > 0")
    if not values["pulse_width"] >= 0:
        raise _field_error("pulse_width", show("pulse_width"), "must be >= 0 ns")
    if "direction" in values:
        direction = values["direction"]
        if direction.shape != (3,):
            raise ConfigError(f"source.direction: shape {direction.shape}, expected (3,)")
        length = float(np.linalg.norm(direction))
        if abs(length - 1.0) > DIRECTION_TOLERANCE:
            raise _field_error(
                "direction", show("direction"), f"not a unit vector (length {length:.4g})"
            )
    if "opening_angle" in values and not 0 < values["opening_angle"] <= math.pi:
        raise _field_error("opening_angle", show("opening_angle"), "must be in (0, pi] rad")
    if "anisotropy" in values and not -1 <= values["anisotropy"] <= 1:
        raise _field_error("anisotropy", show("anisotropy"), "must be in [-1, 1]")
    return source


#: Source kinds by name, as used by configuration files and the command line.
SOURCE_KINDS = {"isotropic": IsotropicSource, "laser": LaserSource, "diffuser": DiffuserSource}


def source_kind(source: Source) -> str:
    """The name of a source's kind ("isotropic", "laser" or "diffuser")."""
    return next(name for name, cls in SOURCE_KINDS.items() if isinstance(source, cls))


def make_source(
    kind: str,
    position,
    n_photons: float,
    *,
    direction=None,
    opening_angle: float | None = None,
    anisotropy: float = 0.0,
    time: float = 0.0,
    pulse_width: float = 0.0,
) -> Source:
    """Build a source by kind name; a one-line ``ConfigError`` for a bad combination.

    Args:
        kind: "isotropic", "laser" (needs ``direction`` and ``opening_angle``, rad) or
            "diffuser" (``direction`` and ``anisotropy`` in [-1, 1]).
        position: (3,) m. n_photons: photons per pulse. time, pulse_width: ns.
        direction: (3,) unit vector (normalised here if its length is off by rounding).
    """
    if kind not in SOURCE_KINDS:
        raise ConfigError(
            f"source = {format_value(kind)}: must be one of {', '.join(SOURCE_KINDS)}"
        )
    common = {
        "position": position,
        "n_photons": n_photons,
        "time": time,
        "pulse_width": pulse_width,
    }
    if kind == "isotropic":
        return IsotropicSource(**common)
    if direction is None:
        raise ConfigError(f"source.direction: required for a {kind} source (a unit vector)")
    direction = np.asarray(direction, dtype=np.float64)
    length = float(np.linalg.norm(direction))
    if not length > 0:
        raise _field_error("direction", direction.tolist(), "must be a non-zero vector")
    direction = direction / length
    if kind == "laser":
        if opening_angle is None:
            raise ConfigError("source.opening_angle: required for a laser source (rad)")
        return LaserSource(direction=direction, opening_angle=opening_angle, **common)
    return DiffuserSource(direction=direction, anisotropy=anisotropy, **common)
