"""Pictures of a detector's sensor layout on a flat map of its wall (matplotlib, Agg).

``plot_detector`` draws every sensor as a disc of its true radius (m) on the map of
``projections.sensor_map``; optional per-sensor values colour the discs, which makes
the same function an event display. Figures are built without pyplot (no global
state, no display needed) and written by ``save_figure`` atomically.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import secrets
from pathlib import Path

import matplotlib as mpl
import numpy as np
from matplotlib.collections import EllipseCollection, LineCollection
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse, Rectangle

from ..errors import PhotonflowError
from ..geometry.detector import Detector
from .projections import Region, SensorMap, mollweide, sensor_map

#: Resolution of written pictures, dots per inch.
DPI = 150
WALL_COLOUR = "#ececec"
EDGE_COLOUR = "#555555"
#: Sensor colours by type index (when no values are given).
SENSOR_COLOURS = ("#1f4e8c", "#d1495b", "#edae49", "#00798c", "#66a182", "#8d96a3")
MISSING_COLOUR = "#bbbbbb"


def detector_title(detector: Detector) -> str:
    """Two-line title: name and shape, then sensor count, sensor models and coverage."""
    coverage = detector.coverage
    cov = "" if math.isnan(coverage) else f", {100 * coverage:.1f} % photocathode coverage"
    models = ", ".join(detector.sensor_models)
    return (
        f"{detector.name}: {detector.shape.describe()}\n"
        f"{detector.n_sensors:,} sensors ({models}){cov}"
    )


def plot_detector(
    detector: Detector,
    path: str | os.PathLike | None = None,
    *,
    values=None,
    title: str | None = None,
    label: str = "value",
    cmap: str = "viridis",
) -> Figure:
    """Draw the sensor layout of ``detector`` on a flat map of its wall.

    Cylinders are unrolled (barrel 2 pi R x H, caps as discs of radius R above and
    below), spheres drawn on a Mollweide equal-area map, boxes unfolded into a cross,
    open media as strings seen from above plus a side view (z versus string). Axes are
    in metres with equal aspect; sensors are discs of their true radius (m).

    Args:
        detector: the detector.
        path: if given, the picture is written there (format from the suffix,
            e.g. .png, .pdf, .svg; parent folders created) via ``save_figure``.
        values: optional (N,) per-sensor values (any unit) that colour the sensors,
            with a colour bar; NaN values are drawn grey.
        title: figure title (default: ``detector_title``).
        label: colour-bar label, with its unit (e.g. "charge (p.e.)").
        cmap: matplotlib colour map name for ``values``.

    Returns:
        The matplotlib ``Figure``. The sensor markers are the collection(s) with
        gid "sensors" (one marker per sensor).
    """
    if values is not None:
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        if values.shape != (detector.n_sensors,):
            raise PhotonflowError(
                f"values: shape {values.shape}, expected ({detector.n_sensors},) (one per sensor)"
            )
    projected = sensor_map(detector)
    if projected.strings is not None:
        figure = _plot_strings(detector, projected, values, label, cmap)
    else:
        figure = _plot_wall(detector, projected, values, label, cmap)
    figure.suptitle(detector_title(detector) if title is None else title)
    if path is not None:
        save_figure(figure, path)
    return figure


def _figure_size(width: float, height: float, extra_width: float) -> tuple[float, float]:
    """Figure size (inches) for a map of width x height (m), ~9 inches across."""
    aspect = height / width
    map_width = 9.0 if aspect < 1.2 else 9.0 * 1.2 / aspect
    return map_width + extra_width, min(max(map_width * aspect + 1.4, 4.0), 12.0)


def _colour_sensors(collection, detector: Detector, values, cmap: str) -> None:
    """Colour the sensor markers: by ``values`` through ``cmap`` (NaN grey), else by type."""
    if values is None:
        palette = np.array([to_rgba(c) for c in SENSOR_COLOURS])
        collection.set_facecolor(palette[np.asarray(detector.sensor_type) % len(palette)])
        return
    collection.set_array(np.ma.masked_invalid(values))
    collection.set_cmap(mpl.colormaps[cmap].with_extremes(bad=MISSING_COLOUR))


def _region_patch(region: Region):
    cx, cy = region.centre
    style = {"facecolor": WALL_COLOUR, "edgecolor": EDGE_COLOUR, "linewidth": 0.8, "zorder": 0}
    if region.kind == "rect":
        return Rectangle((cx - region.half_width, cy - region.half_height),
                         2 * region.half_width, 2 * region.half_height, **style)
    return Ellipse((cx, cy), 2 * region.half_width, 2 * region.half_height, **style)


def _disc_ellipses(projected: SensorMap, radius: np.ndarray):
    """Widths, heights (m) and angles (deg) of the map images of sensor discs."""
    u, s, _ = np.linalg.svd(projected.jacobian)
    widths = 2.0 * radius * s[:, 0]
    heights = 2.0 * radius * s[:, 1]
    angles = np.degrees(np.arctan2(u[:, 1, 0], u[:, 0, 0]))
    return widths, heights, angles


def _plot_wall(detector: Detector, projected: SensorMap, values, label: str, cmap: str) -> Figure:
    x0, x1, y0, y1 = projected.bounds
    extra = 1.4 if values is not None else 0.4
    figure = Figure(figsize=_figure_size(x1 - x0, y1 - y0, extra), layout="constrained")
    draw_wall(figure, figure.add_subplot(), detector, projected, values, label, cmap)
    return figure


def draw_wall(figure, ax, detector: Detector, projected: SensorMap, values, label: str,
              cmap: str = "viridis", norm=None):
    """Draw the wall map with every sensor (coloured by ``values`` if given) on ``ax``.

    Returns the sensor collection (gid "sensors"). ``norm`` is an optional matplotlib
    normalisation of ``values`` (e.g. ``LogNorm`` for charges).
    """
    x0, x1, y0, y1 = projected.bounds
    margin = 0.03 * max(x1 - x0, y1 - y0)
    for region in projected.regions:
        ax.add_patch(_region_patch(region))
    widths, heights, angles = _disc_ellipses(
        projected, np.asarray(detector.sensor_radius, dtype=np.float64)
    )
    offsets = np.column_stack([projected.x, projected.y])
    sensors = EllipseCollection(
        widths, heights, angles, units="xy", offsets=offsets,
        offset_transform=ax.transData, linewidths=0, zorder=2,
    )
    sensors.set_gid("sensors")
    _colour_sensors(sensors, detector, values, cmap)
    if norm is not None:
        sensors.set_norm(norm)
    ax.add_collection(sensors, autolim=False)
    if projected.regions and projected.regions[0].name == "sphere":
        _draw_graticule(ax, projected.regions[0].half_height / math.sqrt(2.0))
    else:
        _label_regions(ax, projected.regions)
    ax.set_xlim(x0 - margin, x1 + margin)
    ax.set_ylim(y0 - margin, y1 + 2 * margin)
    ax.set_aspect("equal")
    ax.set_xlabel(projected.x_label)
    ax.set_ylabel(projected.y_label)
    _legend_or_colourbar(figure, ax, sensors, detector, values, label)
    return sensors


def _label_regions(ax, regions: tuple[Region, ...]) -> None:
    """Name each face: discs to their right, rectangles above their top-left corner
    (inside it where another face lies there)."""
    style = {"textcoords": "offset points", "fontsize": 9, "color": EDGE_COLOUR}
    for region in regions:
        x0, x1, y0, y1 = region.bounds
        if region.kind == "ellipse":
            ax.annotate(region.name, (x1, region.centre[1]), xytext=(6, 0), ha="left",
                        va="center", **style)
            continue
        probe = 0.02 * (y1 - y0)
        blocked = any(other.contains(x0 + probe, y1 + probe) for other in regions
                      if other is not region)
        inside = {"bbox": {"boxstyle": "round,pad=0.15", "facecolor": "white", "alpha": 0.8,
                           "linewidth": 0}} if blocked else {}
        ax.annotate(region.name, (x0, y1), xytext=(3, -3 if blocked else 2), ha="left",
                    va="top" if blocked else "bottom", zorder=4, **style, **inside)


def _draw_graticule(ax, radius: float) -> None:
    """Meridians every 30 degrees and parallels every 30 degrees on a Mollweide map."""
    lines = []
    latitudes = np.radians(np.linspace(-90, 90, 181))
    for lon in range(-180, 181, 30):
        lines.append(np.column_stack(mollweide(np.full_like(latitudes, math.radians(lon)),
                                               latitudes, radius)))
    longitudes = np.radians(np.linspace(-180, 180, 361))
    for lat in range(-60, 61, 30):
        lines.append(np.column_stack(mollweide(longitudes, np.full_like(longitudes,
                                                                        math.radians(lat)),
                                               radius)))
    ax.add_collection(LineCollection(lines, colors="white", linewidths=0.6, alpha=0.8, zorder=3),
                      autolim=False)
    for lat in range(-60, 61, 30):
        x, y = mollweide(np.array([-math.pi]), np.array([math.radians(lat)]), radius)
        ax.annotate(f"{lat}°", (x[0], y[0]), xytext=(-3, 0), textcoords="offset points",
                    ha="right", va="center", fontsize=7, color=EDGE_COLOUR)
    for lon in range(-150, 151, 60):
        x, _ = mollweide(np.array([math.radians(lon)]), np.array([0.0]), radius)
        ax.annotate(f"{lon}°", (x[0], 0.0), xytext=(0, -2), textcoords="offset points",
                    ha="center", va="top", fontsize=7, color="white", zorder=4)


def _legend_or_colourbar(figure, ax, collection, detector, values, label) -> None:
    if values is not None:
        figure.colorbar(collection, ax=ax, label=label, shrink=0.8)
        return
    if len(detector.sensor_models) > 1:
        from matplotlib.lines import Line2D

        handles = [
            Line2D([], [], marker="o", linestyle="", color=SENSOR_COLOURS[k % len(SENSOR_COLOURS)],
                   label=model)
            for k, model in enumerate(detector.sensor_models)
        ]
        ax.legend(handles=handles, loc="upper right", fontsize=8)


def _plot_strings(detector: Detector, projected: SensorMap, values, label: str,
                  cmap: str) -> Figure:
    figure = Figure(figsize=(12.0 if values is not None else 11.0, 6.0), layout="constrained")
    top, side = figure.subplots(1, 2, width_ratios=[1.0, 1.3])
    strings = projected.strings
    top.scatter(strings[:, 0], strings[:, 1], s=30, color=SENSOR_COLOURS[0], zorder=2,
                gid="strings")
    for number, (x, y) in enumerate(strings):
        top.annotate(str(number), (x, y), xytext=(4, 4), textcoords="offset points", fontsize=8)
    span = max(float(np.ptp(strings[:, 0])), float(np.ptp(strings[:, 1])), 1.0)
    centre = strings.mean(axis=0)
    top.set_xlim(centre[0] - 0.65 * span, centre[0] + 0.65 * span)
    top.set_ylim(centre[1] - 0.65 * span, centre[1] + 0.65 * span)
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_title("strings seen from above", fontsize=10)
    top.grid(alpha=0.3)

    sensors = side.scatter(projected.x, projected.y, s=12, linewidths=0, zorder=2, gid="sensors")
    _colour_sensors(sensors, detector, values, cmap)
    side.set_xticks(np.arange(len(strings)))
    side.set_xlim(-0.7, len(strings) - 0.3)
    side.set_xlabel(projected.x_label)
    side.set_ylabel(projected.y_label)
    side.set_title("side view", fontsize=10)
    side.grid(axis="y", alpha=0.3)
    _legend_or_colourbar(figure, side, sensors, detector, values, label)
    return figure


#: Picture formats ``save_figure`` accepts (file suffix without the dot).
PICTURE_FORMATS = ("png", "pdf", "svg", "jpg", "jpeg", "eps", "ps", "webp", "tif", "tiff")


def check_picture_path(path: str | os.PathLike) -> str:
    """The picture format of ``path`` (its suffix); ``PhotonflowError`` if unsupported."""
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in PICTURE_FORMATS:
        found = f".{suffix}" if suffix else "(no suffix)"
        raise PhotonflowError(
            f"output = {str(path)!r}: unknown picture format {found};"
            f" use one of {', '.join('.' + f for f in PICTURE_FORMATS)}"
        )
    return "jpeg" if suffix == "jpg" else ("tiff" if suffix == "tif" else suffix)


def save_figure(figure: Figure, path: str | os.PathLike, dpi: int = DPI) -> Path:
    """Write ``figure`` to ``path`` atomically; returns the path.

    The picture is rendered in memory first, then written under a temporary name in
    the target folder (created if missing) and renamed, so a failure leaves nothing
    behind. The format comes from the suffix (``check_picture_path``).

    Raises:
        PhotonflowError: unsupported suffix, or the file cannot be written (one line).
    """
    path = Path(path)
    picture_format = check_picture_path(path)
    buffer = io.BytesIO()
    figure.savefig(buffer, format=picture_format, dpi=dpi)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(temporary, "xb") as stream:  # "x": never reuse a file; umask applies
            stream.write(buffer.getvalue())
        os.replace(temporary, path)
    except OSError as error:
        with contextlib.suppress(OSError):  # absent, or its folder is not one
            temporary.unlink()
        reason = error.strerror or str(error)
        raise PhotonflowError(f"output = {str(path)!r}: cannot write ({reason})") from None
    return path
