"""Analytic detector boundaries: cylinder, sphere, box and open medium.

All shapes are centred on the origin; the cylinder axis is z. Lengths in metres.
Shapes are small immutable (hashable) records, so a ``Detector`` can carry its shape
as static configuration.

Ray intersections are written for float32 at 40 m scale: the quadratic is solved in
the numerically stable form and then solved again from the point it found (a nearby
point, where the constant term is tiny), so the returned distances are accurate to a
few micrometres instead of the ~0.1 mm a naive float32 solution gives.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError, format_value
from ..numerics import hypot, safe_sqrt, where

_INF = jnp.inf


def _xp(points):
    """numpy for host arrays (no compilation per new sensor count), jax.numpy otherwise."""
    return np if isinstance(points, np.ndarray | list | tuple | float | int) else jnp


def xyz(vectors):
    """The x, y, z components (...,) of vectors (..., 3), as a 3-tuple of arrays."""
    return tuple(vectors[..., k] for k in range(3))


def _check_positive(shape: str, **values: float) -> None:
    for name, value in values.items():
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ConfigError(
                f"{shape}.{name} = {format_value(value)}: must be a positive, finite length in m"
            )


def _safe_divide(numerator, denominator):
    """numerator / denominator with 0 denominators mapped to +-inf (never NaN)."""
    tiny = jnp.abs(denominator) < 1e-30
    safe = where(tiny, 1.0, denominator)
    ratio = numerator / safe
    sign = where(numerator >= 0, 1.0, -1.0)
    return where(tiny, sign * _INF, ratio)


def _slab_interval(origin, direction, half_width):
    """Parameter interval in which o + t d lies within |x| <= half_width (one axis)."""
    t_low = _safe_divide(-half_width - origin, direction)
    t_high = _safe_divide(half_width - origin, direction)
    parallel = jnp.abs(direction) < 1e-30
    inside = jnp.abs(origin) <= half_width
    t0 = where(parallel, where(inside, -_INF, _INF), jnp.minimum(t_low, t_high))
    t1 = where(parallel, where(inside, _INF, -_INF), jnp.maximum(t_low, t_high))
    return t0, t1


def _quadric_interval(a, b, c):
    """Interval of t where a t^2 + 2 b t + c <= 0 (a >= 0), in the stable root form.

    ``c`` should be computed as (rho - R)(rho + R) by the caller, never rho^2 - R^2.
    Returns (t0, t1); an empty interval is (inf, -inf).
    """
    disc = b * b - a * c
    positive = disc > 0
    root = where(positive, jnp.sqrt(where(positive, disc, 1.0)), 0.0)  # finite grad
    q = -(b + where(b >= 0, root, -root))
    safe_q = where(q == 0, 1.0, q)
    safe_a = where(a == 0, 1.0, a)
    r1 = q / safe_a
    r2 = where(q == 0, 0.0, c / safe_q)
    t0 = jnp.minimum(r1, r2)
    t1 = jnp.maximum(r1, r2)
    degenerate = a < 1e-30  # direction parallel to the axis of the quadric
    t0 = where(degenerate, where(c <= 0, -_INF, _INF), t0)
    t1 = where(degenerate, where(c <= 0, _INF, -_INF), t1)
    miss = (disc < 0) & ~degenerate
    return where(miss, _INF, t0), where(miss, -_INF, t1)


def _nearest_root(t0, t1):
    """Of the two interval ends, the one closest to zero (used for refinement)."""
    finite0 = jnp.isfinite(t0)
    finite1 = jnp.isfinite(t1)
    pick0 = finite0 & (~finite1 | (jnp.abs(t0) <= jnp.abs(t1)))
    return where(pick0, t0, where(finite1, t1, 0.0))


@dataclasses.dataclass(frozen=True)
class Shape:
    """Base class of analytic detector boundaries (lengths in m)."""

    kind: ClassVar[str] = "shape"
    has_walls: ClassVar[bool] = True

    # ---- description -------------------------------------------------------------
    def dimensions(self) -> dict[str, float]:
        """The defining dimensions, name -> value in m."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def describe(self) -> str:
        """One-line human description, e.g. ``cylinder 33.68 m diameter x 36.20 m``."""
        raise NotImplementedError

    @property
    def wall_area(self) -> float:
        """Area of the wall on which sensors sit, m^2 (nan for an open medium)."""
        raise NotImplementedError

    @property
    def volume(self) -> float:
        """Enclosed volume, m^3."""
        raise NotImplementedError

    @property
    def extent(self) -> float:
        """Largest distance between two points of the volume (m)."""
        raise NotImplementedError

    # ---- point queries ------------------------------------------------------------
    def distance_to_wall(self, points):
        """Signed distance (m) from points (..., 3) to the boundary; positive inside."""
        raise NotImplementedError

    def contains(self, points, tolerance: float = 0.0):
        """Whether points (..., 3) are inside the boundary, with a tolerance in m."""
        return self.distance_to_wall(points) >= -tolerance

    def inward_normal(self, points):
        """Unit inward normal (..., 3) of the wall face nearest to each point."""
        raise NotImplementedError

    # ---- rays -------------------------------------------------------------------------
    def _raw_interval(self, origins, directions):
        raise NotImplementedError

    def ray_interval(self, origins, directions):
        """Where rays o + t d (t any real) are inside the boundary.

        origins, directions: (..., 3), m and unit vectors. Returns ``(t_enter, t_exit)``
        in m along the ray, each (...,); for a ray from inside, t_enter < 0 < t_exit
        (t_exit is where it leaves); a ray that misses has t_enter = inf, t_exit = -inf.
        Both ends are refined by a second solve from the point found first (float32-safe).
        """
        t0, t1 = self._raw_interval(origins, directions)
        hit = t0 <= t1
        return self._refine(origins, directions, t0, hit), self._refine(
            origins, directions, t1, hit
        )

    def _refine(self, origins, directions, t, hit):
        finite = hit & jnp.isfinite(t)
        t_safe = where(finite, t, 0.0)
        near = origins + t_safe[..., None] * directions
        c0, c1 = self._raw_interval(near, directions)
        correction = where(finite, _nearest_root(c0, c1), 0.0)
        return where(finite, t_safe + correction, t)

    def ray_exit(self, origins, directions):
        """Distance (m) along each ray from an inside origin to the wall (the exit point)."""
        return self.ray_interval(origins, directions)[1]


