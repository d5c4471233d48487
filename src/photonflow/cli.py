"""The ``photonflow`` command: parse, call the library, write, report.

Every command reports bad input (any ``PhotonflowError``) as one line
``error: <message>`` on stderr and exits with code 2, without a traceback; pictures
and files are written under a temporary name and renamed, so a failed command leaves
nothing behind.
"""

from __future__ import annotations

import functools
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, TypeVar

import typer
from rich.console import Console
from rich.table import Table

from . import __version__
from .errors import PhotonflowError

#: Exit code of a command given bad input (the same as a command-line usage error).
EXIT_BAD_INPUT = 2

app = typer.Typer(
    name="photonflow",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,
)

F = TypeVar("F", bound=Callable)


def fail(message: str) -> typer.Exit:
    """Print ``error: <message>`` as one line on stderr; return the exit to raise (code 2)."""
    sys.stderr.write(f"error: {' '.join(message.split())}\n")
    sys.stderr.flush()
    return typer.Exit(code=EXIT_BAD_INPUT)


def command(function: F) -> F:
    """Register ``function`` as a sub-command that turns ``PhotonflowError`` into exit 2."""

    @functools.wraps(function)
    def run(*args, **kwargs):
        try:
            return function(*args, **kwargs)
        except PhotonflowError as error:
            raise fail(str(error)) from None

    app.command()(run)
    return function


def preset_rich_table() -> Table:
    """The detector presets as a rich table (name, shape, dimensions, sensors, coverage %,
    sensor model, medium), from ``photonflow.geometry.preset_table``."""
    from .geometry.presets import preset_table

    table = Table(title="photonflow detector presets", title_justify="left")
    table.add_column("name", style="bold", no_wrap=True)
    table.add_column("shape", no_wrap=True)
    table.add_column("dimensions", min_width=20)
    table.add_column("sensors", justify="right", no_wrap=True)
    table.add_column("coverage %", justify="right", no_wrap=True)
    table.add_column("sensor model", overflow="fold")
    table.add_column("medium", overflow="fold")
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
        )
    return table


def console() -> Console:
    """A rich console on stdout; 120 columns wide when stdout is not a terminal (pipes,
    files), so that tables are not squeezed to the 80-column default."""
    return Console() if sys.stdout.isatty() else Console(width=120)


def _version(show: bool) -> None:
    if show:
        print(f"photonflow {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True,
                     help="Print the version and exit."),
    ] = False,
) -> None:
    """Differentiable simulation, calibration and reconstruction of optical particle
    detectors (units: m, ns, MeV, rad)."""


@command
def presets() -> None:
    """List the built-in detector presets."""
    console().print(preset_rich_table())


@command
def geometry(
    detector: Annotated[str, typer.Argument(
        metavar="NAME_OR_CONFIG", help="Preset name (see 'photonflow presets') or config file.",
    )],
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Picture to write (.png, .pdf, .svg); default geometry_NAME.png.",
    )] = None,
) -> None:
    """Draw the sensor layout of a detector on a flat map of its wall (lengths in m)."""
    from .config import load_detector
    from .viz import plot_detector
    from .viz.geometry_plot import check_picture_path

    if out is not None:
        check_picture_path(out)
    loaded = load_detector(detector)
    path = out if out is not None else Path(f"geometry_{loaded.name}.png")
    plot_detector(loaded, path)
    console().print(f"wrote {path} ({loaded.describe()})", highlight=False, soft_wrap=True)


@command
def info(
    path: Annotated[Path, typer.Argument(metavar="FILE", help="Event file (HDF5).")],
) -> None:
    """Summarise an event file: detector, events, hits, charge and time ranges."""
    from .io import format_summary, summarize_events

    print(format_summary(summarize_events(path)))


