"""``photonflow simulate``: check the options, make the light (``light``), produce the
events (``transport.production``) and write them with an ``EventWriter`` that keeps an
interrupted run resumable."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from .. import __version__
from ..cli_errors import (
    EXIT_INTERRUPTED,
    MAX_BOUNCES,
    MAX_EVENTS,
    MAX_PHOTONS,
    check_simulate_counts,
    refuse_inapplicable_light,
)
from ..interrupts import terminate_as_interrupt
from .light import calibration_source, track_sources
from .root import console


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
    from ..config import load_setup

    _check_simulate_options(context, particle, source, vertex, events, bounces, workers,
                            scheduler, photons)
    setup = load_setup(detector)
    if particle is not None:
        light, settings = track_sources(
            setup.detector, particle, energy, energy_range, vertex, direction or "isotropic",
            fiducial_margin, seed, events, spectrum,
        )
    else:
        light, settings = calibration_source(
            setup.detector, source, position, direction, opening_angle, anisotropy, photons,
            pulse_width,
        )
    writer = _event_writer(out, setup, settings, seed=seed, events=events, bounces=bounces,
                           mode=mode, resume=resume)
    _write_events(writer, setup, light, tracks=particle is not None, seed=seed, events=events,
                  bounces=bounces, workers=workers, scheduler=scheduler, resume=resume)


def _check_simulate_options(context, particle, source, vertex, events, bounces, workers,
                            scheduler, photons) -> None:
    """The checks of ``simulate`` that need no detector: the counts, the options that
    exclude each other, and light options that do not apply to the chosen light."""
    from ..errors import ConfigError

    check_simulate_counts(events, bounces, workers, photons)
    if particle is not None and source is not None:
        raise ConfigError(f"--source = {source!r}: not with --particle (choose one)")
    if workers is not None and scheduler is not None:
        raise ConfigError(f"--scheduler = {scheduler!r}: not with --workers (choose one)")
    refuse_inapplicable_light(context, particle, source, vertex)


def _event_writer(out, setup, settings, *, seed, events, bounces, mode, resume):
    """The ``EventWriter`` of ``simulate`` (``--out``, ``--mode``, ``--resume``), after
    checking the detector's parameters; ``settings`` (the light's) gain the run's seed,
    event count, bounces, medium, photonflow version and code identity, which the file
    records (a resumed run must be made by the same code)."""
    from ..io import EventWriter
    from ..params import validate_params
    from ..provenance import code_identity

    validate_params(setup.params, setup.detector.n_sensors)
    settings.update(seed=seed, n_events=events, bounces=bounces, medium=setup.medium,
                    photonflow_version=__version__, code=code_identity())
    return EventWriter(out, setup.detector, setup.params, mode=mode, chunk_events=100,
                       run=settings, resume=resume)


def _write_events(writer, setup, light, *, tracks, seed, events, bounces, workers, scheduler,
                  resume) -> None:
    """Produce the events missing from ``writer`` (all, or from the first missing one
    with --resume; ``tracks``: ``light`` holds one track per event), write them and
    report it; an interrupt keeps what was written and ends in ``interrupted``."""
    from ..transport.optics import TransportConfig
    from ..transport.production import produce_events

    produced = None
    with terminate_as_interrupt() as interrupts:
        try:
            with writer:
                done = writer.n_run_events
                produced = produce_events(
                    setup.detector, setup.params,
                    light[done:] if tracks else light, seed, events - done,
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


def interrupted(writer, events: int, interrupts) -> typer.Exit:
    """Report an interrupted ``simulate`` in one line (marking ``interrupts`` reported);
    return the exit to raise (130: ``main`` then leaves at once,
    ``cli_errors.run_console``)."""
    from ..io.partial_files import checkpoint_path

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

