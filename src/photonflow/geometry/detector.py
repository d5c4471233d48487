"""The ``Detector``: an analytic boundary plus an array of disc-shaped photosensors.

Sensor arrays are pytree leaves (so a ``Detector`` can be passed through ``jit``);
the shape, name and sensor-model names are static configuration.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..errors import ConfigError, format_value
from ..pytree import pytree_dataclass, static_field
from .shapes import Shape

#: Sensor centres may lie this far (m) outside the boundary (disc centres sit on the wall).
BOUNDARY_TOLERANCE = 0.01
#: Sensors closer than this (m) to the wall count as wall-mounted (normal checked).
WALL_MOUNT_DISTANCE = 0.05
#: Allowed deviation of a sensor normal's length from 1.
NORMAL_TOLERANCE = 1e-3


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    array.setflags(write=False)
    return array


@pytree_dataclass
class Detector:
    """A detector: boundary ``shape`` and N photosensors (discs facing inward).

    Attributes:
        sensor_positions: (N, 3) disc centres, m.
        sensor_normals: (N, 3) unit normals pointing into the detector (the
            direction a sensor looks).
        sensor_radius: (N,) disc radii, m.
        sensor_type: (N,) integer index into ``sensor_models``.
        shape: the analytic boundary (static).
        name: preset or configuration name (static).
        sensor_models: photosensor model name of each type index (static), see
            ``photonflow.photosensors``.
    """

    sensor_positions: np.ndarray
    sensor_normals: np.ndarray
    sensor_radius: np.ndarray
    sensor_type: np.ndarray
    shape: Shape = static_field()
    name: str = static_field(default="custom")
    sensor_models: tuple[str, ...] = static_field(default=("R3600",))

    @property
    def n_sensors(self) -> int:
        """Number of sensors N."""
        return int(self.sensor_positions.shape[0])

    @property
    def photocathode_area(self) -> float:
        """Summed disc area of all sensors, m^2."""
        return float(np.sum(np.pi * np.asarray(self.sensor_radius, dtype=np.float64) ** 2))

    @property
    def coverage(self) -> float:
        """Photocathode coverage: summed disc area / wall area (nan for an open medium)."""
        return self.photocathode_area / self.shape.wall_area

    def describe(self) -> str:
        """One-line summary: name, shape, sensor count and coverage."""
        cov = "" if math.isnan(self.coverage) else f", {100 * self.coverage:.1f} % coverage"
        return f"{self.name}: {self.shape.describe()}, {self.n_sensors} sensors{cov}"

    def __repr__(self) -> str:
        return f"Detector({self.describe()})"


def make_detector(
    shape: Shape,
    positions,
    normals,
    radius,
    sensor_type=None,
    *,
    name: str = "custom",
    sensor_models: Sequence[str] = ("R3600",),
    source: str = "sensors",
) -> Detector:
    """Build and validate a ``Detector``.

    Args:
        shape: boundary.
        positions: (N, 3) sensor centres, m.
        normals: (N, 3) inward unit normals.
        radius: (N,) or scalar sensor disc radius, m.
        sensor_type: (N,) or scalar index into ``sensor_models`` (default 0).
        name: detector name.
        sensor_models: photosensor model names, one per type index.
        source: how errors refer to the sensor arrays (e.g. a file name).

    Raises:
        ConfigError: a one-line message naming the bad field, sensor index and value.
    """
    positions = np.asarray(positions, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ConfigError(f"{source}.positions: shape {positions.shape}, expected (N, 3)")
    n = positions.shape[0]
    if n == 0:
        raise ConfigError(f"{source}: no sensors")
    if normals.shape != positions.shape:
        raise ConfigError(f"{source}.normals: shape {normals.shape}, expected ({n}, 3)")
    radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), (n,)).copy()
    types = np.broadcast_to(np.asarray(0 if sensor_type is None else sensor_type), (n,)).astype(
        np.int32
    )

    for field_name, values in (("positions", positions), ("normals", normals), ("radius", radius)):
        bad = np.flatnonzero(~np.all(np.isfinite(values.reshape(n, -1)), axis=1))
        if bad.size:
            i = int(bad[0])
            raise ConfigError(
                f"{source}.{field_name}[{i}] = {format_value(values[i].tolist())}: not finite"
            )
    bad = np.flatnonzero(radius <= 0)
    if bad.size:
        i = int(bad[0])
        raise ConfigError(f"{source}.radius[{i}] = {format_value(float(radius[i]))}: must be > 0 m")
    lengths = np.linalg.norm(normals, axis=1)
    bad = np.flatnonzero(np.abs(lengths - 1) > NORMAL_TOLERANCE)
    if bad.size:
        i = int(bad[0])
        raise ConfigError(
            f"{source}.normals[{i}] = {format_value(normals[i].tolist())}: not a unit vector"
            f" (length {lengths[i]:.4g})"
        )
    normals = normals / lengths[:, None]
    bad = np.flatnonzero((types < 0) | (types >= len(sensor_models)))
    if bad.size:
        i = int(bad[0])
        raise ConfigError(
            f"{source}.type[{i}] = {int(types[i])}: must be in 0..{len(sensor_models) - 1}"
        )
    _check_placement(shape, positions, normals, source)
    return Detector(
        sensor_positions=_frozen(positions),
        sensor_normals=_frozen(normals),
        sensor_radius=_frozen(radius),
        sensor_type=_frozen(types),
        shape=shape,
        name=name,
        sensor_models=tuple(sensor_models),
    )


def _check_placement(shape: Shape, positions: np.ndarray, normals: np.ndarray,
                     source: str) -> None:
    """Raise ``ConfigError`` for a sensor outside ``shape`` or a wall-mounted sensor whose
    normal points out of the volume (positions m, normals unit)."""
    distance = np.asarray(shape.distance_to_wall(positions), dtype=np.float64)
    bad = np.flatnonzero(distance < -BOUNDARY_TOLERANCE)
    if bad.size:
        i = int(bad[0])
        raise ConfigError(
            f"{source}.positions[{i}] = {format_value(np.round(positions[i], 4).tolist())}:"
            f" outside the {shape.describe()} by {-distance[i]:.3g} m"
        )
    if shape.has_walls:
        # Sensors mounted on the wall must look into the volume; sensors held away from
        # the wall (e.g. the PMTs of a multi-PMT module's dome) may be tilted freely.
        wall_normal = np.asarray(shape.inward_normal(positions), dtype=np.float64)
        facing = np.sum(wall_normal * normals, axis=1)
        on_wall = distance < WALL_MOUNT_DISTANCE
        bad = np.flatnonzero(on_wall & (facing <= 0))
        if bad.size:
            i = int(bad[0])
            raise ConfigError(
                f"{source}.normals[{i}] = {format_value(np.round(normals[i], 4).tolist())}:"
                " points out of the detector (normals must point inward)"
            )
