"""Pictures of a reconstruction against its truth (``photonflow evaluate --plots``): the
error distributions, the resolution versus energy, the pulls of the reported
uncertainties, and the e/mu log-likelihood ratio. Lengths cm, angles degrees, times
ns, energies MeV."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ..reconstruction.coordinates import LOCAL
from ..reconstruction.evaluation import event_errors, summarize
from .geometry_plot import save_figure

#: (error key, axis label) of the error-distribution panels.
ERROR_PANELS = (("vertex_cm", "vertex error (cm)"),
                ("longitudinal_cm", "along the track (cm)"),
                ("transverse_cm", "across the track (cm)"),
                ("direction_deg", "direction error (deg)"),
                ("energy_frac", "(E_fit - E_true) / E_true"),
                ("time_ns", "t_fit - t_true (ns)"))
#: (summary key, axis label, scale) of the resolution-versus-energy panels.
RESOLUTION_PANELS = (("vertex_68_cm", "vertex 68 % (cm)", 1.0),
                     ("direction_68_deg", "direction 68 % (deg)", 1.0),
                     ("energy_68_frac", "energy 68 % (%)", 100.0),
                     ("energy_bias_frac", "energy bias (%)", 100.0))


def plot_reconstruction(table, folder, summary: dict | None = None,
                        prefix: str = "") -> list[Path]:
    """Draw the pictures of a ``RecoTable`` into ``folder`` (created), each name after
    ``prefix``: errors.png, pulls.png, and where they apply resolution_vs_energy.png
    (several energies) and likelihood_ratio.png (a ``--particle auto`` job).
    ``summary``: the table's ``summarize`` if already made. Returns the paths written."""
    folder = Path(folder)
    errors = event_errors(table)
    particles = sorted(set(table.truth["particle"]))
    written = [_errors_figure(table, errors, particles, folder / f"{prefix}errors.png"),
               _pulls_figure(table, errors, particles, folder / f"{prefix}pulls.png")]
    summary = summarize(table) if summary is None else summary
    if any(entry["energy_bins"] for entry in summary["particles"].values()):
        written.append(_resolution_figure(
            summary, folder / f"{prefix}resolution_vs_energy.png"))
    ratio = table.reco["log_likelihood_ratio"]
    if np.any(np.isfinite(ratio)):
        written.append(_ratio_figure(table, particles,
                                     folder / f"{prefix}likelihood_ratio.png"))
    return written


def _rows(table, particle):
    return table.truth["particle"] == particle


def _errors_figure(table, errors, particles, path) -> Path:
    figure = Figure(figsize=(12, 6.5), layout="constrained")
    axes = figure.subplots(2, 3).ravel()
    for ax, (key, label) in zip(axes, ERROR_PANELS, strict=True):
        for particle in particles:
            values = errors[key][_rows(table, particle)]
            values = values[np.isfinite(values)]
            if values.size:
                ax.hist(values, bins=30, histtype="step", label=particle or "unknown")
                if key in ("vertex_cm", "transverse_cm", "direction_deg"):
                    ax.axvline(np.quantile(values, 0.68), ls=":", lw=1)
        ax.set_xlabel(label)
        ax.set_ylabel("events")
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(title="dotted: 68 %", fontsize=8)
    figure.suptitle(f"reconstruction errors ({table.run.get('method', '?')})")
    return save_figure(figure, path)


def _pulls_figure(table, errors, particles, path) -> Path:
    figure = Figure(figsize=(14, 6.5), layout="constrained")
    axes = figure.subplots(2, 4).ravel()
    grid = np.linspace(-4, 4, 200)
    for ax, name in zip(axes, LOCAL, strict=False):
        for particle in particles:
            values = errors[f"pull_{name}"][_rows(table, particle)]
            values = values[np.isfinite(values)]
            if values.size:
                ax.hist(np.clip(values, -4.99, 4.99), bins=20, range=(-5, 5), density=True,
                        histtype="step", label=particle or "unknown")
        ax.plot(grid, np.exp(-0.5 * grid**2) / np.sqrt(2 * np.pi), "k--", lw=1)
        ax.set_xlabel(f"pull of {name}")
    axes[-1].set_axis_off()
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(title="dashed: N(0, 1)", fontsize=8)
    figure.suptitle("pulls: error / reported uncertainty")
    return save_figure(figure, path)


def _resolution_figure(summary, path) -> Path:
    figure = Figure(figsize=(12, 3.6), layout="constrained")
    axes = figure.subplots(1, len(RESOLUTION_PANELS))
    for ax, (key, label, scale) in zip(axes, RESOLUTION_PANELS, strict=True):
        for particle, entry in summary["particles"].items():
            bins = [b for b in entry["energy_bins"] if b[key] is not None]
            if bins:
                energy = [0.5 * (b["energy_low_mev"] + b["energy_high_mev"]) for b in bins]
                ax.plot(energy, [scale * b[key] for b in bins], "o-", label=particle)
        ax.set_xlabel("true energy (MeV)")
        ax.set_ylabel(label)
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=8)
    return save_figure(figure, path)


def _ratio_figure(table, particles, path) -> Path:
    figure = Figure(figsize=(6, 4), layout="constrained")
    ax = figure.subplots()
    ratio = table.reco["log_likelihood_ratio"]
    finite = ratio[np.isfinite(ratio)]
    spread = finite.size > 1 and finite.max() > finite.min()
    bins = np.linspace(finite.min(), finite.max(), 30) if spread else 10
    for particle in particles:
        values = ratio[_rows(table, particle)]
        ax.hist(values[np.isfinite(values)], bins=bins, histtype="step",
                label=particle or "unknown")
    ax.axvline(0.0, color="k", lw=1)
    ax.set_xlabel("nll(mu-) - nll(e-)   (> 0: e-like)")
    ax.set_ylabel("events")
    ax.legend(title="true particle")
    return save_figure(figure, path)
