"""Flat maps of a detector's wall: 2-D coordinates of every sensor, per shape.

One function, ``sensor_map(detector)``, turns the 3-D sensor positions into map
coordinates that a geometry picture or an event display can draw directly:

- cylinder: the barrel unrolled into a rectangle (x = R * phi, y = z) with the two
  caps folded out above and below it as discs of radius R, each cap touching the
  barrel at phi = 0 (the fold keeps the map continuous there);
- sphere: Mollweide equal-area map, x = 2 sqrt(2)/pi * R * lon * cos(theta),
  y = sqrt(2) * R * sin(theta), with 2 theta + sin(2 theta) = pi sin(lat);
- box: the six faces unfolded into a cross (the four side faces in a row around z,
  top and bottom folded out above and below the +x face);
- open medium: a side view of the strings, x = string number, y = z.

Sensors that do not sit on the wall (the 19 small PMTs on the dome of a multi-PMT
module) are first moved to the nearest point of their face: the wall face whose
inward normal is closest to the sensor's normal (so the PMTs of one module stay
together), or, without normals, the nearest face. All lengths are in metres; the
cylinder and box maps are isometric (a sensor keeps its true size), the sphere map
keeps areas, and ``SensorMap.jacobian`` gives the local distortion for each sensor.
The map is seen from outside: x grows with azimuth phi = atan2(y, x).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..geometry.detector import Detector
from ..geometry.shapes import Box, Cylinder, OpenMedium, Sphere

#: Mollweide constant 2 sqrt(2) / pi (x scale of the equal-area map).
MOLLWEIDE_X = 2.0 * math.sqrt(2.0) / math.pi
#: Faces of a box in the order of ``SensorMap.face`` indices.
BOX_FACES: tuple[str, ...] = ("+x", "+y", "-x", "-y", "+z", "-z")
CYLINDER_FACES: tuple[str, ...] = ("barrel", "top", "bottom")


@dataclasses.dataclass(frozen=True)
class Region:
    """One face of a flat wall map: a rectangle or an ellipse (discs are ellipses).

    Attributes:
        name: face name ("barrel", "top", "+x", "sphere", ...).
        kind: "rect" or "ellipse".
        centre: (x, y) map centre, m.
        half_width: half extent along x (rectangle) or semi-axis (ellipse), m.
        half_height: half extent along y, or semi-axis, m.
    """

    name: str
    kind: str
    centre: tuple[float, float]
    half_width: float
    half_height: float

    def contains(self, x, y, tolerance: float = 1e-9) -> np.ndarray:
        """Whether map points (x, y) in m lie inside the face (with a tolerance in m)."""
        u = np.asarray(x, dtype=np.float64) - self.centre[0]
        v = np.asarray(y, dtype=np.float64) - self.centre[1]
        a = self.half_width + tolerance
        b = self.half_height + tolerance
        if self.kind == "rect":
            return (np.abs(u) <= a) & (np.abs(v) <= b)
        return (u / a) ** 2 + (v / b) ** 2 <= 1.0

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the face, m."""
        cx, cy = self.centre
        return (cx - self.half_width, cx + self.half_width,
                cy - self.half_height, cy + self.half_height)