@dataclasses.dataclass(frozen=True)
class Cylinder(Shape):
    """Upright cylinder centred on the origin: radius and height in m, axis along z."""

    radius: float
    height: float
    kind: ClassVar[str] = "cylinder"

    def __post_init__(self):
        _check_positive("cylinder", radius=self.radius, height=self.height)

    def describe(self) -> str:
        return f"cylinder {2 * self.radius:.2f} m diameter x {self.height:.2f} m"

    @property
    def wall_area(self) -> float:
        return 2 * math.pi * self.radius * self.height + 2 * math.pi * self.radius**2

    @property
    def volume(self) -> float:
        return math.pi * self.radius**2 * self.height

    @property
    def extent(self) -> float:
        return math.hypot(2 * self.radius, self.height)

    def distance_to_wall(self, points):
        xp = _xp(points)
        points = xp.asarray(points)
        rho = xp.hypot(points[..., 0], points[..., 1])
        return xp.minimum(self.radius - rho, 0.5 * self.height - xp.abs(points[..., 2]))

    def inward_normal(self, points):
        xp = _xp(points)
        points = xp.asarray(points)
        rho = xp.hypot(points[..., 0], points[..., 1])
        safe_rho = xp.where(rho > 0, rho, 1.0)
        barrel = xp.stack(
            [-points[..., 0] / safe_rho, -points[..., 1] / safe_rho, xp.zeros_like(rho)], -1
        )
        cap = xp.stack([xp.zeros_like(rho), xp.zeros_like(rho), -xp.sign(points[..., 2])], -1)
        on_cap = (0.5 * self.height - xp.abs(points[..., 2])) < (self.radius - rho)
        return xp.where(on_cap[..., None], cap, barrel)

    def _raw_interval(self, origins, directions):
        return _cylinder_interval(origins, directions, self.radius, 0.5 * self.height)


