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
from .cli_errors import (
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    EXIT_NOT_CONVERGED,
    MAX_BOUNCES,
    MAX_EVENTS,
    MAX_PHOTONS,
    MAX_RAYS,
    MAX_REPEATS,
    MIN_CALIBRATION_RAYS,
    check_benchmark_options,
    check_calibration_options,
    check_output_file,
    check_output_folder,
    check_simulate_counts,
    error_line,
    out_of_memory,
    refuse_fit_options,
    refuse_inapplicable_light,
)
from .errors import PhotonflowError
from .interrupts import terminate_as_interrupt
from .terminal_tables import preset_rich_table

__all__ = ["app", "main", "terminate_as_interrupt"]

app = typer.Typer(
    name="photonflow",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,
)

F = TypeVar("F", bound=Callable)


def fail(message: str) -> typer.Exit:
    """Print ``error: <message>`` as one line on stderr; return the exit to raise (code 2)."""
    error_line(message)
    return typer.Exit(code=EXIT_BAD_INPUT)


def guarded(function: F) -> F:
    """``function`` with bad input (any ``PhotonflowError``) and running out of memory
    reported as one ``error:`` line and exit code 2, and an interrupt ending in exit
    code 130."""

    @functools.wraps(function)
    def run(*args, **kwargs):
        try:
            return function(*args, **kwargs)
        except PhotonflowError as error:
            raise fail(str(error)) from None
        except KeyboardInterrupt:  # the console entry says "interrupted"
            raise typer.Exit(code=EXIT_INTERRUPTED) from None
        except Exception as error:
            if not out_of_memory(error):
                raise
            raise fail(f"out of memory ({type(error).__name__}); ask for less: fewer"
                       " --events, --photons or --rays") from None

    return run


def command(function: F) -> F:
    """Register ``function`` as a sub-command of ``photonflow`` (``guarded``)."""
    app.command()(guarded(function))
    return function


def console(width: int = 120) -> Console:
    """A rich console on stdout; ``width`` columns wide when stdout is not a terminal
    (pipes, files), so that tables are not squeezed to the 80-column default."""
    return Console() if sys.stdout.isatty() else Console(width=width)


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
    console(width=200).print(preset_rich_table())


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
        check_output_file(out, "--out")
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


def parse_unit_vector(text: str, option: str) -> tuple[float, float, float]:
    """``parse_vector`` normalised to unit length; a ``ConfigError`` for the zero vector."""
    from .errors import ConfigError

    values = parse_vector(text, option)
    length = math.sqrt(sum(v * v for v in values))
    if not length > 0:
        raise ConfigError(f"{option} = {text!r}: must be a non-zero vector")
    return (values[0] / length, values[1] / length, values[2] / length)


def parse_energies(energy: float | None, energy_range: str | None, spectrum: str | None = None):
    """Kinetic energy (MeV) or (low, high) from ``--energy`` / ``--energy-range``;
    exactly one must be given, within (0, MAXIMUM_ENERGY] MeV; ``--spectrum`` only
    with a range (checked by ``parse_spectrum``)."""
    from .errors import ConfigError
    from .generator.track import MAXIMUM_ENERGY
    from .transport.tracks import parse_spectrum

    if (energy is None) == (energy_range is None):
        raise ConfigError("--energy / --energy-range: give exactly one for a --particle")
    if spectrum is not None:
        parse_spectrum(spectrum, "--spectrum")
        if energy_range is None:
            raise ConfigError(f"--spectrum = {spectrum!r}: only with --energy-range")
    if energy is not None:
        if not 0 < energy <= MAXIMUM_ENERGY:
            raise ConfigError(f"--energy = {energy:g}: must be in (0, {MAXIMUM_ENERGY:g}] MeV")
        return energy
    parts = energy_range.split(",")
    try:
        low, high = (float(part) for part in parts)
    except ValueError:
        low = high = math.nan
    if not 0 < low < high <= MAXIMUM_ENERGY:
        raise ConfigError(
            f"--energy-range = {energy_range!r}: expected LOW,HIGH MeV with"
            f" 0 < LOW < HIGH <= {MAXIMUM_ENERGY:g}"
        )
    return (low, high)


