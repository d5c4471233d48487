"""``Sensors``: a detector's sensor arrays and lookup grids as one pytree.

Every jitted function of the transport takes the detector's sensors in this one form:
centres, inward normals and disc radii as arrays of the computation's float dtype, and
the two lookup grids of a walled detector (``SensorGrid``): the one that finds the
sensor a ray hits and the one that lists the sensors near a point. ``sensors_for``
builds it once per detector object and dtype.
"""

from __future__ import annotations

from weakref import WeakKeyDictionary

import jax
import numpy as np

from ..generator.directions import perpendicular_basis
from ..numerics import default_float_dtype, strict_array
from ..pytree import pytree_dataclass
from .detector import Detector
from .sensor_grid import SensorGrid, build_sensor_grid

#: Sensors nearer than this many disc radii to a point are listed by the near-sensor
#: grid (``near_grid_for``): the expected mode computes their solid angle exactly.
NEAR_RADII = 4.0
#: The widest disc, in disc radii, over which the expected mode may average a sensor's
#: light (``specular_probes``): half a radius inside the near grid's reach.
WIDEST_DISC = NEAR_RADII - 0.5
#: How far (m) a disc's plane may leave the detector and still count as in front of its
#: own wall face (``face_reach_for``; the sag of SK's barrel under a tangent plane is
#: 1.7 cm at 0.75 m from the tangent point).
FACE_TOLERANCE = 0.05


@pytree_dataclass
class Sensors:
    """A detector's sensors as JAX arrays of one float dtype (a pytree: every jitted
    transport function takes it).

    Attributes:
        positions: (N, 3) disc centres, m.
        normals: (N, 3) inward unit normals.
        radius: (N,) disc radii, m.
        grid: the lookup grid of the sensor a ray hits (``build_sensor_grid``); None
            for an open medium (every sensor is tested).
        near_grid: the grid listing every sensor within ``NEAR_RADII`` radii of a
            point (``near_grid_for``); None for an open medium, or to use the far-field
            solid angle everywhere.
        face_reach: (N,) how far each disc's plane stays in front of its own wall face,
            in disc radii, between 1 and ``WIDEST_DISC`` (``face_reach_for``); None
            without a near grid.
        standoff: () the sensors' median distance in front of the wall, m, where it
            exceeds ``STANDOFF_MIN`` (IWCD's mPMTs: 0.19 m); None for discs on the
            wall (``specular_probes`` looks the discs up where a ray crosses their
            layer).
    """

    positions: jax.Array
    normals: jax.Array
    radius: jax.Array
    grid: SensorGrid | None = None
    near_grid: SensorGrid | None = None
    face_reach: jax.Array | None = None
    standoff: jax.Array | None = None

    @property
    def n(self) -> int:
        """Number of sensors N."""
        return int(self.positions.shape[0])


def sensors_for(
    detector: Detector, dtype=None, grid: SensorGrid | None = None, *, near: bool = True
) -> Sensors:
    """The ``Sensors`` of ``detector`` in ``dtype`` (default JAX's default float), with
    ``grid`` or the detector's own lookup grid (None for an open medium) and, when
    ``near``, its near-sensor grid (the sampled mode has no use for it). Built once per
    detector object, dtype and ``near`` (when ``grid`` is None), eagerly even inside a
    traced function."""
    dtype = default_float_dtype() if dtype is None else np.dtype(dtype)
    if grid is not None and grid is not _GRIDS.get(detector):  # a grid of the caller's own
        return _build(detector, dtype, grid, near)
    cached = _SENSORS.setdefault(detector, {})
    if (dtype, near) not in cached:
        cached[(dtype, near)] = _build(detector, dtype, None, near)
    return cached[(dtype, near)]


def _build(detector: Detector, dtype, grid: SensorGrid | None, near: bool) -> Sensors:
    """``sensors_for``, uncached."""
    with jax.ensure_compile_time_eval():
        if grid is None and detector.shape.has_walls:
            grid = sensor_grid_for(detector)
        return Sensors(
            positions=strict_array(detector.sensor_positions, dtype),
            normals=strict_array(detector.sensor_normals, dtype),
            radius=strict_array(detector.sensor_radius, dtype),
            grid=grid,
            near_grid=near_grid_for(detector) if near else None,
            face_reach=(strict_array(face_reach_for(detector), dtype)
                        if near and detector.shape.has_walls else None),
            standoff=_standoff(detector, dtype),
        )


#: Least median distance (m) of the sensors in front of the wall that ``Sensors``
#: records as their ``standoff``.
STANDOFF_MIN = 0.01


def _standoff(detector: Detector, dtype):
    """``Sensors.standoff`` of ``detector`` (numpy, once per build)."""
    if not detector.shape.has_walls:
        return None
    positions = np.asarray(detector.sensor_positions, np.float64)
    distance = float(np.median(detector.shape.distance_to_wall(positions)))
    return strict_array(distance, dtype) if distance > STANDOFF_MIN else None


def sensor_grid_for(detector: Detector) -> SensorGrid:
    """The sensor lookup grid of a walled detector, built once per detector object."""
    if detector not in _GRIDS:
        _GRIDS[detector] = build_sensor_grid(detector)
    return _GRIDS[detector]


def near_grid_for(detector: Detector) -> SensorGrid | None:
    """Grid listing, for any point, every sensor within ``NEAR_RADII`` radii of it (walled
    detectors; None for open media), built once per detector object."""
    if not detector.shape.has_walls:
        return None
    if detector not in _NEAR_GRIDS:
        largest = float(np.max(np.asarray(detector.sensor_radius)))
        _NEAR_GRIDS[detector] = build_sensor_grid(detector, margin=(NEAR_RADII - 1) * largest)
    return _NEAR_GRIDS[detector]


def face_reach_for(detector: Detector, steps: int = 9, azimuths: int = 16) -> np.ndarray:
    """(N,) the widest disc, in units of each sensor's radius (1 to ``WIDEST_DISC``),
    concentric with the sensor in its plane whose rim stays inside the walled detector
    within ``FACE_TOLERANCE``: the disc does not reach across an edge of its wall face
    (a cylinder's rim, a box's edge). Tested at ``steps`` widths x ``azimuths`` rim
    points (numpy, once per detector)."""
    positions = np.asarray(detector.sensor_positions, float)
    normals = np.asarray(detector.sensor_normals, float)
    radius = np.asarray(detector.sensor_radius, float) * np.ones(len(positions))
    u, v = perpendicular_basis(normals)  # numpy: no eager JAX programs at set-up
    angle = np.linspace(0.0, 2.0 * np.pi, azimuths, endpoint=False)
    rim = np.cos(angle)[:, None, None] * u + np.sin(angle)[:, None, None] * v  # (A, N, 3)
    reach = np.ones(len(positions))
    inside_so_far = np.ones(len(positions), bool)
    for width in np.linspace(1.0, WIDEST_DISC, steps):
        points = positions + width * radius[:, None] * rim
        inside = np.all(np.asarray(detector.shape.contains(points, FACE_TOLERANCE)), axis=0)
        inside_so_far &= inside
        reach = np.where(inside_so_far, width, reach)
    return reach


#: Memo of ``Sensors`` per detector object, keyed by (dtype, near) (a pure cache).
_SENSORS: WeakKeyDictionary = WeakKeyDictionary()
#: Memo of near-sensor grids per detector object (a pure cache).
_NEAR_GRIDS: WeakKeyDictionary = WeakKeyDictionary()
#: Memo of lookup grids per detector object (a pure cache; detectors are immutable).
_GRIDS: WeakKeyDictionary = WeakKeyDictionary()
