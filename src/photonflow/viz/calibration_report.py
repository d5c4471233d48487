"""Calibration report: one picture of a ``CalibrationResult``.

Panels, top to bottom:

- convergence: -log L against iteration, and each dense free value (physical units)
  against iteration, with the true value as a dashed line when known and the final
  1-sigma band;
- fitted versus true (when the truth is known): (fitted - true) / true with its
  1-sigma error bar for every dense free entry, the pull written beside it;
- per-sensor fields (efficiency, time offset): a map of fitted - true (or the fitted
  value without a truth) on the detector's flat wall map, and the pull histogram.
"""

from __future__ import annotations

import math
import os

import numpy as np
from matplotlib.colors import TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ..errors import PhotonflowError
from ..geometry.detector import Detector
from ..params import SPECS
from .geometry_plot import draw_wall, save_figure
from .projections import sensor_map


def _label_value(params, label: str) -> float:
    """The physical value of a dense label ("absorption_length", "angular_acceptance[3]")."""
    name, _, index = label.partition("[")
    value = np.asarray(getattr(params, name), np.float64)
    return float(value[int(index.rstrip("]"))] if index else value)


def _unit(label: str) -> str:
    unit = SPECS[label.partition("[")[0]].unit
    return f" ({unit})" if unit else ""


def plot_calibration_report(
    result,
    detector: Detector | None = None,
    path: str | os.PathLike | None = None,
) -> Figure:
    """Draw a calibration result: convergence, fitted versus true, per-sensor maps.

    Args:
        result: a ``photonflow.calibration.CalibrationResult`` (e.g. ``.load(path)``).
        detector: the calibrated detector, needed only to map per-sensor fields
            (efficiency, time offset); without it those get a histogram only.
        path: if given, the picture is written there (format from the suffix) via
            ``save_figure``.

    Returns:
        The matplotlib ``Figure``.

    Raises:
        PhotonflowError: a detector whose sensor count differs from the result's (one
            line), or an unwritable ``path``.
    """
    n_sensors = result.detector.get("n_sensors")
    if detector is not None and n_sensors is not None and detector.n_sensors != n_sensors:
        raise PhotonflowError(
            f"detector: {detector.name} has {detector.n_sensors} sensors, the result"
            f" {result.detector.get('name')!r} has {n_sensors}"
        )
    labels = list(result.correlation_names)
    sensor_fields = [name for name in result.free if SPECS[name].per_sensor]
    truth = result.truth
    history = list(result.history)

    n_curves = 1 + len(labels)
    columns = min(4, n_curves + (1 if truth is not None and labels else 0))
    curve_rows = math.ceil((n_curves + (1 if truth is not None and labels else 0)) / columns)
    map_rows = len(sensor_fields)
    figure = Figure(figsize=(4.0 * columns + 1.0, 3.2 * curve_rows + 4.5 * map_rows + 0.8),
                    layout="constrained")
    parts = figure.subfigures(2 if map_rows else 1, 1, squeeze=False,
                              height_ratios=[3.2 * curve_rows, 4.5 * map_rows]
                              if map_rows else None)[:, 0]
    axes = parts[0].subplots(curve_rows, columns, squeeze=False).ravel()
    for ax in axes:
        ax.set_visible(False)
    for ax in axes[:n_curves]:  # iteration axes
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))

    _draw_convergence(axes, result, labels, history)

    if truth is not None and labels:
        ax = axes[n_curves]
        ax.set_visible(True)
        _draw_pulls(ax, result, labels)

    for row, name in enumerate(sensor_fields, start=1):
        _draw_sensor_field(parts[row], result, name, detector)

    status = "converged" if result.converged else "not converged"
    figure.suptitle(
        f"calibration of {result.detector.get('name', '?')}: {', '.join(result.free)}"
        f" ({result.method}, {result.likelihood}; {status}, -log L = {result.loss:.2f})"
    )
    if path is not None:
        save_figure(figure, path)
    return figure


