"""Detector geometry: boundaries, sensor layouts, presets and ray intersections."""

from .detector import Detector, make_detector
from .intersect import detector_ray_hits, disc_hit_distance, ray_boundary, ray_sensor_hits
from .presets import PRESETS, preset_detector, preset_table
from .sensor_arrays import Sensors, sensors_for
from .shapes import Box, Cylinder, OpenMedium, Shape, Sphere, shape_from_dict, shape_to_dict

__all__ = [
    "PRESETS",
    "Box",
    "Cylinder",
    "Detector",
    "OpenMedium",
    "Sensors",
    "Shape",
    "Sphere",
    "detector_ray_hits",
    "disc_hit_distance",
    "make_detector",
    "preset_detector",
    "preset_table",
    "ray_boundary",
    "ray_sensor_hits",
    "sensors_for",
    "shape_from_dict",
    "shape_to_dict",
]
