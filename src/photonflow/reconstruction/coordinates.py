"""The coordinates a track is fitted in, and the ones its covariance is reported in.

A fit moves 7 unconstrained numbers ``free = (q1, q2, q3, t, a, b, eta)``:

- the vertex, kept inside the detector by the map (not by clipping): with the inner
  volume the detector shrunk by ``margin`` (m), a cylinder's (x, y) = R' tanh(rho) (q1,
  q2) / rho (rho = |(q1, q2)|) and z = H' tanh(q3) (H' the inner half-height); a
  sphere's x = R' tanh(|q|) q / |q|; a box's x_i = h_i' tanh(q_i); an open medium's
  world cylinder as a cylinder. Smooth and one-to-one onto the open inner volume;
- the start time t, ns;
- the direction d = (d0 + a e1 + b e2) / |...| around a fixed axis d0 of the fit
  (``FitFrame``; e1, e2 perpendicular to it), regular everywhere within 90 degrees of
  d0, where (a, b) are the tangents of the angles turned towards e1 and e2;
- the kinetic energy E = exp(l0 + (l1 - l0) sigmoid(eta)), inside the emission model's
  range [l0, l1] = log of (1.0001 x threshold, top of the tables) (MeV).

The covariance is reported in ``LOCAL`` coordinates at the fitted track: (x, y, z m,
t ns, the two angles a, b rad about the fitted direction, ln E), where the angles and
ln E are the physical small quantities (a direction error in rad, a fractional energy
error).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..generator.track import Track
from ..geometry.shapes import Box, Cylinder, OpenMedium, Sphere
from ..numerics import safe_sqrt, where
from ..pytree import pytree_dataclass, static_field
from ..transport.optics import orthonormal_basis

#: Names of the reported (local) coordinates, in the covariance's order.
LOCAL = ("x", "y", "z", "time", "angle_1", "angle_2", "log_energy")


@pytree_dataclass
class FitFrame:
    """What the free coordinates are measured against (fixed during a fit).

    Attributes:
        axis: (3,) unit direction d0 around which the direction turns.
        first, second: (3,) unit vectors perpendicular to ``axis`` and each other.
        log_energy_range: (2,) log of the lowest and highest kinetic energy, log(MeV).
        inner: (3,) the inner volume's sizes, m: (R', R', H') for a cylinder and an
            open medium's world, (R', R', R') for a sphere, the half-sizes of a box.
        shape_kind: "cylinder", "sphere" or "box" (static).
        particle: the track's particle (static).
    """

    axis: jax.Array
    first: jax.Array
    second: jax.Array
    log_energy_range: jax.Array
    inner: jax.Array
    shape_kind: str = static_field(default="cylinder")
    particle: str = static_field(default="mu-")


def fit_frame(shape, axis, energy_range, particle: str, margin: float = 0.0,
              dtype=None) -> FitFrame:
    """The ``FitFrame`` of a detector ``shape`` (a ``geometry.shapes`` boundary), a
    direction ``axis`` (3,), the model's (lowest, highest) kinetic energy (MeV) and
    ``margin`` (m, how far inside the walls the vertex stays)."""
    if isinstance(shape, Sphere):
        kind, inner = "sphere", [shape.radius] * 3
    elif isinstance(shape, Box):
        kind, inner = "box", list(shape.half_sizes)
    elif isinstance(shape, Cylinder | OpenMedium):
        radius = shape.radius if isinstance(shape, Cylinder) else shape.world_radius
        height = shape.height if isinstance(shape, Cylinder) else shape.world_height
        kind, inner = "cylinder", [radius, radius, 0.5 * height]
    else:
        raise TypeError(f"shape = {shape!r}: no fit coordinates for this boundary")
    inner = np.asarray(inner, np.float64) - margin
    if np.any(inner <= 0):
        raise ValueError(f"margin = {margin!r} m: leaves no volume inside {shape.describe()}")
    dtype = jnp.result_type(float) if dtype is None else dtype
    axis = jnp.asarray(axis, dtype)
    axis = axis / jnp.linalg.norm(axis)
    first, second = orthonormal_basis(axis)
    low, high = energy_range
    return FitFrame(axis=axis, first=first, second=second,
                    log_energy_range=jnp.log(jnp.asarray([low * 1.0001, high], dtype)),
                    inner=jnp.asarray(inner, dtype), shape_kind=kind, particle=particle)


def _tanh_ratio(rho):
    """tanh(rho) / rho, smooth at 0."""
    small = rho < 1e-3
    safe = where(small, 1.0, rho)
    return where(small, 1.0 - rho * rho / 3.0, jnp.tanh(safe) / safe)


def _artanh_ratio(r):
    """artanh(r) / r for 0 <= r < 1, smooth at 0."""
    small = r < 1e-3
    safe = where(small, 0.5, r)
    return where(small, 1.0 + r * r / 3.0, jnp.arctanh(safe) / safe)


def vertex_from_free(frame: FitFrame, q):
    """(3,) vertex, m, from the free coordinates q (3,)."""
    if frame.shape_kind == "sphere":
        rho = safe_sqrt(jnp.sum(q * q))
        return frame.inner[0] * _tanh_ratio(rho) * q
    if frame.shape_kind == "box":
        return frame.inner * jnp.tanh(q)
    rho = safe_sqrt(q[0] * q[0] + q[1] * q[1])
    across = frame.inner[0] * _tanh_ratio(rho) * q[:2]
    return jnp.concatenate([across, frame.inner[2:] * jnp.tanh(q[2:])])


#: How close to the inner volume's boundary (as a fraction of its size) a vertex outside
#: it is put when converted to free coordinates (a seed outside, e.g.).
EDGE = 1.0 - 1e-4


def free_from_vertex(frame: FitFrame, vertex):
    """(3,) free coordinates of a vertex (3,) m; a vertex outside the inner volume is
    moved onto it first (``EDGE``)."""
    vertex = jnp.asarray(vertex, frame.inner.dtype)
    if frame.shape_kind == "sphere":
        r = jnp.minimum(safe_sqrt(jnp.sum(vertex * vertex)) / frame.inner[0], EDGE)
        direction = vertex / frame.inner[0]
        norm = safe_sqrt(jnp.sum(direction * direction))
        return direction * jnp.where(norm > 0, r / jnp.where(norm > 0, norm, 1.0), 0.0) \
            * _artanh_ratio(r)
    if frame.shape_kind == "box":
        return jnp.arctanh(jnp.clip(vertex / frame.inner, -EDGE, EDGE))
    scaled = vertex[:2] / frame.inner[0]
    norm = safe_sqrt(jnp.sum(scaled * scaled))
    r = jnp.minimum(norm, EDGE)
    across = scaled * jnp.where(norm > 0, r / jnp.where(norm > 0, norm, 1.0), 0.0) \
        * _artanh_ratio(r)
    return jnp.concatenate([across, jnp.arctanh(jnp.clip(vertex[2:] / frame.inner[2],
                                                          -EDGE, EDGE))])


def track_from_free(frame: FitFrame, free) -> Track:
    """The ``Track`` of the free coordinates (7,) (module docstring)."""
    position = vertex_from_free(frame, free[:3])
    direction = frame.axis + free[4] * frame.first + free[5] * frame.second
    direction = direction / jnp.sqrt(jnp.sum(direction * direction))
    low, high = frame.log_energy_range[0], frame.log_energy_range[1]
    energy = jnp.exp(low + (high - low) * jax.nn.sigmoid(free[6]))
    return Track(frame.particle, position, direction, energy, free[3])


def free_from_track(frame: FitFrame, track: Track):
    """(7,) free coordinates of ``track`` (its direction within 90 degrees of the frame's
    axis; its energy clamped inside the frame's range)."""
    direction = jnp.asarray(track.direction, frame.axis.dtype)
    along = jnp.sum(direction * frame.axis)
    a = jnp.sum(direction * frame.first) / along
    b = jnp.sum(direction * frame.second) / along
    low, high = frame.log_energy_range[0], frame.log_energy_range[1]
    share = (jnp.log(jnp.asarray(track.energy, low.dtype)) - low) / (high - low)
    share = jnp.clip(share, 1e-6, 1.0 - 1e-6)
    return jnp.concatenate([free_from_vertex(frame, track.position),
                            jnp.stack([jnp.asarray(track.time, low.dtype), a, b,
                                       jnp.log(share) - jnp.log1p(-share)])])


def track_from_local(frame: FitFrame, local) -> Track:
    """The ``Track`` of ``LOCAL`` coordinates (7,) about the frame's axis (its angles as
    tangents; unconstrained: for the covariance at a fitted track, not for fitting)."""
    direction = frame.axis + local[4] * frame.first + local[5] * frame.second
    direction = direction / jnp.sqrt(jnp.sum(direction * direction))
    return Track(frame.particle, local[:3], direction, jnp.exp(local[6]), local[3])


def local_from_track(track: Track, dtype=None):
    """(7,) ``LOCAL`` coordinates of ``track`` about its own direction (angles 0)."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    position = jnp.asarray(track.position, dtype)
    return jnp.concatenate([position, jnp.stack([
        jnp.asarray(track.time, dtype), jnp.zeros((), dtype), jnp.zeros((), dtype),
        jnp.log(jnp.asarray(track.energy, dtype))])])