@dataclasses.dataclass(frozen=True)
class SensorMap:
    """2-D map coordinates of every sensor of a detector.

    Attributes:
        x, y: (N,) map coordinates, m (for an open medium x is the string number).
        face: (N,) index into ``regions`` (wall shapes) or the string number (open
            medium) of each sensor.
        jacobian: (N, 2, 2) derivative of the map coordinates with respect to
            distances along the wall (east/along-phi and north/along-z), m per m;
            the identity where the map is isometric.
        regions: the faces to draw (empty for an open medium).
        strings: (S, 2) horizontal string positions in m (open medium), else None.
        x_label, y_label: axis labels with units.
    """

    x: np.ndarray
    y: np.ndarray
    face: np.ndarray
    jacobian: np.ndarray
    regions: tuple[Region, ...]
    x_label: str
    y_label: str
    strings: np.ndarray | None = None

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) covering all regions and sensors, m."""
        boxes = [r.bounds for r in self.regions]
        if len(self.x):
            boxes.append((self.x.min(), self.x.max(), self.y.min(), self.y.max()))
        x0, x1, y0, y1 = zip(*boxes, strict=True)
        return float(min(x0)), float(max(x1)), float(min(y0)), float(max(y1))


def sensor_map(detector: Detector) -> SensorMap:
    """Map coordinates (m) of every sensor of ``detector``, by shape (see module doc)."""
    return wall_map(detector.shape, detector.sensor_positions, detector.sensor_normals)


def wall_map(shape, positions, normals=None) -> SensorMap:
    """Map coordinates (m) of points (M, 3) on or near the wall of ``shape``.

    ``normals`` (M, 3), where given, decide which face an off-wall point belongs to
    (as for the PMTs of a multi-PMT module); otherwise the nearest face is used.
    """
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    if isinstance(shape, Cylinder):
        return cylinder_map(shape, positions, normals)
    if isinstance(shape, Sphere):
        return sphere_map(shape, positions)
    if isinstance(shape, Box):
        return box_map(shape, positions, normals)
    if isinstance(shape, OpenMedium):
        return string_map(positions)
    raise TypeError(f"no flat map for shape {type(shape).__name__}")


def _identity(n: int) -> np.ndarray:
    return np.broadcast_to(np.eye(2), (n, 2, 2)).copy()


def _wall_map(x, y, face, regions, x_label, y_label, jacobian=None) -> SensorMap:
    return SensorMap(
        x=x, y=y, face=face.astype(np.int32),
        jacobian=_identity(len(x)) if jacobian is None else jacobian,
        regions=regions, x_label=x_label, y_label=y_label,
    )


def cylinder_regions(shape: Cylinder) -> tuple[Region, Region, Region]:
    """Barrel rectangle (2 pi R x H) and the top and bottom cap discs (radius R), m."""
    radius, half_height = shape.radius, 0.5 * shape.height
    cap_offset = half_height + radius
    return (
        Region("barrel", "rect", (0.0, 0.0), math.pi * radius, half_height),
        Region("top", "ellipse", (0.0, cap_offset), radius, radius),
        Region("bottom", "ellipse", (0.0, -cap_offset), radius, radius),
    )


def cylinder_map(shape: Cylinder, positions, normals=None) -> SensorMap:
    """Unrolled cylinder: barrel x = R * phi (phi in (-pi, pi]), y = z; caps folded out.

    A top-cap point (px, py) maps to (py, H/2 + R - px) and a bottom-cap point to
    (py, -H/2 - R + px): each cap is hinged on the barrel at phi = 0. Points off the
    wall go to the nearest point of their face (chosen by ``normals``, (N, 3) unit
    vectors, if given, else by distance). positions: (N, 3) m.
    """
    positions = np.asarray(positions, dtype=np.float64)
    px, py, pz = positions[:, 0], positions[:, 1], positions[:, 2]
    radius, half_height = shape.radius, 0.5 * shape.height
    rho = np.hypot(px, py)
    if normals is None:
        scores = np.stack([radius - rho, half_height - pz, half_height + pz])
        face = np.argmin(scores, axis=0)
    else:
        normals = np.asarray(normals, dtype=np.float64)
        outward = np.stack([px, py], axis=1) / np.where(rho > 0, rho, 1.0)[:, None]
        alignment = np.stack([
            -np.sum(normals[:, :2] * outward, axis=1), -normals[:, 2], normals[:, 2]
        ])
        face = np.argmax(alignment, axis=0)
    on_cap = face > 0
    top = face == 1
    # Barrel: the nearest barrel point has the same azimuth, z clipped to the barrel.
    phi = np.arctan2(py, px)
    barrel_x = radius * phi
    barrel_y = np.clip(pz, -half_height, half_height)
    # Caps: the nearest cap point keeps (x, y), pulled inside the cap's disc.
    shrink = np.minimum(1.0, radius / np.where(rho > 0, rho, 1.0))
    cx, cy = px * shrink, py * shrink
    cap_offset = half_height + radius
    x = np.where(on_cap, cy, barrel_x)
    y = np.where(top, cap_offset - cx, np.where(on_cap, -cap_offset + cx, barrel_y))
    return _wall_map(
        x, y, face, cylinder_regions(shape),
        "R $\\phi$ (m)", "z (m); caps folded out",
    )


def sphere_angles(positions) -> tuple[np.ndarray, np.ndarray]:
    """Longitude atan2(y, x) in (-pi, pi] and latitude asin(z / r) in [-pi/2, pi/2], rad."""
    positions = np.asarray(positions, dtype=np.float64)
    longitude = np.arctan2(positions[:, 1], positions[:, 0])
    latitude = np.arctan2(positions[:, 2], np.hypot(positions[:, 0], positions[:, 1]))
    return longitude, latitude


def mollweide_theta(latitude) -> np.ndarray:
    """Auxiliary angle theta (rad) of the Mollweide map: 2 theta + sin 2 theta = pi sin(lat).

    Newton's method from a start that is good everywhere (theta = lat at low latitude,
    the pole expansion pi/2 - theta = (3 pi eps^2 / 8)^(1/3), eps = pi/2 - |lat|, near
    the poles); converges to float64 precision in a few iterations.
    """
    latitude = np.asarray(latitude, dtype=np.float64)
    sign = np.where(latitude < 0, -1.0, 1.0)
    colat = 0.5 * math.pi - np.abs(latitude)
    polar = 0.5 * math.pi - np.cbrt(3.0 * math.pi * colat**2 / 8.0)
    theta = np.where(colat < 0.3, polar, np.abs(latitude))
    target = math.pi * np.sin(np.abs(latitude))
    for _ in range(30):
        residual = 2.0 * theta + np.sin(2.0 * theta) - target
        slope = np.maximum(4.0 * np.cos(theta) ** 2, 1e-300)
        theta = np.clip(theta - residual / slope, 0.0, 0.5 * math.pi)
    return sign * theta


def mollweide(longitude, latitude, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Mollweide map (m) of points at longitude, latitude (rad) of a sphere of radius (m).

    Equal-area: the map of the whole sphere is an ellipse of semi-axes 2 sqrt(2) R and
    sqrt(2) R, of area 4 pi R^2.
    """
    theta = mollweide_theta(latitude)
    x = MOLLWEIDE_X * radius * np.asarray(longitude, dtype=np.float64) * np.cos(theta)
    y = math.sqrt(2.0) * radius * np.sin(theta)
    return x, y


