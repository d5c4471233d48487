"""``photonflow tables``: emission tables of the particle generator."""

from __future__ import annotations

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