def track_sources(detector, particle, energy, energy_range, vertex, direction, margin, seed,
                  events, spectrum=None):
    """The per-event ``Track``s of ``simulate --particle`` (``random_tracks``), with
    one-line errors naming the option, and the settings that make them (a JSON-able
    dict: particle, energy MeV or [low, high], spectrum, vertex, direction,
    fiducial_margin m; ``margin`` None: ``default_fiducial_margin``)."""
    from .errors import ConfigError
    from .generator.particles import PARTICLES
    from .transport.tracks import default_fiducial_margin, random_tracks

    if particle not in PARTICLES:
        raise ConfigError(f"--particle = {particle!r}: must be one of {', '.join(PARTICLES)}")
    if vertex != "uniform-fiducial":
        point = parse_vector(vertex, "--vertex")
        if float(detector.shape.distance_to_wall(point)) < 0:
            raise ConfigError(f"--vertex = {vertex!r}: outside the {detector.shape.describe()}")
        vertex = point
    if direction != "isotropic":
        direction = parse_unit_vector(direction, "--direction")
    if margin is None:
        margin = default_fiducial_margin(detector)
    if not (math.isfinite(margin) and margin >= 0):
        raise ConfigError(f"--fiducial-margin = {margin:g}: must be >= 0 m")
    energies = parse_energies(energy, energy_range, spectrum)
    settings = {
        "particle": particle, "energy": energies, "spectrum": spectrum or "uniform",
        "vertex": vertex, "direction": direction, "fiducial_margin": margin,
    }
    tracks = random_tracks(
        detector, particle, energies, seed, events, vertex=vertex, direction=direction,
        fiducial_margin=margin, spectrum=spectrum or "uniform",
    )
    return tracks, settings


def source_settings(source) -> dict:
    """A calibration source as a JSON-able dict: its kind and every field (m, ns, rad,
    photons) as numbers or lists."""
    import dataclasses

    import numpy as np

    fields = {f.name: np.asarray(getattr(source, f.name)).tolist()
              for f in dataclasses.fields(source)}
    return {"source": type(source).__name__, **fields}


def interrupted(writer, events: int, interrupts) -> typer.Exit:
    """Report an interrupted ``simulate`` in one line (marking ``interrupts`` reported);
    return the exit to raise (130: ``main`` then leaves at once,
    ``cli_errors.run_console``)."""
    from .io.writer import checkpoint_path

    done = writer.n_run_events
    kept = checkpoint_path(writer.path)
    if done and kept.exists():
        advice = f"{kept.name} keeps them: run the same command with --resume to finish"
    elif done == events and writer.path.exists():
        advice = f"{writer.path.name} was already complete"
    else:
        advice = "nothing kept"
    sys.stderr.write(f"interrupted after {done} of {events} events; {advice}\n")
    interrupts.reported = True
    return typer.Exit(code=EXIT_INTERRUPTED)