def sphere_region(shape: Sphere) -> Region:
    """The Mollweide ellipse of a sphere (semi-axes 2 sqrt(2) R and sqrt(2) R), m."""
    return Region("sphere", "ellipse", (0.0, 0.0), 2 * math.sqrt(2.0) * shape.radius,
                  math.sqrt(2.0) * shape.radius)


def sphere_map(shape: Sphere, positions) -> SensorMap:
    """Mollweide equal-area map of sensors on a sphere (positions (N, 3) in m).

    Points off the sphere are moved radially onto it. The Jacobian (per sensor) maps
    distances east and north on the sphere to map metres; its determinant is 1.
    """
    longitude, latitude = sphere_angles(positions)
    theta = mollweide_theta(latitude)
    x, y = mollweide(longitude, latitude, shape.radius)
    cos_lat = np.maximum(np.cos(latitude), 1e-12)
    cos_theta = np.maximum(np.cos(theta), 1e-12)
    dtheta_dlat = math.pi * cos_lat / (4.0 * cos_theta**2)
    jacobian = np.zeros((len(x), 2, 2))
    jacobian[:, 0, 0] = MOLLWEIDE_X * cos_theta / cos_lat
    jacobian[:, 0, 1] = -MOLLWEIDE_X * longitude * np.sin(theta) * dtheta_dlat
    jacobian[:, 1, 1] = math.sqrt(2.0) * cos_theta * dtheta_dlat
    return _wall_map(
        x, y, np.zeros(len(x)), (sphere_region(shape),),
        "Mollweide x (m, equal-area)", "Mollweide y (m)", jacobian,
    )


