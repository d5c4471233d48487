"""Predicted versus observed: one event beside the expected-mode prediction it is scored
against (``photonflow display FILE --predicted``).

Four panels: the observed charge and the predicted mean charge on the same logarithmic
colour scale (predicted p.e. x the single-p.e. mean charge, so both are in the event's
charge units), the per-sensor residual (observed - predicted) / sqrt(predicted + 1) on a
diverging scale, and the histogram of first-hit time residuals: the observed first-hit
time minus the predicted mean time of the light's earliest component (the direct light),
for sensors the prediction lights with >= 0.5 p.e. Charges in p.e., times in ns.
"""

from __future__ import annotations

import os

import numpy as np
from matplotlib.colors import LogNorm, TwoSlopeNorm
from matplotlib.figure import Figure

from ..geometry.detector import Detector
from ..io.events import Event
from .event_display import dense_hits
from .geometry_plot import detector_title, draw_wall, save_figure
from .projections import sensor_map

#: Sensors with at least this many predicted p.e. enter the time-residual histogram.
TIME_RESIDUAL_MINIMUM = 0.5


def plot_prediction(
    detector: Detector,
    event: Event,
    prediction,
    path: str | os.PathLike | None = None,
    *,
    spe_mean: float = 1.0,
    title: str | None = None,
) -> Figure:
    """Draw an event against its prediction (module docstring).

    Args:
        detector: the event's detector.
        event: the observed event (charges p.e., first-hit times ns).
        prediction: a ``Prediction`` for the same sensors (``expected``).
        path: if given, the picture is written there (format from the suffix).
        spe_mean: mean charge of one photoelectron (``response.spe.single_pe_moments``),
            by which the predicted p.e. are scaled.
        title: the figure's title (default: detector, hits and total charges).

    Returns:
        The matplotlib ``Figure``.
    """
    observed, first = dense_hits(event, detector.n_sensors)
    observed = np.nan_to_num(observed, nan=0.0)
    predicted_pe = np.asarray(prediction.charge, np.float64)
    predicted = predicted_pe * spe_mean
    weights = np.asarray(prediction.time_weight, np.float64)
    means = np.asarray(prediction.time_mean, np.float64)
    earliest = means[np.arange(len(means)), np.argmin(np.where(weights > 0, means, np.inf),
                                                      axis=1)]
    heading = title or (
        f"{detector_title(detector).splitlines()[0]}: {event.n_hits} hit sensors;"
        f" observed {observed.sum():.1f}, predicted {predicted.sum():.1f} (charge, p.e.)"
    )
    figure = Figure(figsize=(15.0, 11.0), layout="constrained")
    axes = figure.subplots(2, 2).ravel()
    projected = sensor_map(detector)
    positive = np.concatenate([observed[observed > 0], predicted[predicted > 1e-3]])
    norm = None
    if positive.size and positive.max() > positive.min():
        norm = LogNorm(vmin=max(positive.min(), 1e-2), vmax=positive.max())
    residual = (observed - predicted) / np.sqrt(predicted + 1.0)
    scale = max(float(np.max(np.abs(residual))), 1e-6)
    if projected.strings is None:
        draw_wall(figure, axes[0], detector, projected, np.where(observed > 0, observed, np.nan),
                  "observed charge (p.e.)", "viridis", norm)
        draw_wall(figure, axes[1], detector, projected, predicted, "predicted charge (p.e.)",
                  "viridis", norm)
        draw_wall(figure, axes[2], detector, projected, residual,
                  "(observed - predicted) / sqrt(predicted + 1)", "RdBu_r",
                  TwoSlopeNorm(vcenter=0.0, vmin=-scale, vmax=scale))
    else:  # an open medium: no wall map, observed against predicted per sensor
        _charge_scatter(axes[0], observed, predicted)
        for ax in axes[1:3]:
            ax.set_visible(False)
    axes[0].set_title("observed", fontsize=10)
    axes[1].set_title("predicted", fontsize=10)
    axes[2].set_title("residual", fontsize=10)
    _time_residuals(axes[3], first, earliest, predicted_pe)
    figure.suptitle(heading)
    if path is not None:
        save_figure(figure, path)
    return figure


def _charge_scatter(ax, observed, predicted) -> None:
    lit = (observed > 0) | (predicted > 1e-3)
    ax.loglog(np.maximum(predicted[lit], 1e-3), np.maximum(observed[lit], 1e-3), ".",
              markersize=3)
    top = max(float(np.max(predicted[lit], initial=1.0)), float(np.max(observed[lit],
                                                                         initial=1.0)))
    ax.plot([1e-3, top], [1e-3, top], "k--", linewidth=1)
    ax.set_xlabel("predicted charge (p.e.)")
    ax.set_ylabel("observed charge (p.e.)")


def _time_residuals(ax, first, earliest, predicted_pe) -> None:
    chosen = np.isfinite(first) & (predicted_pe >= TIME_RESIDUAL_MINIMUM)
    residual = first[chosen] - earliest[chosen]
    if residual.size:
        low, high = np.percentile(residual, [1.0, 99.0])
        ax.hist(residual, bins=80, range=(low - 1.0, high + 1.0), color="C0")
        ax.axvline(0.0, color="k", linestyle="--", linewidth=1)
    ax.set_xlabel("first-hit time - predicted direct time (ns)")
    ax.set_ylabel("sensors")
    ax.set_title(f"time residuals ({int(chosen.sum())} sensors with >= "
                 f"{TIME_RESIDUAL_MINIMUM:g} predicted p.e.)", fontsize=10)
