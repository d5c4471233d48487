"""Pictures: detector layouts and event displays on flat wall maps.

matplotlib is used through ``matplotlib.figure.Figure`` only (no pyplot, no display);
lengths on every map are in metres.
"""

from .event_display import dense_hits, plot_event, truth_wall_point
from .geometry_plot import detector_title, plot_detector, save_figure
from .projections import Region, SensorMap, mollweide, sensor_map, sphere_angles, wall_map

__all__ = [
    "Region",
    "SensorMap",
    "dense_hits",
    "detector_title",
    "mollweide",
    "plot_detector",
    "plot_event",
    "save_figure",
    "sensor_map",
    "sphere_angles",
    "truth_wall_point",
    "wall_map",
]
