"""Sensor layout generators (numpy, float64; positions in m, unit inward normals).

Each generator returns ``(positions (N, 3), normals (N, 3))``. Generators with a
count argument reproduce a detector's published sensor count exactly; the
``*_for_spacing`` / ``*_for_coverage`` front ends derive the counts from a sensor
pitch or a photocathode coverage and call the same core.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError, format_value

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))  # rad


def _grid_points(spacing: float, limit: float, grid: str) -> np.ndarray:
    """2-D square or hexagonal lattice points with the given pitch within |p| <= limit."""
    n = int(math.ceil(limit / spacing)) + 2
    i, j = np.meshgrid(np.arange(-n, n + 1), np.arange(-n, n + 1), indexing="ij")
    if grid == "square":
        x, y = i * spacing, j * spacing
    elif grid == "hex":
        x = (i + 0.5 * (j % 2)) * spacing
        y = j * spacing * math.sqrt(3.0) / 2.0
    else:
        raise ConfigError(f"layout.cap_grid = {format_value(grid)}: must be 'square' or 'hex'")
    points = np.stack([x.ravel(), y.ravel()], axis=1).astype(np.float64)
    return points[np.hypot(points[:, 0], points[:, 1]) <= limit + 1e-9]


def disc_grid(count: int, limit: float, grid: str = "square") -> np.ndarray:
    """``count`` lattice points filling a disc of radius ``limit`` (m) as evenly as possible.

    The pitch starts at the value that would place ``count`` points on the disc area
    and shrinks until enough points fit; the ``count`` points nearest to the centre are
    kept (ties broken by azimuth, so the result is deterministic). Returns (count, 2) m.
    """
    if count <= 0:
        return np.zeros((0, 2))
    cell = 1.0 if grid == "square" else math.sqrt(3.0) / 2.0
    spacing = math.sqrt(math.pi * limit**2 / (count * cell))
    for _ in range(10_000):
        points = _grid_points(spacing, limit, grid)
        if len(points) >= count:
            break
        spacing *= 0.999
    radius = np.round(np.hypot(points[:, 0], points[:, 1]), 9)
    azimuth = np.round(np.arctan2(points[:, 1], points[:, 0]), 9)
    order = np.lexsort((azimuth, radius))
    return points[order[:count]]


def barrel_caps_layout(
    radius: float,
    height: float,
    rings: int,
    columns: int,
    cap_count: int,
    *,
    cap_grid: str = "square",
    cap_margin: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Sensors on an upright cylinder: a barrel of ``rings`` x ``columns`` plus two caps.

    Barrel sensors sit at the centres of a rings x columns grid of the barrel wall;
    each cap holds ``cap_count`` sensors on a square or hexagonal grid inside radius
    ``radius - cap_margin``. Lengths in m. Returns positions and inward normals (N, 3).
    """
    z = -0.5 * height + (np.arange(rings) + 0.5) * height / rings
    phi = (np.arange(columns) + 0.5) * 2 * math.pi / columns
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    zz, pp = zz.ravel(), pp.ravel()
    barrel = np.stack([radius * np.cos(pp), radius * np.sin(pp), zz], axis=1)
    barrel_normals = np.stack([-np.cos(pp), -np.sin(pp), np.zeros_like(pp)], axis=1)
    cap_xy = disc_grid(cap_count, radius - cap_margin, cap_grid)
    ones = np.ones(len(cap_xy))
    top = np.column_stack([cap_xy, 0.5 * height * ones])
    bottom = np.column_stack([cap_xy, -0.5 * height * ones])
    down = np.tile([0.0, 0.0, -1.0], (len(cap_xy), 1))
    positions = np.concatenate([barrel, top, bottom])
    normals = np.concatenate([barrel_normals, down, -down])
    return positions, normals


def barrel_caps_layout_for_spacing(
    radius: float, height: float, spacing: float, sensor_radius: float, *, cap_grid: str = "square"
) -> tuple[np.ndarray, np.ndarray]:
    """Cylinder layout with a given sensor pitch (m) on barrel and caps.

    The cap count is the number of pitch cells on the cap area, placed within
    ``radius - sensor_radius`` so that no disc reaches past the cap's rim.
    """
    if not spacing > 2 * sensor_radius:
        raise ConfigError(
            f"layout.spacing = {format_value(spacing)}: must exceed the sensor diameter"
            f" {2 * sensor_radius:.4g} m"
        )
    rings = max(1, round(height / spacing))
    columns = max(1, round(2 * math.pi * radius / spacing))
    cell = spacing**2 if cap_grid == "square" else spacing**2 * math.sqrt(3.0) / 2.0
    cap_count = round(math.pi * radius**2 / cell)
    return barrel_caps_layout(
        radius, height, rings, columns, cap_count, cap_grid=cap_grid, cap_margin=sensor_radius
    )


