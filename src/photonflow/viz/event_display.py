"""Event display: charge and first-hit time of every sensor on the flat wall map.

Unhit sensors are drawn grey; the source (truth) is marked where it projects onto the
wall: for a directed source (laser, track) the point where its axis leaves the
detector, otherwise the wall point radially outward from the detector centre.
"""

from __future__ import annotations

import math
import os

import numpy as np
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure

from ..geometry.detector import Detector
from ..io.events import Event
from .geometry_plot import detector_title, draw_wall, plot_detector, save_figure
from .projections import sensor_map, wall_map


def dense_hits(event: Event, n_sensors: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-sensor charge (p.e.) and time (ns) arrays of an event, NaN for unhit sensors."""
    charge = np.full(n_sensors, np.nan)
    time = np.full(n_sensors, np.nan)
    ids = np.asarray(event.sensor_ids, dtype=np.int64)
    charge[ids] = np.asarray(event.charge, dtype=np.float64)
    time[ids] = np.asarray(event.time, dtype=np.float64)
    return charge, time


def truth_wall_point(detector: Detector, event: Event) -> np.ndarray | None:
    """Where the event's source projects onto the wall (m), or None if it cannot."""
    truth = event.truth
    if truth is None or not detector.shape.has_walls:
        return None
    position = np.asarray(truth.position, dtype=np.float64)
    if not np.all(np.isfinite(position)):
        return None
    direction = np.asarray(truth.direction, dtype=np.float64)
    if not np.all(np.isfinite(direction)) or np.linalg.norm(direction) == 0:
        norm = np.linalg.norm(position)
        if norm < 1e-6:
            return None
        direction = position / norm
    direction = direction / np.linalg.norm(direction)
    distance = float(detector.shape.ray_exit(position, direction))
    return position + distance * direction


def _truth_text(event: Event) -> str:
    truth = event.truth
    if truth is None:
        return ""
    kind = truth.particle or truth.source_kind or "source"
    position = np.asarray(truth.position, dtype=np.float64)
    where = (
        f" at ({position[0]:.2f}, {position[1]:.2f}, {position[2]:.2f}) m"
        if np.all(np.isfinite(position))
        else ""
    )
    energy = f", {truth.energy:.4g} MeV" if math.isfinite(float(truth.energy)) else ""
    return f"truth: {kind}{where}{energy}"


def plot_event(
    detector: Detector,
    event: Event,
    path: str | os.PathLike | None = None,
    *,
    title: str | None = None,
) -> Figure:
    """Draw an event: charge (p.e., log scale) and first-hit time (ns) of every sensor.

    Two maps side by side (one per quantity) for walled detectors; for an open medium
    the charge is shown on the string side view. The truth source, if stored, is marked
    with a star. Writes the picture to ``path`` if given (format from its suffix).
    """
    charge, time = dense_hits(event, detector.n_sensors)
    heading = title or (
        f"{detector_title(detector).splitlines()[0]}: {event.n_hits} hit sensors,"
        f" {np.nansum(charge):.1f} p.e.\n{_truth_text(event)}"
    )
    projected = sensor_map(detector)
    if projected.strings is not None:
        figure = plot_detector(detector, values=charge, title=heading, label="charge (p.e.)")
    else:
        x0, x1, y0, y1 = projected.bounds
        wide = (x1 - x0) > 1.3 * (y1 - y0)
        size = (11.0, 11.0) if wide else (15.0, 7.5)
        figure = Figure(figsize=size, layout="constrained")
        axes = figure.subplots(2, 1) if wide else figure.subplots(1, 2)
        positive = charge[np.isfinite(charge) & (charge > 0)]
        norm = None
        if positive.size and positive.max() > positive.min():
            norm = LogNorm(vmin=max(positive.min(), 1e-2), vmax=positive.max())
        draw_wall(figure, axes[0], detector, projected, charge, "charge (p.e.)", "viridis", norm)
        # Dark-noise hits spread over the whole readout window: colour times by their
        # 2nd-98th percentile range so that the light's arrival pattern stays visible.
        finite = time[np.isfinite(time)]
        time_norm = None
        if finite.size > 1:
            low, high = np.percentile(finite, [2.0, 98.0])
            if high > low:
                time_norm = Normalize(vmin=low, vmax=high)
        draw_wall(figure, axes[1], detector, projected, time, "first-hit time (ns)", "plasma",
                  time_norm)
        axes[0].set_title("charge", fontsize=10)
        axes[1].set_title("time", fontsize=10)
        point = truth_wall_point(detector, event)
        if point is not None:
            marker = wall_map(detector.shape, point[None])
            for ax in axes:
                ax.plot(marker.x, marker.y, marker="*", markersize=16, color="red",
                        markeredgecolor="white", zorder=5, linestyle="", gid="truth")
        figure.suptitle(heading)
    if path is not None:
        save_figure(figure, path)
    return figure
