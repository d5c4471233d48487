"""Pictures: detector layouts on flat wall maps (later: event displays, diagnostics).

matplotlib is used through ``matplotlib.figure.Figure`` only (no pyplot, no display);
lengths on every map are in metres.
"""

from .geometry_plot import detector_title, plot_detector, save_figure
from .projections import Region, SensorMap, mollweide, sensor_map, sphere_angles

__all__ = [
    "Region",
    "SensorMap",
    "detector_title",
    "mollweide",
    "plot_detector",
    "save_figure",
    "sensor_map",
    "sphere_angles",
]