def _draw_convergence(axes, result, labels: list[str], history: list[dict]) -> None:
    """-log L (minus its minimum) against iteration on ``axes[0]``, and each dense free
    value (physical units) with its final 1-sigma band and the truth on ``axes[1:]``."""
    truth = result.truth
    iterations = np.array([step["iteration"] for step in history], dtype=np.float64)
    losses = np.array([step["loss"] for step in history], dtype=np.float64)
    ax = axes[0]
    ax.set_visible(True)
    if losses.size:
        excess = losses - np.nanmin(losses)
        ax.plot(iterations, excess, marker="o", color="C0")
        if np.nanmax(excess) > 10.0:  # large first steps: keep the last ones visible
            ax.set_yscale("symlog", linthresh=1.0)
    _mark_stage(ax, history, label="independent-ray stage\n(roots, not minima)")
    ax.set_xlabel("iteration")
    ax.set_ylabel("-log L - minimum")
    ax.set_title("convergence", fontsize=10)

    for number, label in enumerate(labels, start=1):
        ax = axes[number]
        ax.set_visible(True)
        values = np.array([step["values"].get(label, np.nan) for step in history], np.float64)
        ax.plot(iterations, values, marker="o", color="C1", label="fit")
        _mark_stage(ax, history)
        fitted = _label_value(result.params, label)
        error = _label_value(result.errors, label)
        if iterations.size:
            ax.fill_between([iterations[0], iterations[-1]], fitted - error, fitted + error,
                            color="C1", alpha=0.2, linewidth=0, label="final $\\pm 1\\sigma$")
        if truth is not None:
            ax.axhline(_label_value(truth, label), color="k", linestyle="--", label="true")
        ax.set_xlabel("iteration")
        ax.set_ylabel(label + _unit(label))
        ax.set_title(label, fontsize=10)
        if number == 1:
            ax.legend(fontsize=8)


def _mark_stage(ax, history: list, label: str | None = None) -> None:
    """Shade the iterations of the independent-ray stage (entries with a ``"stage"``),
    where -log L is not minimised and may rise by design."""
    staged = [step["iteration"] for step in history if "stage" in step]
    if staged:
        ax.axvspan(min(staged) - 0.5, max(staged) + 0.5, color="0.85", alpha=0.5,
                   linewidth=0, zorder=0, gid="independent-ray stage")
        if label:
            ax.text(min(staged) - 0.4, 0.98, label, transform=ax.get_xaxis_transform(),
                    fontsize=7, va="top", color="0.3")


def _draw_pulls(ax, result, labels: list[str]) -> None:
    """(fitted - true) / true with 1-sigma error bars per dense label, pulls beside."""
    y = np.arange(len(labels))[::-1]
    true = np.array([_label_value(result.truth, label) for label in labels])
    fitted = np.array([_label_value(result.params, label) for label in labels])
    error = np.array([_label_value(result.errors, label) for label in labels])
    scale = np.where(true != 0, np.abs(true), 1.0)
    ax.errorbar((fitted - true) / scale, y, xerr=error / scale, fmt="o", color="C2",
                capsize=3)
    ax.axvline(0.0, color="k", linestyle="--", linewidth=1)
    for yk, f, t, e in zip(y, fitted, true, error, strict=True):
        pull = (f - t) / e if e > 0 else math.nan
        ax.annotate(f"pull {pull:+.2f}", (1.0, yk), xycoords=("axes fraction", "data"),
                    xytext=(-4, 6), textcoords="offset points", ha="right", fontsize=8)
    ax.set_yticks(y, labels, fontsize=8)
    ax.set_ylim(-0.7, len(labels) - 0.3)
    ax.set_xlabel("(fitted - true) / |true|")
    ax.set_title("fitted vs true ($\\pm 1\\sigma$)", fontsize=10)


def _draw_sensor_field(part, result, name: str, detector: Detector | None) -> None:
    """Map of fitted - true (or fitted) of a per-sensor field, and the pull histogram."""
    unit = SPECS[name].unit
    fitted = np.asarray(getattr(result.params, name), np.float64)
    error = np.asarray(getattr(result.errors, name), np.float64)
    if result.truth is not None:
        values = fitted - np.asarray(getattr(result.truth, name), np.float64)
        what = f"{name}: fitted - true"
    else:
        values, what = fitted, f"{name}: fitted"
    label = what + (f" ({unit})" if unit else "")
    if detector is not None:
        map_ax, hist_ax = part.subplots(1, 2, width_ratios=[3, 1])
        norm = None
        finite = values[np.isfinite(values)]
        if result.truth is not None and finite.size:
            limit = float(np.max(np.abs(finite))) or 1.0
            norm = TwoSlopeNorm(0.0, -limit, limit)
        draw_wall(part, map_ax, detector, sensor_map(detector), values, label,
                  "coolwarm" if norm is not None else "viridis", norm)
        map_ax.set_title(what, fontsize=10)
    else:
        hist_ax = part.subplots(1, 1)
    if result.truth is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            pulls = values / error
        pulls = pulls[np.isfinite(pulls)]
        hist_ax.hist(pulls, bins=30, color="C3")
        hist_ax.set_xlabel(f"{name} pull")
        if pulls.size:
            hist_ax.set_title(f"pulls: mean {pulls.mean():+.2f}, rms {pulls.std():.2f}",
                              fontsize=10)
    else:
        hist_ax.hist(fitted[np.isfinite(fitted)], bins=30, color="C3")
        hist_ax.set_xlabel(f"{name} fitted" + (f" ({unit})" if unit else ""))
    hist_ax.set_ylabel("sensors")
