"""``photonflow tables``: emission tables of the particle generator, and the SIREN
emission model trained on them."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from ..cli_errors import check_output_file
from .root import console, guarded

tables_app = typer.Typer(help="Emission tables of the particle generator.",
                         no_args_is_help=True)


@tables_app.command("build")
@guarded
def tables_build(
    particle: Annotated[str, typer.Option(help="mu-, mu+, e-, e+ or gamma.")],
    out: Annotated[Path, typer.Option(help="HDF5 file to write (resumed if it exists).")],
    energies: Annotated[
        str | None, typer.Option(help="Comma-separated kinetic energies, MeV.")
    ] = None,
    per_energy: Annotated[int, typer.Option(help="Particles per energy.")] = 20,
    seed: Annotated[int, typer.Option(help="Seed of the whole table.")] = 0,
    medium: Annotated[str, typer.Option(help="water or scintillator.")] = "water",
    yield_scale: Annotated[
        float, typer.Option(help="Photon yield scale while building (counts are rescaled).")
    ] = 1.0,
    target_error: Annotated[
        float | None,
        typer.Option(help="Add batches of --per-energy particles until the yield's relative"
                          " statistical error is below this (e.g. 0.002)."),
    ] = None,
    max_per_energy: Annotated[
        int | None, typer.Option(help="Most particles per energy with --target-error.")
    ] = None,
) -> None:
    """Build an emission table (photons per particle by distance, angle and time offset
    along the initial direction) for an energy grid; resumes an interrupted build."""
    from ..errors import ConfigError
    from ..generator import GeneratorSettings
    from ..generator.emission_tables import DEFAULT_ENERGIES, build_table
    from ..interrupts import terminate_as_interrupt

    grid = DEFAULT_ENERGIES if energies is None else _parse_floats(energies, "--energies")
    check_output_file(out, "--out")
    try:
        with terminate_as_interrupt() as interrupts:
            table = build_table(
                particle, grid, per_energy, seed=seed, medium=medium,
                settings=GeneratorSettings(yield_scale=yield_scale), resume=out,
                progress=True, target_error=target_error, max_per_energy=max_per_energy,
                check=interrupts.check,
            )
    except OSError as error:
        raise ConfigError(f"--out = {str(out)!r}: cannot write ({error.strerror or error})"
                          ) from None
    console().print(
        f"{out}: {particle} in {medium}, {len(table.energies)} energies,"
        f" {int(table.particles.sum())} particles, {table.total_yield[-1]:.3g} photons at"
        f" {table.energies[-1]:g} MeV; largest relative error of the yield"
        f" {float(np.max(table.yield_error / table.total_yield)):.2%}, of the angular profile"
        f" {float(np.max(table.profile_error())):.2%}"
    )


def _parse_floats(text: str, option: str) -> tuple[float, ...]:
    """Comma-separated numbers; ``ConfigError`` naming the option otherwise."""
    from ..errors import ConfigError

    try:
        return tuple(float(part) for part in text.split(","))
    except ValueError:
        raise ConfigError(f"{option} = {text!r}: expected comma-separated numbers") from None


@tables_app.command("train")
@guarded
def tables_train(
    particle: Annotated[str, typer.Option(help="mu- or e- (a shipped table).")],
    out: Annotated[Path, typer.Option(help="Network file to write (.eqx).")],
    medium: Annotated[str, typer.Option(help="water or scintillator.")] = "water",
    table: Annotated[
        Path | None, typer.Option(help="Emission table (HDF5); default: the shipped one.")
    ] = None,
    steps: Annotated[int, typer.Option(help="Adam steps.")] = 4000,
    width: Annotated[int, typer.Option(help="Units per hidden layer.")] = 128,
    depth: Annotated[int, typer.Option(help="Hidden layers.")] = 3,
    batch: Annotated[int, typer.Option(help="Training points per step.")] = 16384,
    seed: Annotated[int, typer.Option(help="Seed of the weights and the batches.")] = 0,
    checkpoint: Annotated[
        Path | None,
        typer.Option(help="Checkpoint file (resumed if it exists); default OUT.checkpoint."),
    ] = None,
    report: Annotated[
        Path | None, typer.Option(help="Write the fit-quality report here (JSON).")
    ] = None,
) -> None:
    """Train the SIREN emission model on an emission table (resumable: an interrupted run
    continues from its checkpoint), then report its fit quality per energy."""
    from ..emission.models import threshold_energy
    from ..emission.siren import save_network
    from ..emission.training import SirenSettings, fit_report, train_siren
    from ..errors import ConfigError
    from ..generator.emission_tables import shipped_table
    from ..interrupts import terminate_as_interrupt

    check_output_file(out, "--out")
    if report is not None:
        check_output_file(report, "--report")
    settings = SirenSettings(width=width, depth=depth, steps=steps, batch=batch, seed=seed)
    source = shipped_table(particle, medium) if table is None else _read_table(table)
    if source.particle != particle or source.medium != medium:
        raise ConfigError(f"--table = {str(table)!r}: holds {source.particle} in"
                          f" {source.medium}, not {particle} in {medium}")
    checkpoint = out.with_name(out.name + ".checkpoint") if checkpoint is None else checkpoint
    threshold = threshold_energy(particle, medium)
    try:
        with terminate_as_interrupt() as interrupts:
            network, history = train_siren(source, threshold, settings,
                                           checkpoint=checkpoint, progress=True,
                                           check=interrupts.check)
        save_network(out, network, {"particle": particle, "medium": medium,
                                    "loss": history["loss"][-1]})
    except OSError as error:
        raise ConfigError(f"--out = {str(out)!r}: cannot write ({error.strerror or error})"
                          ) from None
    rows = fit_report(network, source, threshold)
    if report is not None:
        report.write_text(json.dumps({"history": history, "energies": rows}, indent=1))
    _print_fit_report(out, history, rows)


def _read_table(path: Path):
    """The emission table at ``path``; ``ConfigError`` naming --table otherwise."""
    from ..errors import ConfigError
    from ..generator.emission_tables import load_table

    try:
        return load_table(path)
    except (OSError, KeyError) as error:
        raise ConfigError(f"--table = {str(path)!r}: not an emission table ({error})"
                          ) from None


def _print_fit_report(out: Path, history: dict, rows: list[dict]) -> None:
    """The loss and the per-energy fit quality as a rich table."""
    from rich.table import Table

    view = Table(title=f"{out}: final loss {history['loss'][-1]:.3g}")
    for name in ("E MeV", "profile chi2/bin", "normalisation", "rms error of h"):
        view.add_column(name, justify="right")
    for row in rows:
        view.add_row(f"{row['energy']:.4g}", f"{row['profile_chi2']:.2f}",
                     f"{row['normalisation']:+.2%}", f"{row['rms_h']:.2%}")
    console().print(view)
