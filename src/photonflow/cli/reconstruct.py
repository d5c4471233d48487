"""``photonflow reconstruct`` (an event file to a reconstruction file, resumable, serial
or on Dask) and ``photonflow evaluate`` (a reconstruction file to its resolution
summary and plots)."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from ..cli_errors import EXIT_INTERRUPTED, MAX_BOUNCES, check_count, max_workers
from ..interrupts import terminate_as_interrupt
from ..provenance import code_identity
from ..reconstruction.settings import RecoSettings
from ..transport.optics import TransportConfig, check_config
from .root import console

_DEFAULTS = RecoSettings()
_TRANSPORT = TransportConfig()


def reconstruct(
    events: Annotated[Path, typer.Argument(
        help="Event file to reconstruct (HDF5, e.g. from photonflow simulate).")],
    out: Annotated[Path, typer.Option(
        "--out", "-o", help="Reconstruction file to write (HDF5).")],
    particle: Annotated[str, typer.Option(
        help="Hypothesis: mu-, e-, or auto (both; the likelier kept, with the e/mu"
             " log-likelihood ratio).")] = "mu-",
    method: Annotated[str, typer.Option(
        help="gradient (L-BFGS on exact gradients) or minuit (MIGRAD, numerical"
             " derivatives: the conventional baseline).")] = "gradient",
    params: Annotated[Path | None, typer.Option(
        help="Detector parameters from this calibration result (.json) instead of those"
             " stored in the event file.")] = None,
    bounces: Annotated[int, typer.Option(
        help=f"Scatterings/reflections of the predicted light, 0 (direct light only) to"
             f" {MAX_BOUNCES}.")] = 2,
    rays: Annotated[int, typer.Option(
        help="Rays of the predicted indirect light, 1 to 1,000,000 (docs/reconstruction.md:"
             " its noise against its cost).")] = _TRANSPORT.n_rays,
    emission_model: Annotated[str, typer.Option(
        "--emission-model", help="Direct light of the tracks: spline (quadrature),"
                                 " siren or tables (moment tables: ~1.5x faster fits,"
                                 " docs/tracks.md).")] = _TRANSPORT.emission_model,
    fits: Annotated[int, typer.Option(
        help="Starts fitted per hypothesis (the likeliest).")] = _DEFAULTS.fits,
    restarts: Annotated[int, typer.Option(
        help="Further starts fitted, one after another, while no fit has converged.")]
    = _DEFAULTS.restarts,
    scan_directions: Annotated[int, typer.Option(
        "--scan-directions", help="Starting directions spread over the sphere, besides"
                                  " the seeded one and its opposite.")]
    = _DEFAULTS.scan_directions,
    max_iterations: Annotated[int, typer.Option(
        "--max-iterations", help="Optimiser iterations per fit stage.")]
    = _DEFAULTS.max_iterations,
    overdispersion: Annotated[float, typer.Option(
        help="r of the likelihood's per-sensor counts (variance mu + r mu^2), 0 to 0.5;"
             " 0 is Poisson (docs/reconstruction.md).")] = _DEFAULTS.overdispersion,
    variability_events: Annotated[int, typer.Option(
        "--variability-events", help="Events simulated at each fitted track for the"
        " reported covariance (the sandwich H^-1 J H^-1; docs/reconstruction.md), 0 or 8"
        " to 10,000; 0: the inverse Fisher information alone.")]
    = _DEFAULTS.variability_events,
    bias_correction: Annotated[bool, typer.Option(
        "--bias-correction/--no-bias-correction", help="Report each fit less its"
        " first-order bias over those events (docs/reconstruction.md).")]
    = _DEFAULTS.bias_correction,
    threads: Annotated[int | None, typer.Option(
        help="Threads per fitting process for independent likelihood calls and simulated"
             " events, 1 to 256"
             " (default: the host's cores, shared among --workers); the results do not"
             " depend on it.")] = None,
    workers: Annotated[int | None, typer.Option(
        help="Reconstruct on a local Dask cluster of this many worker processes.")] = None,
    scheduler: Annotated[str | None, typer.Option(
        help="Reconstruct on the existing Dask cluster whose scheduler is at this"
             " address (e.g. tcp://host:8786).")] = None,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Continue the interrupted job of the same command (its"
                         " .OUT.partial file) at its first missing event.")] = False,
    mode: Annotated[str, typer.Option(
        help="create (refuse to overwrite --out) or recreate.")] = "create",
) -> None:
    """Reconstruct every event of an event file: vertex, time, direction, energy and
    (with --particle auto) the particle type, with uncertainties.

    Results are written as each event is done; a failed fit is recorded with its reason
    and the job goes on. An interrupted job (Ctrl-C, kill) keeps its results in
    .OUT.partial beside OUT; the same command with --resume finishes it. --workers and
    --scheduler give the same results as a serial job."""
    from ..cli_errors import check_output_file
    from ..emission.models import EMISSION_MODELS
    from ..errors import ConfigError
    from ..io import read_events
    from ..io.reco_file import RecoWriter
    from ..likelihood import MAX_OVERDISPERSION
    from ..params import validate_params
    from ..reconstruction.batch import check_batch_options
    from ..reconstruction.settings import MIN_VARIABILITY_EVENTS

    check_batch_options(particle, method)
    check_count("--bounces", bounces, 0, MAX_BOUNCES)
    check_count("--rays", rays, 1, 1_000_000)
    if emission_model not in EMISSION_MODELS:
        raise ConfigError(f"--emission-model = {emission_model!r}: must be one of"
                          f" {', '.join(EMISSION_MODELS)}")
    config = check_config(TransportConfig(n_bounces=bounces, n_rays=rays,
                                          emission_model=emission_model))
    check_count("--fits", fits, 1, 100)
    check_count("--restarts", restarts, 0, 100)
    check_count("--scan-directions", scan_directions, 0, 1000)
    check_count("--max-iterations", max_iterations, 1, 100_000)
    if not 0.0 <= overdispersion <= MAX_OVERDISPERSION:
        raise ConfigError(f"--overdispersion = {overdispersion!r}: must be in"
                          f" [0, {MAX_OVERDISPERSION}]")
    if variability_events != 0:
        check_count("--variability-events", variability_events, MIN_VARIABILITY_EVENTS,
                    10_000, "or 0 for the inverse Fisher information alone")
    if threads is not None:
        check_count("--threads", threads, 1, 256)
    if workers is not None and scheduler is not None:
        raise ConfigError(f"--scheduler = {scheduler!r}: not with --workers (choose one)")
    if workers is not None:
        check_count("--workers", workers, 1, max_workers())
    check_output_file(out, "--out")
    if out.expanduser().resolve() == events.expanduser().resolve():
        raise ConfigError(f"--out = {str(out)!r}: is the event file itself; name another file")
    with read_events(events) as event_file:
        detector = event_file.detector
        if params is None:
            detector_params, params_id = event_file.params, "event file"
        else:
            from ..calibration import load_params

            detector_params = load_params(params)
            params_id = "sha256:" + hashlib.sha256(Path(params).read_bytes()).hexdigest()
            try:
                validate_params(detector_params, detector.n_sensors)
            except ConfigError as error:
                raise ConfigError(f"--params = {str(params)!r}: not for the detector of"
                                  f" {events.name} ({error})") from None
        settings = RecoSettings(fits=fits, restarts=restarts,
                                scan_directions=scan_directions,
                                max_iterations=max_iterations,
                                overdispersion=overdispersion, threads=threads,
                                variability_events=variability_events,
                                bias_correction=bias_correction)
        run = {"events": _file_identity(event_file), "particle": particle, "method": method,
               "params": params_id, "bounces": bounces, "rays": rays,
               "emission_model": emission_model, "fits": fits, "restarts": restarts,
               "scan_directions": scan_directions, "max_iterations": max_iterations,
               "overdispersion": settings.overdispersion,
               "variability_events": variability_events, "bias_correction": bias_correction,
               "code": code_identity()}
        writer = RecoWriter(out, detector, run, events_file=str(events.resolve()),
                            mode=mode, resume=resume)
        _run_job(writer, event_file, detector, detector_params, particle, method, config,
                 settings, workers, scheduler, resume)


def _file_identity(event_file) -> str:
    """What identifies an event file's events: their count, its creation time and a hash
    of its hit offsets (a resumed job must read the same events)."""
    offsets = np.asarray(event_file.h5["events/offsets"][()], np.int64)
    digest = hashlib.sha256(offsets.tobytes()).hexdigest()[:16]
    return f"{len(event_file)} events, created {event_file.attrs.get('created', '?')}," \
           f" offsets {digest}"


def _run_job(writer, event_file, detector, params, particle, method, config, settings,
             workers, scheduler, resume) -> None:
    """Reconstruct the events missing from ``writer`` and write them as they come."""
    from ..io.reco_file import reco_row
    from ..progress import with_progress
    from ..reconstruction.batch import reconstruct_events

    n_events = len(event_file)
    results = None
    failed = 0
    with terminate_as_interrupt() as interrupts:
        try:
            with writer:
                done = writer.n_events
                results = reconstruct_events(
                    detector, params, event_file, particle, method,
                    config=config, settings=settings,
                    first_event=done, workers=workers, scheduler=scheduler)
                where = f" ({workers} workers)" if workers else (
                    f" ({scheduler})" if scheduler else "")
                shown = with_progress(results, f"reconstructing{where}", total=n_events,
                                      completed=done, unit="events")
                for index, result in enumerate(interrupts.checked(shown), start=done):
                    writer.write(reco_row(index, result, event_file[index].truth))
                    failed += result.failure is not None
                interrupts.check()
        except KeyboardInterrupt:
            if hasattr(results, "close"):
                results.close()  # stops a local Dask cluster now, not at exit
            kept = writer.partial
            if kept.exists():
                advice = (f"{kept.name} keeps them: run the same command with --resume to"
                          " finish")
            elif writer.path.exists() and writer.n_events == n_events:
                advice = f"{writer.path.name} was already complete"
            else:
                advice = "nothing kept"
            sys.stderr.write(f"interrupted after {writer.n_events} of {n_events} events;"
                             f" {advice}\n")
            interrupts.reported = True
            raise typer.Exit(code=EXIT_INTERRUPTED) from None
    resumed = f", resumed at event {done}" if resume else ""
    console().print(f"reconstructed {n_events} events to {writer.path}"
                    f" ({failed} failed in this job{resumed})", highlight=False,
                    soft_wrap=True)


def evaluate(
    reco: Annotated[Path, typer.Argument(help="Reconstruction file (from photonflow"
                                               " reconstruct).")],
    out: Annotated[Path, typer.Option(
        "--out", "-o", help="Summary to write (.json).")],
    plots: Annotated[Path | None, typer.Option(
        help="Folder for the plots (error distributions, resolution versus energy,"
             " pulls, e/mu log-likelihood ratio).")] = None,
) -> None:
    """Resolution of a reconstruction against the events' truth: 68 % quantiles of the
    vertex (also along and across the track), direction, energy and time errors, the
    energy bias, misidentification, failures and time per event, per particle type and
    energy; pull widths of the reported uncertainties."""
    from ..cli_errors import check_output_file
    from ..io.reco_file import read_reco
    from ..reconstruction.evaluation import format_summary, summarize

    check_output_file(out, "--out")
    table = read_reco(reco)
    summary = summarize(table)
    written = [_write_json(out, summary)]
    if plots is not None:
        from ..viz.reco_plots import plot_reconstruction

        written += plot_reconstruction(table, plots, summary)
    console().print(format_summary(summary), highlight=False, soft_wrap=True)
    console().print("wrote " + ", ".join(str(p) for p in written), highlight=False,
                    soft_wrap=True)


def _write_json(path: Path, data) -> Path:
    """Write ``data`` as JSON under a temporary name, then rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.partial")
    temporary.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n")
    temporary.replace(path)
    return path