def parse_vector(text: str, option: str) -> tuple[float, float, float]:
    """Three comma-separated numbers ("x,y,z"); a one-line ``ConfigError`` otherwise."""
    from .errors import ConfigError

    parts = [part.strip() for part in text.split(",")]
    try:
        values = tuple(float(part) for part in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ConfigError(f"{option} = {text!r}: expected three comma-separated numbers")
    return values


@command
def simulate(
    out: Annotated[Path, typer.Option("--out", "-o", help="Event file to write (HDF5).")],
    detector: Annotated[str, typer.Option(
        "--detector", "-d", help="Preset name or configuration file.")] = "SK",
    source: Annotated[str, typer.Option(
        "--source", help="isotropic, laser or diffuser.")] = "isotropic",
    position: Annotated[str, typer.Option(help="Source position x,y,z in m.")] = "0,0,0",
    direction: Annotated[str | None, typer.Option(
        help="Laser/diffuser axis x,y,z (normalised).")] = None,
    opening_angle: Annotated[float | None, typer.Option(
        "--opening-angle", help="Laser cone half-angle, rad.")] = None,
    anisotropy: Annotated[float, typer.Option(help="Diffuser anisotropy a in [-1, 1].")] = 0.0,
    photons: Annotated[float, typer.Option(help="Photons per pulse.")] = 1e6,
    pulse_width: Annotated[float, typer.Option(
        "--pulse-width", help="Source pulse width (Gaussian sigma), ns.")] = 0.0,
    events: Annotated[int, typer.Option(help="Number of events (pulses).")] = 1,
    seed: Annotated[int, typer.Option(help="Random seed (same seed, same events).")] = 0,
    bounces: Annotated[int, typer.Option(
        help="Scatterings/reflections followed per photon.")] = 2,
    mode: Annotated[str, typer.Option(
        help="create (refuse to overwrite), recreate or append.")] = "create",
) -> None:
    """Simulate calibration-source events photon by photon and write them to a file."""
    from .config import load_setup
    from .errors import ConfigError
    from .io import write_events
    from .params import validate_params
    from .sources import check_source, make_source
    from .transport.optics import TransportConfig
    from .transport.sampled import sample_events

    if events < 1:
        raise ConfigError(f"--events = {events}: must be >= 1")
    if bounces < 0:
        raise ConfigError(f"--bounces = {bounces}: must be >= 0")
    setup = load_setup(detector)
    light = make_source(
        source, parse_vector(position, "--position"), photons,
        direction=None if direction is None else parse_vector(direction, "--direction"),
        opening_angle=opening_angle, anisotropy=anisotropy, pulse_width=pulse_width,
    )
    check_source(light, setup.detector)
    validate_params(setup.params, setup.detector.n_sensors)
    stream = sample_events(
        setup.detector, setup.params, light, seed, events,
        config=TransportConfig(n_bounces=bounces), progress=True,
    )
    path = write_events(out, stream, setup.detector, setup.params, mode=mode)
    console().print(
        f"wrote {events} events to {path} ({setup.detector.describe()})",
        highlight=False, soft_wrap=True,
    )


@command
def display(
    path: Annotated[Path, typer.Argument(metavar="FILE", help="Event file (HDF5).")],
    event: Annotated[int, typer.Option("--event", "-e", help="Event index (0-based).")] = 0,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Picture to write; default FILE_event<N>.png.")] = None,
) -> None:
    """Draw one event: charge and first-hit time of every sensor on the wall map."""
    from .errors import EventFileError
    from .io import read_events
    from .viz import plot_event
    from .viz.geometry_plot import check_picture_path

    if out is not None:
        check_picture_path(out)
    with read_events(path) as events:
        if not -len(events) <= event < len(events):
            held = f"events 0..{len(events) - 1}" if len(events) else "no events"
            raise EventFileError(f"{path}: --event = {event}: the file holds {held}")
        record = events[event]
        target = out if out is not None else path.with_name(f"{path.stem}_event{event}.png")
        plot_event(events.detector, record, target)
    console().print(f"wrote {target} ({record.n_hits} hit sensors)", highlight=False)


@command
def demo(
    out_dir: Annotated[Path, typer.Option(
        "--out-dir", help="Folder for the demo's pictures and files.",
    )] = Path("demo_output"),
) -> None:
    """Run the main job on the embedded default detectors and write its outputs."""
    from .demo import run_demo

    run_demo(out_dir, console())


benchmark_app = typer.Typer(help="Timing and memory benchmarks (see BENCHMARKS.md).",
                            no_args_is_help=True)
app.add_typer(benchmark_app, name="benchmark")


@benchmark_app.command("transport")
def benchmark_transport_command(
    detector: Annotated[str, typer.Option("--detector", "-d", help="Preset name.")] = "SK",
    photons: Annotated[float, typer.Option(help="Photons of the isotropic source.")] = 1e6,
    repeats: Annotated[int, typer.Option(help="Timed repetitions (median).")] = 5,
    rays: Annotated[int | None, typer.Option(help="Rays for indirect light.")] = None,
    bounces: Annotated[int, typer.Option(help="Bounces followed.")] = 2,
) -> None:
    """Expected-mode forward and value-and-gradient time, noise, peak memory and
    sampled-mode photons per second, for an isotropic source at the centre and 2 m
    from the barrel wall."""
    from .benchmarking import benchmark_transport, machine_description

    try:
        rows = benchmark_transport(detector, photons, repeats, rays, bounces)
    except PhotonflowError as error:
        raise fail(str(error)) from None
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


def main() -> None:
    """Entry point of the ``photonflow`` console script and ``python -m photonflow``."""
    app(prog_name="photonflow")
