"""``photonflow benchmark``: timing and memory benchmarks (``benchmarking``)."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.table import Table

from ..cli_errors import MAX_BOUNCES, MAX_PHOTONS, MAX_RAYS, MAX_REPEATS, check_benchmark_options
from .root import console, guarded

benchmark_app = typer.Typer(help="Timing and memory benchmarks (see BENCHMARKS.md).",
                            no_args_is_help=True)


@benchmark_app.command("transport")
@guarded
def benchmark_transport_command(
    detector: Annotated[str, typer.Option("--detector", "-d", help="Preset name.")] = "SK",
    photons: Annotated[float, typer.Option(
        help=f"Photons of the isotropic source, at most {MAX_PHOTONS:.0e}.")] = 1e6,
    repeats: Annotated[int, typer.Option(
        help=f"Timed repetitions (median), 1 to {MAX_REPEATS}.")] = 5,
    rays: Annotated[int | None, typer.Option(
        help=f"Rays for indirect light, 1 to {MAX_RAYS:,}.")] = None,
    bounces: Annotated[int, typer.Option(help=f"Bounces followed, 0 to {MAX_BOUNCES}.")] = 2,
) -> None:
    """Expected-mode forward and value-and-gradient time, noise, peak memory and
    sampled-mode photons per second, for an isotropic source at the centre and 2 m
    from the barrel wall."""
    from ..benchmarking import benchmark_transport, machine_description
    from ..config import load_setup

    check_benchmark_options(photons, repeats, rays, bounces)
    load_setup(detector)  # an unknown detector is refused here, not in the child process
    rows = benchmark_transport(detector, photons, repeats, rays, bounces,
                               report=lambda line: console().print(line, highlight=False))
    table = Table(title=f"transport benchmark: {machine_description()}", title_justify="left")
    columns = [
        ("case", "case", "{}"), ("forward s", "forward_s", "{:.3f}"),
        ("value+grad s", "value_and_grad_s", "{:.3f}"),
        ("noise median", "noise_median", "{:.2%}"), ("noise p90", "noise_p90", "{:.2%}"),
        ("sampled photons/s", "sampled_photons_per_s", "{:.3g}"),
        ("peak RSS MB", "peak_rss_mb", "{:.0f}"),
        ("compile fwd/grad s", None, None),
    ]
    for title, _, _ in columns:
        table.add_column(title, justify="right")
    for row in rows:
        cells = [fmt.format(row[key]) for _, key, fmt in columns if key is not None]
        cells.append(f"{row['compile_forward_s']:.1f} / {row['compile_grad_s']:.1f}")
        table.add_row(*cells)
    console().print(table)