def barrel_caps_layout_for_coverage(
    radius: float, height: float, coverage: float, sensor_radius: float, *, cap_grid: str = "square"
) -> tuple[np.ndarray, np.ndarray]:
    """Cylinder layout giving a photocathode coverage (fraction of wall area in discs)."""
    if not 0 < coverage < 0.9:
        raise ConfigError(f"layout.coverage = {format_value(coverage)}: must be in (0, 0.9)")
    cell = math.pi * sensor_radius**2 / coverage  # wall area per sensor, m^2
    rings = max(1, round(height / math.sqrt(cell)))
    columns = max(1, round(2 * math.pi * radius * height / (rings * cell)))
    cap_count = round(math.pi * radius**2 / cell)
    return barrel_caps_layout(
        radius, height, rings, columns, cap_count, cap_grid=cap_grid, cap_margin=sensor_radius
    )


def fibonacci_sphere_layout(radius: float, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` sensors on a sphere of ``radius`` (m) on a Fibonacci (golden-angle) lattice.

    Nearly uniform, but its nearest-neighbour distance is only ~0.88 of the ideal
    hexagonal pitch, so discs touch above ~70 % coverage: use
    ``latitude_rings_sphere_layout`` for denser arrays. Returns positions (m) and
    inward normals.
    """
    k = np.arange(count, dtype=np.float64)
    z = 1.0 - (2.0 * k + 1.0) / count
    rho = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))
    phi = k * GOLDEN_ANGLE
    unit = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    return radius * unit, -unit


def fibonacci_sphere_layout_for_coverage(
    radius: float, coverage: float, sensor_radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Fibonacci sphere layout with the count that gives a photocathode coverage."""
    count = round(coverage * 4 * math.pi * radius**2 / (math.pi * sensor_radius**2))
    if coverage > 0.6:
        return latitude_rings_sphere_layout(radius, count, min_pitch=2 * sensor_radius)
    return fibonacci_sphere_layout(radius, count)


def _ring_counts(radius: float, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """Polar angles (rad) and sensor counts of latitude rings with chord pitch >= ``pitch``."""
    ring_step = 2.0 * math.asin(min(1.0, pitch / (2.0 * radius)))
    n_rings = max(1, int(math.floor(math.pi / ring_step)))
    theta = (np.arange(n_rings) + 0.5) * math.pi / n_rings
    ring_radius = radius * np.sin(theta)
    half_angle = np.arcsin(np.minimum(1.0, pitch / (2.0 * ring_radius)))
    counts = np.maximum(1, np.floor(math.pi / half_angle + 1e-9)).astype(int)
    return theta, counts


def latitude_rings_sphere_layout(
    radius: float, count: int, *, min_pitch: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` sensors on a sphere of ``radius`` (m) in rings of constant latitude.

    Rings are spaced by, and sensors within a ring separated by, at least the largest
    chord pitch that still fits ``count`` sensors (found by bisection); surplus sensors
    are removed one per ring from the fullest rings. Any two sensors are then at least
    that pitch apart (the rings are also at least the pitch apart), so discs of
    diameter <= pitch never overlap: up to ~78 % coverage (square packing, pi/4),
    where a Fibonacci lattice's discs already touch above ~70 %. This is also how
    large spherical detectors such as JUNO mount their PMTs. Returns positions (m)
    and inward normals.
    """
    low, high = 1e-6 * radius, 2.0 * radius
    for _ in range(200):
        middle = 0.5 * (low + high)
        if _ring_counts(radius, middle)[1].sum() >= count:
            low = middle
        else:
            high = middle
    pitch = low
    if min_pitch is not None and pitch < min_pitch:
        raise ConfigError(
            f"layout.count = {count}: sensors {min_pitch:.4g} m apart do not fit on a"
            f" sphere of radius {radius:.4g} m in latitude rings (pitch {pitch:.4g} m)"
        )
    theta, counts = _ring_counts(radius, pitch)
    surplus = int(counts.sum() - count)
    while surplus > 0:
        fullest = np.argsort(-counts, kind="stable")[:surplus]
        counts[fullest] -= 1
        surplus = int(counts.sum() - count)
    units = []
    for ring, (polar, n) in enumerate(zip(theta, counts, strict=True)):
        phi = (np.arange(n) + 0.5) * 2 * math.pi / n + ring * GOLDEN_ANGLE
        units.append(
            np.stack(
                [
                    np.sin(polar) * np.cos(phi),
                    np.sin(polar) * np.sin(phi),
                    np.full(n, np.cos(polar)),
                ],
                axis=1,
            )
        )
    unit = np.concatenate(units)
    return radius * unit, -unit


def box_grid_layout(
    size_x: float, size_y: float, size_z: float, spacing: float
) -> tuple[np.ndarray, np.ndarray]:
    """Sensors on the six faces of a centred box, each face a grid with pitch ``spacing`` (m)."""
    half = np.array([size_x, size_y, size_z]) / 2.0
    positions, normals = [], []
    for axis in range(3):
        u_axis, v_axis = [a for a in range(3) if a != axis]
        nu = max(1, round(2 * half[u_axis] / spacing))
        nv = max(1, round(2 * half[v_axis] / spacing))
        u = -half[u_axis] + (np.arange(nu) + 0.5) * 2 * half[u_axis] / nu
        v = -half[v_axis] + (np.arange(nv) + 0.5) * 2 * half[v_axis] / nv
        uu, vv = (a.ravel() for a in np.meshgrid(u, v, indexing="ij"))
        for side in (-1.0, 1.0):
            face = np.zeros((uu.size, 3))
            face[:, u_axis], face[:, v_axis] = uu, vv
            face[:, axis] = side * half[axis]
            normal = np.zeros((uu.size, 3))
            normal[:, axis] = -side
            positions.append(face)
            normals.append(normal)
    return np.concatenate(positions), np.concatenate(normals)


def string_positions(count: int, spacing: float) -> np.ndarray:
    """(count, 2) horizontal positions (m) of strings on a triangular lattice with the
    given spacing, the ``count`` nodes nearest to the centre (7 = centre + hexagon)."""
    limit = spacing * (math.sqrt(count) + 2)
    points = _grid_points(spacing, limit, "hex")
    radius = np.round(np.hypot(points[:, 0], points[:, 1]), 9)
    azimuth = np.round(np.arctan2(points[:, 1], points[:, 0]), 9)
    return points[np.lexsort((azimuth, radius))[:count]]


def string_layout(
    strings: int,
    string_spacing: float,
    sensors_per_string: int,
    sensor_spacing: float,
    *,
    facing: tuple[float, float, float] = (0.0, 0.0, -1.0),
) -> tuple[np.ndarray, np.ndarray]:
    """Sensors hung on vertical strings (IceCube/KM3NeT-like), centred on z = 0.

    ``strings`` strings on a triangular lattice of pitch ``string_spacing`` (m), each
    with ``sensors_per_string`` sensors ``sensor_spacing`` apart (m), all looking along
    ``facing`` (default down, as IceCube's PMTs).
    """
    xy = string_positions(strings, string_spacing)
    z = (0.5 * (sensors_per_string - 1) - np.arange(sensors_per_string)) * sensor_spacing
    positions = np.array([[x, y, zk] for x, y in xy for zk in z], dtype=np.float64)
    direction = np.asarray(facing, dtype=np.float64)
    direction = direction / np.linalg.norm(direction)
    return positions, np.tile(direction, (len(positions), 1))


def _orthonormal_frame(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to each normal (and to each other)."""
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(normals, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(normals, e1)
    return e1, e2


#: Polar tilts (rad) and counts of the 1 + 6 + 12 arrangement of a 19-PMT module.
#: The real mPMT tilt angles are not in the reference sheet; 20 and 40 degrees keep
#: neighbouring 3-inch discs apart on a 0.254 m dome (assumed geometry).
MPMT_RINGS: tuple[tuple[float, int], ...] = (
    (0.0, 1),
    (math.radians(20.0), 6),
    (math.radians(40.0), 12),
)


def expand_modules(
    module_positions: np.ndarray,
    module_normals: np.ndarray,
    dome_radius: float,
    rings: tuple[tuple[float, int], ...] = MPMT_RINGS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Replace each multi-PMT module by its small PMTs on a dome.

    A module at wall point p with inward normal n holds PMTs at p + dome_radius * u,
    u tilted from n by each ring's polar angle, facing along u. Returns PMT positions
    (M, 3) m, normals (M, 3) and the module index of each PMT (M,).
    """
    module_positions = np.asarray(module_positions, dtype=np.float64)
    module_normals = np.asarray(module_normals, dtype=np.float64)
    e1, e2 = _orthonormal_frame(module_normals)
    directions = []
    for tilt, count in rings:
        for k in range(count):
            phi = 2 * math.pi * k / count
            directions.append(
                (math.cos(tilt), math.sin(tilt) * math.cos(phi), math.sin(tilt) * math.sin(phi))
            )
    local = np.asarray(directions)  # (19, 3) in (n, e1, e2)
    u = (
        local[None, :, 0:1] * module_normals[:, None, :]
        + local[None, :, 1:2] * e1[:, None, :]
        + local[None, :, 2:3] * e2[:, None, :]
    )
    positions = module_positions[:, None, :] + dome_radius * u
    module = np.repeat(np.arange(len(module_positions)), len(local))
    return positions.reshape(-1, 3), u.reshape(-1, 3), module