@command
def simulate(
    context: typer.Context,
    out: Annotated[Path, typer.Option("--out", "-o", help="Event file to write (HDF5).")],
    detector: Annotated[str, typer.Option(
        "--detector", "-d", help="Preset name or configuration file.")] = "SK",
    source: Annotated[str | None, typer.Option(
        "--source", help="isotropic (default), laser or diffuser.")] = None,
    particle: Annotated[str | None, typer.Option(
        help="Simulate particle tracks instead of a source: mu-, mu+, e-, e+, gamma.")] = None,
    energy: Annotated[float | None, typer.Option(
        help="Track kinetic energy, MeV.")] = None,
    energy_range: Annotated[str | None, typer.Option(
        "--energy-range", help="Track kinetic energy range LOW,HIGH MeV.")] = None,
    spectrum: Annotated[str | None, typer.Option(
        help="Energy spectrum over --energy-range: uniform (default) or power:GAMMA"
             " (dN/dE ~ E^-GAMMA; 1 = log-uniform).")] = None,
    vertex: Annotated[str, typer.Option(
        help="Track start: uniform-fiducial or x,y,z in m.")] = "uniform-fiducial",
    fiducial_margin: Annotated[float | None, typer.Option(
        "--fiducial-margin", help="Fiducial volume for uniform-fiducial vertices: this far"
             " (m) from every wall. Default: 2 m, or a quarter of the distance from the"
             " centre to the nearest wall where that is less (0.5 m in the 4 m toys).")] = None,
    position: Annotated[str, typer.Option(help="Source position x,y,z in m.")] = "0,0,0",
    direction: Annotated[str | None, typer.Option(
        help="Laser/diffuser axis x,y,z, or track direction: isotropic (default for"
             " tracks) or x,y,z (normalised).")] = None,
    opening_angle: Annotated[float | None, typer.Option(
        "--opening-angle", help="Laser cone half-angle, rad.")] = None,
    anisotropy: Annotated[float, typer.Option(help="Diffuser anisotropy a in [-1, 1].")] = 0.0,
    photons: Annotated[float, typer.Option(
        help=f"Photons per pulse, at most {MAX_PHOTONS:.0e}.")] = 1e6,
    pulse_width: Annotated[float, typer.Option(
        "--pulse-width", help="Source pulse width (Gaussian sigma), ns.")] = 0.0,
    events: Annotated[int, typer.Option(
        help=f"Number of events (pulses or tracks), 1 to {MAX_EVENTS:,}.")] = 1,
    seed: Annotated[int, typer.Option(help="Random seed (same seed, same events).")] = 0,
    bounces: Annotated[int, typer.Option(
        help=f"Scatterings/reflections followed per photon, 0 to {MAX_BOUNCES}.")] = 2,
    mode: Annotated[str, typer.Option(
        help="create (refuse to overwrite), recreate or append.")] = "create",
    workers: Annotated[int | None, typer.Option(
        help="Run on a local Dask cluster of this many worker processes (at most 4 per"
             " CPU core).")] = None,
    scheduler: Annotated[str | None, typer.Option(
        help="Run on the existing Dask cluster whose scheduler is at this address"
             " (e.g. tcp://host:8786).")] = None,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Continue the interrupted run of the same command (its"
                         " .OUT.partial file) at its first missing event.")] = False,
) -> None:
    """Simulate calibration-source or particle-track events photon by photon and write
    them to a file (tracks: vertex, direction and energy drawn per event from the seed).

    The same seed gives the same file, serially or in parallel (--workers,
    --scheduler). An interrupted run (Ctrl-C, kill) keeps its events in .OUT.partial
    beside OUT; the same command with --resume finishes it."""
    from .config import load_setup
    from .errors import ConfigError
    from .io import EventWriter
    from .params import validate_params
    from .sources import check_source, make_source
    from .transport.optics import TransportConfig
    from .transport.production import produce_events

    check_simulate_counts(events, bounces, workers, photons)
    if particle is not None and source is not None:
        raise ConfigError(f"--source = {source!r}: not with --particle (choose one)")
    if workers is not None and scheduler is not None:
        raise ConfigError(f"--scheduler = {scheduler!r}: not with --workers (choose one)")
    refuse_inapplicable_light(context, particle, source, vertex)
    setup = load_setup(detector)
    if particle is not None:
        light, settings = track_sources(
            setup.detector, particle, energy, energy_range, vertex, direction or "isotropic",
            fiducial_margin, seed, events, spectrum,
        )
    else:
        light = make_source(
            source or "isotropic", parse_vector(position, "--position"), photons,
            direction=None if direction is None else parse_vector(direction, "--direction"),
            opening_angle=opening_angle, anisotropy=anisotropy, pulse_width=pulse_width,
        )
        check_source(light, setup.detector)
        settings = source_settings(light)
    validate_params(setup.params, setup.detector.n_sensors)
    settings.update(seed=seed, n_events=events, bounces=bounces, medium=setup.medium,
                    photonflow_version=__version__)
    writer = EventWriter(out, setup.detector, setup.params, mode=mode, chunk_events=100,
                         run=settings, resume=resume)
    produced = None
    with terminate_as_interrupt() as interrupts:
        try:
            with writer:
                done = writer.n_run_events
                produced = produce_events(
                    setup.detector, setup.params,
                    light[done:] if particle is not None else light, seed, events - done,
                    first_event=done, config=TransportConfig(n_bounces=bounces),
                    medium=setup.medium, workers=workers, scheduler=scheduler, progress=True,
                )
                writer.extend(interrupts.checked(produced))
                interrupts.check()  # one whose exception was lost: keep, do not commit
        except KeyboardInterrupt:
            if hasattr(produced, "close"):
                produced.close()  # stops a local Dask cluster now, not at exit
            raise interrupted(writer, events, interrupts) from None
    console().print(
        f"wrote {events} events to {writer.path} ({setup.detector.describe()})"
        + (f", resumed at event {done}" if resume else ""),
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
        check_output_file(out, "--out")
    with read_events(path) as events:
        if not -len(events) <= event < len(events):
            held = f"events 0..{len(events) - 1}" if len(events) else "no events"
            raise EventFileError(f"{path}: --event = {event}: the file holds {held}")
        record = events[event]
        target = out if out is not None else path.with_name(f"{path.stem}_event{event}.png")
        plot_event(events.detector, record, target)
    console().print(f"wrote {target} ({record.n_hits} hit sensors)", highlight=False)


class _FitProgress:
    """A rich live table of a running calibration: one row per iteration with -log L
    and the dense free values (the ``callback`` of ``calibrate``)."""

    def __init__(self, live) -> None:
        self.live = live
        self.table: Table | None = None

    def __call__(self, iteration: int, loss: float, values: dict) -> None:
        if self.table is None:
            self.table = Table(title="calibration progress", title_justify="left")
            for title in ("iteration", "-log L", *values):
                self.table.add_column(title, justify="right")
        self.table.add_row(str(iteration), f"{loss:.3f}", *(f"{v:.5g}" for v in values.values()))
        self.live.update(self.table)


@command
def calibrate(
    context: typer.Context,
    files: Annotated[list[Path] | None, typer.Argument(
        metavar="FILE...", help="Event files of calibration runs (photonflow simulate),"
                                " one run each.")] = None,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Result to write (.json); with --report, the picture (.png).")] = None,
    detector: Annotated[str | None, typer.Option(
        "--detector", "-d", help="Preset name or configuration file (default: the files'"
                                 " detector).")] = None,
    free: Annotated[str | None, typer.Option(
        help="Comma-separated Params fields to fit, e.g."
             " absorption_length,scattering_length,efficiency.")] = None,
    init: Annotated[Path | None, typer.Option(
        help="Start from the parameters of this calibration result (.json) instead of"
             " the detector's defaults.")] = None,
    method: Annotated[str, typer.Option(help="gauss-newton, lbfgs or adam.")] = "gauss-newton",
    likelihood: Annotated[str, typer.Option(help="charge or charge+time.")] = "charge",
    rays: Annotated[int, typer.Option(
        help=f"Rays per source for the expected mode's indirect light,"
             f" {MIN_CALIBRATION_RAYS} to {MAX_RAYS:,}.")] = 4096,
    bounces: Annotated[int | None, typer.Option(
        help=f"Scatterings/reflections followed, 0 to {MAX_BOUNCES} (default: the files'"
             " 'bounces').")] = None,
    max_iterations: Annotated[int, typer.Option(
        "--max-iterations", help="Iteration limit.")] = 50,
    report: Annotated[Path | None, typer.Option(
        help="Draw this calibration result (.json) to --out instead of fitting.")] = None,
    ray_extrapolation: Annotated[bool, typer.Option(
        "--ray-extrapolation/--no-ray-extrapolation",
        help="Extrapolate the optics to infinitely many rays, removing the expected"
             " mode's O(1/rays) ray-noise bias (docs/calibration.md).")] = True,
    jacobian_sets: Annotated[int | None, typer.Option(
        "--jacobian-sets",
        help="Average the independent-ray score's weights over this many ray sets, once"
             " (default: calibrate()'s, 4); 0: a fresh set every step"
             " (docs/calibration.md).")] = None,
    mode: Annotated[str, typer.Option(
        help="create (refuse to overwrite an existing --out, checked before the fit) or"
             " recreate.")] = "create",
) -> None:
    """Fit detector parameters (absorption and scattering lengths, reflectivities,
    per-sensor efficiency and time offset, ...) to calibration runs and write the result
    as JSON; or, with --report, draw a result: convergence, fitted versus true, and
    per-sensor residual maps."""
    from .errors import ConfigError

    if report is not None:
        if files:
            raise ConfigError(f"FILE = {str(files[0])!r}: not with --report (choose one)")
        refuse_fit_options(context)
        _calibration_report(report, out, detector)
        return
    if out is None:
        raise ConfigError("--out: required (the calibration result to write, .json)")
    if free is None:
        raise ConfigError("--free: required (comma-separated Params fields to fit)")
    if not files:
        raise ConfigError("FILE: give at least one event file of a calibration run")
    _calibration_fit(files, out, detector, free, init, method, likelihood, rays, bounces,
                     max_iterations, ray_extrapolation, jacobian_sets, mode)


def _calibration_fit(files, out, detector, free, init, method, likelihood, rays, bounces,
                     max_iterations, ray_extrapolation: bool = True,
                     jacobian_sets: int | None = None, mode: str = "create") -> None:
    """``calibrate FILE... --out``: check the options and --out, read the runs, fit with
    a live display, print the table, save the result; a fit that did not converge
    still writes its result, says so on stderr and exits with code 1."""
    from rich.live import Live

    from .calibration import LIKELIHOODS, calibrate, free_layout, load_params
    from .calibration.methods import make_method
    from .config import load_setup
    from .errors import ConfigError
    from .io import read_events
    from .io.calibration_runs import open_runs
    from .terminal_tables import calibration_rich_table
    from .transport.optics import TransportConfig

    check_calibration_options(out, mode, rays, bounces, max_iterations, jacobian_sets)
    if likelihood not in LIKELIHOODS:
        raise ConfigError(f"--likelihood = {likelihood!r}: must be one of {', '.join(LIKELIHOODS)}")
    make_method(method)
    if detector is None:
        with read_events(files[0]) as first:
            detector = first.detector.name
    setup = load_setup(detector)
    layout = free_layout(free, setup.detector.n_sensors)
    start = setup.params if init is None else load_params(init)
    # --jacobian-sets: unset keeps calibrate()'s default, 0 means a fresh set every step
    weight_sets = {} if jacobian_sets is None else {"jacobian_sets": jacobian_sets or None}
    with open_runs(files, setup.detector) as runs:
        if bounces is None:
            bounces = runs.bounces if runs.bounces is not None else TransportConfig.n_bounces
        config = TransportConfig(n_bounces=bounces, n_rays=rays)
        console().print(
            f"calibrating {', '.join(layout.names)} of {setup.detector.describe()} on"
            f" {len(files)} runs ({config.n_rays} rays, {config.n_bounces} bounces)",
            highlight=False, soft_wrap=True,
        )
        with Live(console=console(), refresh_per_second=4, transient=False) as live:
            live.update(f"compiling the expected mode of {len(files)} runs ...")
            result = calibrate(  # a failed fit raises a one-line CalibrationError
                setup.detector, runs.runs, start, list(layout.names), method=method,
                likelihood=likelihood, config=config, truth=runs.truth,
                max_iterations=max_iterations, callback=_FitProgress(live),
                ray_extrapolation=ray_extrapolation, **weight_sets,
            )
    console().print(calibration_rich_table(result))
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        path = result.save(out)
    except OSError as error:
        raise ConfigError(
            f"--out = {str(out)!r}: cannot write ({error.strerror or error})"
        ) from None
    console().print(f"wrote {path} ({result.wall_time_s:.1f} s)", highlight=False)
    if not result.converged:
        sys.stderr.write(f"warning: the fit did not converge ({' '.join(result.message.split())});"
                         f" {path} holds it with converged: false\n")
        raise typer.Exit(code=EXIT_NOT_CONVERGED)


def _calibration_report(report: Path, out: Path | None, detector: str | None) -> None:
    """``calibrate --report RESULT --out PICTURE``."""
    from .calibration import CalibrationResult
    from .config import load_detector
    from .errors import ConfigError
    from .geometry.presets import PRESETS
    from .viz.calibration_report import plot_calibration_report
    from .viz.geometry_plot import check_picture_path

    if out is None:
        raise ConfigError("--out: required with --report (the picture to write, e.g. .png)")
    check_picture_path(out)
    check_output_file(out, "--out")
    result = CalibrationResult.load(report)
    name = result.detector.get("name")
    loaded = None
    if detector is not None:
        loaded = load_detector(detector)
    elif name in PRESETS:
        loaded = load_detector(name)
    plot_calibration_report(result, loaded, out)
    console().print(f"wrote {out}", highlight=False)


@command
def demo(
    out_dir: Annotated[Path, typer.Option(
        "--out-dir", help="Folder for the demo's pictures and files.",
    )] = Path("demo_output"),
    skip_fit: Annotated[bool, typer.Option(
        "--skip-fit", help="Leave out the optics calibration fit (minutes on a laptop CPU).",
    )] = False,
) -> None:
    """Run the main job on the embedded default detectors and write its outputs."""
    from .demo import demo_steps, run_demo

    check_output_folder(out_dir, "--out-dir")
    run_demo(out_dir, console(), demo_steps(with_fit=not skip_fit))


benchmark_app = typer.Typer(help="Timing and memory benchmarks (see BENCHMARKS.md).",
                            no_args_is_help=True)
app.add_typer(benchmark_app, name="benchmark")


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
    from .benchmarking import benchmark_transport, machine_description
    from .config import load_setup

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


tables_app = typer.Typer(help="Emission tables of the particle generator.",
                         no_args_is_help=True)
app.add_typer(tables_app, name="tables")


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
) -> None:
    """Build an emission table (photons per particle by distance, angle and time offset
    along the initial direction) for an energy grid; resumes an interrupted build."""
    from .errors import ConfigError
    from .generator import GeneratorSettings
    from .generator.emission_tables import DEFAULT_ENERGIES, build_table

    grid = DEFAULT_ENERGIES if energies is None else _parse_floats(energies, "--energies")
    check_output_file(out, "--out")
    try:
        table = build_table(
            particle, grid, per_energy, seed=seed, medium=medium,
            settings=GeneratorSettings(yield_scale=yield_scale), resume=out, progress=True,
        )
    except OSError as error:
        raise ConfigError(f"--out = {str(out)!r}: cannot write ({error.strerror or error})"
                          ) from None
    console().print(
        f"{out}: {particle} in {medium}, {len(table.energies)} energies x {per_energy},"
        f" {table.total_yield[-1]:.3g} photons at {table.energies[-1]:g} MeV"
    )


def _parse_floats(text: str, option: str) -> tuple[float, ...]:
    """Comma-separated numbers; ``ConfigError`` naming the option otherwise."""
    from .errors import ConfigError

    try:
        return tuple(float(part) for part in text.split(","))
    except ValueError:
        raise ConfigError(f"{option} = {text!r}: expected comma-separated numbers") from None


def main() -> None:
    """Entry point of the ``photonflow`` console script and ``python -m photonflow``
    (``cli_errors.run_console``: usage errors as one line, exit 130 when interrupted)."""
    from ._startup import release
    from .cli_errors import run_console

    release()  # run_console handles interrupts from here on
    run_console(app, prog_name="photonflow")