def _cylinder_interval(origins, directions, radius, half_height):
    ox, oy, oz = origins[..., 0], origins[..., 1], origins[..., 2]
    dx, dy, dz = directions[..., 0], directions[..., 1], directions[..., 2]
    rho = hypot(ox, oy)
    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    c = (rho - radius) * (rho + radius)
    r0, r1 = _quadric_interval(a, b, c)
    z0, z1 = _slab_interval(oz, dz, half_height)
    t0 = jnp.maximum(r0, z0)
    t1 = jnp.minimum(r1, z1)
    miss = t0 > t1
    return where(miss, _INF, t0), where(miss, -_INF, t1)


@dataclasses.dataclass(frozen=True)
class Sphere(Shape):
    """Sphere centred on the origin, radius in m."""

    radius: float
    kind: ClassVar[str] = "sphere"

    def __post_init__(self):
        _check_positive("sphere", radius=self.radius)

    def describe(self) -> str:
        return f"sphere {2 * self.radius:.2f} m diameter"

    @property
    def wall_area(self) -> float:
        return 4 * math.pi * self.radius**2

    @property
    def volume(self) -> float:
        return 4.0 / 3.0 * math.pi * self.radius**3

    @property
    def extent(self) -> float:
        return 2 * self.radius

    def distance_to_wall(self, points):
        xp = _xp(points)
        return self.radius - xp.linalg.norm(xp.asarray(points), axis=-1)

    def inward_normal(self, points):
        xp = _xp(points)
        points = xp.asarray(points)
        norm = xp.linalg.norm(points, axis=-1, keepdims=True)
        return -points / xp.where(norm > 0, norm, 1.0)

    def _raw_interval(self, origins, directions):
        # finite gradient at the centre, where d rho / d o is 0 x NaN
        rho = safe_sqrt(jnp.sum(origins * origins, axis=-1))
        a = jnp.sum(directions * directions, axis=-1)
        b = jnp.sum(origins * directions, axis=-1)
        c = (rho - self.radius) * (rho + self.radius)
        return _quadric_interval(a, b, c)


@dataclasses.dataclass(frozen=True)
class Box(Shape):
    """Axis-aligned box centred on the origin; full edge lengths in m."""

    size_x: float
    size_y: float
    size_z: float
    kind: ClassVar[str] = "box"

    def __post_init__(self):
        _check_positive("box", size_x=self.size_x, size_y=self.size_y, size_z=self.size_z)

    @property
    def half_sizes(self) -> tuple[float, float, float]:
        """Half edge lengths (m)."""
        return (0.5 * self.size_x, 0.5 * self.size_y, 0.5 * self.size_z)

    def describe(self) -> str:
        return f"box {self.size_x:.2f} x {self.size_y:.2f} x {self.size_z:.2f} m"

    @property
    def wall_area(self) -> float:
        x, y, z = self.size_x, self.size_y, self.size_z
        return 2 * (x * y + y * z + x * z)

    @property
    def volume(self) -> float:
        return self.size_x * self.size_y * self.size_z

    @property
    def extent(self) -> float:
        return math.sqrt(self.size_x**2 + self.size_y**2 + self.size_z**2)

    def distance_to_wall(self, points):
        xp = _xp(points)
        points = xp.asarray(points)
        half = xp.asarray(self.half_sizes, dtype=points.dtype)
        return xp.min(half - xp.abs(points), axis=-1)

    def inward_normal(self, points):
        xp = _xp(points)
        points = xp.asarray(points)
        half = xp.asarray(self.half_sizes, dtype=points.dtype)
        gap = half - xp.abs(points)
        axis = xp.argmin(gap, axis=-1)
        one_hot = xp.eye(3, dtype=points.dtype)[axis]
        return -one_hot * xp.sign(points)

    def _raw_interval(self, origins, directions):
        t0 = jnp.full(origins.shape[:-1], -_INF, dtype=origins.dtype)
        t1 = jnp.full(origins.shape[:-1], _INF, dtype=origins.dtype)
        for axis, half in enumerate(self.half_sizes):
            s0, s1 = _slab_interval(origins[..., axis], directions[..., axis], half)
            t0 = jnp.maximum(t0, s0)
            t1 = jnp.minimum(t1, s1)
        miss = t0 > t1
        return where(miss, _INF, t0), where(miss, -_INF, t1)