def box_regions(shape: Box) -> tuple[Region, ...]:
    """Rectangles (m) of the unfolded box in ``BOX_FACES`` order.

    Side faces in a row: -y | +x | +y | -x, the +x face centred on x = 0; +z above and
    -z below the +x face.
    """
    hx, hy, hz = shape.half_sizes
    return (
        Region("+x", "rect", (0.0, 0.0), hy, hz),
        Region("+y", "rect", (hy + hx, 0.0), hx, hz),
        Region("-x", "rect", (2 * hx + 2 * hy, 0.0), hy, hz),
        Region("-y", "rect", (-hy - hx, 0.0), hx, hz),
        Region("+z", "rect", (0.0, hz + hx), hy, hx),
        Region("-z", "rect", (0.0, -hz - hx), hy, hx),
    )


def box_map(shape: Box, positions, normals=None) -> SensorMap:
    """Unfolded box (a cross of six faces, see ``box_regions``), map coordinates in m.

    Each point goes to its face (the one whose inward normal is closest to the
    sensor's normal, (N, 3), if given, else the nearest face); coordinates along the
    face are clamped to it. positions: (N, 3) m.
    """
    positions = np.asarray(positions, dtype=np.float64)
    half = np.asarray(shape.half_sizes)
    rows = np.arange(len(positions))
    if normals is None:
        axis = np.argmin(half - np.abs(positions), axis=1)
        positive = positions[rows, axis] >= 0
    else:
        normals = np.asarray(normals, dtype=np.float64)
        axis = np.argmax(np.abs(normals), axis=1)
        positive = normals[rows, axis] < 0  # an inward normal -x looks from the +x face
    px, py, pz = (np.clip(positions[:, k], -half[k], half[k]) for k in range(3))
    hx, hy, hz = half
    # face index in BOX_FACES: axis 0 -> +x/-x (0/2), axis 1 -> +y/-y (1/3), axis 2 -> +z/-z
    face = np.select(
        [axis == 0, axis == 1], [np.where(positive, 0, 2), np.where(positive, 1, 3)],
        np.where(positive, 4, 5),
    )
    x = np.select(
        [face == 0, face == 1, face == 2, face == 3],
        [py, hy + (hx - px), hy + 2 * hx + (hy - py), -hy - (hx - px)],
        py,
    )
    y = np.select([face == 4, face == 5], [hz + (hx - px), -hz - (hx - px)], pz)
    return _wall_map(
        x, y, face, box_regions(shape),
        "unfolded wall (m)", "z (m); top and bottom folded out",
    )


def string_map(positions, tolerance: float = 1e-3) -> SensorMap:
    """Side view of sensors on vertical strings: x = string number, y = z (m).

    Strings are the distinct horizontal positions (within ``tolerance`` m), numbered
    by distance from the array's axis, then azimuth.
    """
    positions = np.asarray(positions, dtype=np.float64)
    keys = np.round(positions[:, :2] / tolerance).astype(np.int64)
    _, first, string = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    xy = positions[first, :2]
    order = np.lexsort((np.round(np.arctan2(xy[:, 1], xy[:, 0]), 6),
                        np.round(np.hypot(xy[:, 0], xy[:, 1]), 3)))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    number = rank[string.ravel()]
    return SensorMap(
        x=number.astype(np.float64), y=positions[:, 2].copy(), face=number.astype(np.int32),
        jacobian=_identity(len(positions)), regions=(), x_label="string",
        y_label="z (m)", strings=xy[order],
    )
