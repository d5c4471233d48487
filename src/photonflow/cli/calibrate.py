"""``photonflow calibrate``: fit detector parameters to calibration runs with a live
progress table and write the result as JSON, or draw a saved result (--report)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from ..cli_errors import (
    EXIT_NOT_CONVERGED,
    MAX_BOUNCES,
    MAX_RAYS,
    MIN_CALIBRATION_RAYS,
    check_calibration_options,
    check_output_file,
    refuse_fit_options,
)
from .root import console


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
    from ..errors import ConfigError

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

    from ..calibration import LIKELIHOODS, calibrate, free_layout, load_params
    from ..calibration.methods import make_method
    from ..config import load_setup
    from ..errors import ConfigError
    from ..io import read_events
    from ..io.calibration_runs import open_runs
    from ..terminal_tables import calibration_rich_table
    from ..transport.optics import TransportConfig

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
    from ..calibration import CalibrationResult
    from ..config import load_detector
    from ..errors import ConfigError
    from ..geometry.presets import PRESETS
    from ..viz.calibration_report import plot_calibration_report
    from ..viz.geometry_plot import check_picture_path

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