@dataclasses.dataclass(frozen=True)
class OpenMedium(Shape):
    """An open medium without walls (ice, sea water) with sensors hung on strings.

    ``world_radius`` and ``world_height`` (m) bound the simulated volume: a cylinder
    around the array beyond which light is counted as lost. Nothing reflects there.
    """

    world_radius: float
    world_height: float
    kind: ClassVar[str] = "open"
    has_walls: ClassVar[bool] = False

    def __post_init__(self):
        _check_positive("open", world_radius=self.world_radius, world_height=self.world_height)

    def describe(self) -> str:
        return (
            f"open medium, world {2 * self.world_radius:.0f} m diameter x {self.world_height:.0f} m"
        )

    @property
    def wall_area(self) -> float:
        return math.nan

    @property
    def volume(self) -> float:
        return math.pi * self.world_radius**2 * self.world_height

    @property
    def extent(self) -> float:
        return math.hypot(2 * self.world_radius, self.world_height)

    def distance_to_wall(self, points):
        xp = _xp(points)
        points = xp.asarray(points)
        rho = xp.hypot(points[..., 0], points[..., 1])
        return xp.minimum(self.world_radius - rho, 0.5 * self.world_height - xp.abs(points[..., 2]))

    def inward_normal(self, points):
        return Cylinder(self.world_radius, self.world_height).inward_normal(points)

    def _raw_interval(self, origins, directions):
        return _cylinder_interval(origins, directions, self.world_radius, 0.5 * self.world_height)


SHAPES: dict[str, type[Shape]] = {cls.kind: cls for cls in (Cylinder, Sphere, Box, OpenMedium)}


def shape_from_dict(spec: dict) -> Shape:
    """Build a shape from ``{"kind": "cylinder", "radius": ..., "height": ...}`` (m)."""
    spec = dict(spec)
    kind = spec.pop("kind", None)
    if kind not in SHAPES:
        raise ConfigError(
            f"detector.shape.kind = {format_value(kind)}: must be one of {', '.join(SHAPES)}"
        )
    cls = SHAPES[kind]
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(spec) - set(names))
    if unknown:
        raise ConfigError(
            f"detector.shape.{unknown[0]}: unknown for a {kind}; expected {', '.join(names)}"
        )
    missing = [n for n in names if n not in spec]
    if missing:
        raise ConfigError(
            f"detector.shape.{missing[0]}: missing (a {kind} needs {', '.join(names)})"
        )
    values = {}
    for name in names:
        value = spec[name]
        try:
            values[name] = float(value)
        except (TypeError, ValueError):
            raise ConfigError(
                f"detector.shape.{name} = {format_value(value)}: must be a number in m"
            ) from None
    return cls(**values)


def shape_to_dict(shape: Shape) -> dict:
    """Inverse of ``shape_from_dict``: ``{"kind": ..., <dimension>: value in m}``."""
    return {"kind": shape.kind, **shape.dimensions()}
