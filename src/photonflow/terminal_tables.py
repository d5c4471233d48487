"""Tables for the terminal (rich): the detector presets and a calibration result, for
the command line and the demo."""

from __future__ import annotations

import math

import numpy as np
from rich.table import Table

from .geometry.presets import preset_table


def preset_rich_table() -> Table:
    """The detector presets as a rich table (name, shape, dimensions, sensors, coverage %,
    sensor model, medium, source of the published figures), from
    ``photonflow.geometry.preset_table``."""
    table = Table(title="photonflow detector presets", title_justify="left")
    table.add_column("name", style="bold", no_wrap=True)
    table.add_column("shape", no_wrap=True)
    table.add_column("dimensions", min_width=20)
    table.add_column("sensors", justify="right", no_wrap=True)
    table.add_column("coverage %", justify="right", no_wrap=True)
    table.add_column("sensor model", overflow="fold")
    table.add_column("medium", overflow="fold")
    table.add_column("source", overflow="fold")
    for row in preset_table():
        coverage = row["coverage"]
        table.add_row(
            str(row["name"]),
            str(row["shape"]),
            str(row["dimensions"]),
            str(row["sensors"]),
            "-" if math.isnan(coverage) else f"{100 * coverage:.1f}",
            str(row["sensor_model"]),
            str(row["medium"]),
            str(row["source"]),
        )
    return table


def calibration_rich_table(result) -> Table:
    """The fit of a ``CalibrationResult`` as a rich table: parameter, fitted, 1-sigma
    error, true value and pull (fitted - true) / error when the truth is known; a
    per-sensor field is one row of its mean and spread over the sensors."""
    from .params import SPECS

    truth = result.truth
    with np.errstate(divide="ignore", invalid="ignore"):
        pulls = result.pulls() if truth is not None else {}
    status = "" if result.converged or result.message.startswith("not converged") else (
        "not converged: ")
    table = Table(title=f"calibration ({result.method}, {result.likelihood} likelihood):"
                        f" {status}{result.message}", title_justify="left")
    for title in ("parameter", "fitted", "error", "true", "pull"):
        table.add_column(title, justify="left" if title == "parameter" else "right")
    for name in result.free:
        spec = SPECS[name]
        unit = f" ({spec.unit})" if spec.unit else ""
        fitted = np.atleast_1d(np.asarray(getattr(result.params, name), np.float64))
        error = np.atleast_1d(np.asarray(getattr(result.errors, name), np.float64))
        true = (np.atleast_1d(np.asarray(getattr(truth, name), np.float64))
                if truth is not None else None)
        pull = np.atleast_1d(pulls[name]) if name in pulls else None
        if spec.per_sensor:
            table.add_row(
                f"{name}{unit}, {fitted.size} sensors",
                f"mean {fitted.mean():.4g} rms {fitted.std():.3g}",
                f"median {np.median(error):.3g}",
                "-" if true is None else f"mean {true.mean():.4g} rms {true.std():.3g}",
                "-" if pull is None else f"mean {np.nanmean(pull):+.2f} rms {np.nanstd(pull):.2f}",
            )
            continue
        for k in range(fitted.size):
            label = f"{name}[{k}]" if spec.size else name
            table.add_row(
                label + unit, f"{fitted[k]:.5g}",
                f"{error[k]:.3g}" if np.isfinite(error[k]) else f"{error[k]} (no measurement)",
                "-" if true is None else f"{true[k]:.5g}",
                "-" if pull is None else f"{pull[k]:+.2f}",
            )
    return table
