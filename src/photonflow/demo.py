"""The main job (``photonflow demo`` / ``make demo``) as a sequence of steps.

Each step is a title and a function of the shared ``DemoContext`` that returns a
one-line result and the files it wrote; ``run_demo`` runs them in order with a rich
status display. The steps show the detector presets, draw the sensor layouts of the
default cylinder (SK) and sphere (JUNO), simulate a calibration run in SK with its
event display, simulate a muon and an electron in SK and draw them against their
expected-mode predictions, calibrate SK's optics, and reconstruct those tracks and a
dozen more muons and electrons each with the calibrated optics.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from rich.console import Console

#: The embedded default detector of the demo (a preset name) and its sphere counterpart.
DEFAULT_DETECTOR = "SK"
SPHERE_DETECTOR = "JUNO"


@dataclasses.dataclass(frozen=True)
class DemoContext:
    """What every step may use: the output folder and the console to report to."""

    out_dir: Path
    console: Console


@dataclasses.dataclass(frozen=True)
class StepResult:
    """A step's outcome: a one-line summary and the files it wrote."""

    summary: str
    files: tuple[Path, ...] = ()


@dataclasses.dataclass(frozen=True)
class Step:
    """One step of the demo: a title and the function that does it."""

    title: str
    run: Callable[[DemoContext], StepResult]


def presets_step() -> Step:
    """Print the table of detector presets."""

    def run(context: DemoContext) -> StepResult:
        from .terminal_tables import preset_rich_table

        table = preset_rich_table()
        context.console.print(table)
        return StepResult(f"{table.row_count} presets")

    return Step("detector presets", run)


def geometry_step(name: str) -> Step:
    """Draw the sensor layout of preset ``name`` to ``<out_dir>/geometry_<name>.png``."""

    def run(context: DemoContext) -> StepResult:
        from .geometry.presets import preset_detector
        from .viz import plot_detector

        detector = preset_detector(name)
        path = context.out_dir / f"geometry_{detector.name}.png"
        plot_detector(detector, path)
        return StepResult(f"{detector.n_sensors:,} sensors drawn to {path}", (path,))

    return Step(f"sensor layout of {name}", run)


#: The demo's calibration run: an isotropic flash at the centre of the default detector.
CALIBRATION_PHOTONS = 1e6
CALIBRATION_EVENTS = 3


def calibration_run_step(name: str) -> Step:
    """Simulate a calibration run (isotropic flashes at the centre, photon by photon),
    write it to ``<out_dir>/calibration_run.h5`` and draw its first event; compare the
    mean detected light with the expected mode's prediction."""

    def run(context: DemoContext) -> StepResult:
        import jax
        import numpy as np

        from .config import load_setup
        from .io import read_events, write_events
        from .likelihood import dark_expectation
        from .response.spe import single_pe_moments
        from .sources import IsotropicSource
        from .transport.expected import expected
        from .transport.optics import TransportConfig
        from .transport.pseudo_data import sample_events
        from .viz import plot_event

        setup = load_setup(name)
        source = IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=CALIBRATION_PHOTONS)
        config = TransportConfig(n_bounces=2, n_rays=1024)
        path = context.out_dir / "calibration_run.h5"
        events = sample_events(
            setup.detector, setup.params, source, 1, CALIBRATION_EVENTS, config=config
        )
        write_events(path, events, setup.detector, setup.params, mode="recreate")
        picture = context.out_dir / "calibration_event0.png"
        with read_events(path) as stored:
            charges = [float(np.sum(event.charge)) for event in stored]
            plot_event(stored.detector, stored[0], picture)
        prediction = expected(
            setup.detector, setup.params, source, config=config, key=jax.random.key(0)
        )
        # expected total charge: (signal + dark p.e.) x mean single-p.e. charge
        mean_one, _ = single_pe_moments(setup.params.spe_width)
        dark = dark_expectation(setup.params, config.window) * setup.detector.n_sensors
        expected_charge = float((np.sum(prediction.charge) + dark) * mean_one)
        return StepResult(
            f"one calibration run of {CALIBRATION_EVENTS} central flashes of"
            f" {CALIBRATION_PHOTONS:.0e} photons in {name}:"
            f" total charge {np.mean(charges):,.0f} p.e. per event sampled,"
            f" {expected_charge:,.0f} expected; event display in {picture}",
            (path, picture),
        )

    return Step(f"calibration run in {name}", run)


#: The particle tracks of the demo: (particle, start m, direction, kinetic energy MeV).
DEMO_TRACKS = (
    ("mu-", (-4.0, 2.0, 1.0), (0.8, 0.0, 0.6), 1000.0),
    ("e-", (3.0, -2.0, -2.0), (0.0, 0.6, -0.8), 500.0),
)


def track_events_step(name: str) -> Step:
    """Simulate one event of each ``DEMO_TRACKS`` track (generator + photon transport)
    with the optics ``CALIBRATION_TRUTH`` (which the calibration step recovers), write
    them to ``<out_dir>/track_events.h5`` and draw each against its expected-mode
    prediction (``track_event<N>.png``)."""

    def run(context: DemoContext) -> StepResult:
        import numpy as np

        from .config import load_setup
        from .generator import Track
        from .io import write_events
        from .likelihood import dark_expectation
        from .response.spe import single_pe_moments
        from .transport.expected import expected
        from .transport.optics import TransportConfig
        from .transport.pseudo_data import sample_events
        from .viz.prediction_display import plot_prediction

        setup = load_setup(name)
        params = setup.params.replace(**CALIBRATION_TRUTH)  # the optics calibrated below
        tracks = [Track(particle, start, direction, energy)
                  for particle, start, direction, energy in DEMO_TRACKS]
        events = list(sample_events(setup.detector, params, tracks, 7, len(tracks)))
        path = context.out_dir / "track_events.h5"
        write_events(path, events, setup.detector, params, mode="recreate")
        spe_mean = float(single_pe_moments(params.spe_width)[0])
        config = TransportConfig(n_rays=1024)
        dark = float(dark_expectation(params, config.window)) * setup.detector.n_sensors
        pictures, totals = [], []
        for index, (track, event) in enumerate(zip(tracks, events, strict=True)):
            prediction = expected(setup.detector, params, track, config=config)
            picture = context.out_dir / f"track_event{index}.png"
            plot_prediction(setup.detector, event, prediction, picture, spe_mean=spe_mean)
            pictures.append(picture)
            totals.append(f"{track.particle} {float(track.energy):g} MeV:"
                          f" {float(np.sum(event.charge)):,.0f} observed,"
                          f" {(float(np.sum(prediction.charge)) + dark) * spe_mean:,.0f}"
                          " predicted (with dark noise)")
        return StepResult(
            f"tracks in {name} (charge, p.e.): {'; '.join(totals)}; predicted-versus-observed"
            f" displays in {', '.join(str(p) for p in pictures)}",
            (path, *pictures),
        )

    return Step(f"particle tracks in {name}", run)


#: The optics the demo's calibration recovers: true values (shifted from the preset's
#: defaults), the fit's start (20-30 % away) and the free fields.
CALIBRATION_TRUTH = {
    "absorption_length": 90.0,  # m
    "scattering_length": 70.0,  # m
    "wall_reflectivity": 0.15,
    "sensor_reflectivity": 0.25,
}
CALIBRATION_START = {
    "absorption_length": 115.0,
    "scattering_length": 52.0,
    "wall_reflectivity": 0.19,
    "sensor_reflectivity": 0.2,
}
#: Photons per run (one flash each) and rays of the expected mode. The expected mode's
#: indirect light is a fixed set of weighted rays; the fit is unbiased while their noise
#: per sensor stays small compared with its statistical error (docs/calibration.md). At
#: 2,048 rays and 2e5 photons the truth lies within the fit's statistical reach
#: (2 x delta(-log L) = 7.0 for 4 parameters, measured on SK).
CALIBRATION_FIT_PHOTONS = 2e5
CALIBRATION_FIT_RAYS = 2048


def optics_calibration_step(name: str) -> Step:
    """Recover the optics (absorption and scattering lengths, wall and sensor
    reflectivities) of preset ``name`` from three simulated calibration runs: a laser at
    the top of the axis pointing down and two isotropic flashes (centre, and off-centre
    low); fit all four from a start 20-30 % away, print fitted +- error versus true,
    save the result to ``<out_dir>/calibration.json`` and its report picture."""

    def run(context: DemoContext) -> StepResult:
        import numpy as np

        from .calibration import calibrate
        from .config import load_setup
        from .sources import IsotropicSource, LaserSource
        from .terminal_tables import calibration_rich_table
        from .transport.optics import TransportConfig
        from .transport.pseudo_data import sample_events
        from .viz.calibration_report import plot_calibration_report

        setup = load_setup(name)
        detector = setup.detector
        truth = setup.params.replace(**CALIBRATION_TRUTH)
        start = setup.params.replace(**CALIBRATION_START)
        config = TransportConfig(n_bounces=2, n_rays=CALIBRATION_FIT_RAYS)
        half = 0.5 * float(detector.shape.height)
        radius = float(detector.shape.radius)
        photons = CALIBRATION_FIT_PHOTONS
        sources = [
            LaserSource(position=[0.0, 0.0, 0.8 * half], direction=[0.0, 0.0, -1.0],
                        n_photons=photons, opening_angle=0.1),
            IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=photons),
            IsotropicSource(position=[0.5 * radius, 0.0, -0.5 * half], n_photons=photons),
        ]
        runs = [
            (source, list(sample_events(detector, truth, source, 10 + k, 1, config=config)))
            for k, source in enumerate(sources)
        ]
        free = list(CALIBRATION_TRUTH)
        status = context.console

        def progress(iteration: int, loss: float, values: dict) -> None:
            shown = ", ".join(f"{label} {value:.4g}" for label, value in values.items())
            status.print(f"  iteration {iteration}: -log L {loss:.2f}; {shown}",
                         highlight=False, soft_wrap=True)

        result = calibrate(detector, runs, start, free, config=config, truth=truth,
                           callback=progress)
        context.console.print(calibration_rich_table(result))
        context.out_dir.mkdir(parents=True, exist_ok=True)
        path = result.save(context.out_dir / "calibration.json")
        picture = context.out_dir / "calibration_report.png"
        plot_calibration_report(result, detector, picture)
        pulls = result.pulls()
        worst = max(free, key=lambda field: abs(float(pulls[field])))
        return StepResult(
            f"{len(free)} optical parameters from {len(runs)} further runs (a downward laser"
            f" and two flashes, one pulse of {photons:.0e} photons each)"
            f" in {result.history[-1]['iteration']} iterations"
            f" ({'converged' if result.converged else result.message}); largest pull"
            f" {worst} {float(np.asarray(pulls[worst])):+.2f}; report in {picture}",
            (path, picture),
        )

    return Step(f"optics calibration in {name}", run)


#: Settings of the demo's reconstruction: one fit per event from the likeliest start
#: (docs/reconstruction.md), the direct light from the emission model's moment tables.
DEMO_RECO_FITS = 1
DEMO_EMISSION_MODEL = "tables"
#: The sample reconstructed besides the two displayed tracks: this many events of each
#: (particle, kinetic energy MeV), vertices at least 2 m inside the walls, isotropic,
#: simulated with ``DEMO_SAMPLE_SEED``.
DEMO_SAMPLE_EVENTS = 12
DEMO_SAMPLE = (("mu-", 1000.0), ("e-", 500.0))
DEMO_SAMPLE_SEED = 23


def _reco_events(name: str, context: DemoContext) -> Path:
    """Write ``<out_dir>/reco_events.h5``: the displayed tracks' events
    (``track_events.h5``) and ``DEMO_SAMPLE_EVENTS`` more of each ``DEMO_SAMPLE``
    particle, simulated with the optics ``CALIBRATION_TRUTH``; return its path."""
    import itertools

    from .config import load_setup
    from .io import read_events, write_events
    from .transport.pseudo_data import sample_events
    from .transport.tracks import random_tracks

    setup = load_setup(name)
    truth = setup.params.replace(**CALIBRATION_TRUTH)
    tracks = [track for k, (particle, energy) in enumerate(DEMO_SAMPLE)
              for track in random_tracks(setup.detector, particle, energy,
                                         DEMO_SAMPLE_SEED + k, DEMO_SAMPLE_EVENTS)]
    with read_events(context.out_dir / "track_events.h5") as shown:
        displayed = [shown[index] for index in range(len(shown))]
    path = context.out_dir / "reco_events.h5"
    sample = sample_events(setup.detector, truth, tracks, DEMO_SAMPLE_SEED, len(tracks))
    write_events(path, itertools.chain(displayed, sample), setup.detector, truth,
                 mode="recreate")
    return path


def reconstruction_step(name: str) -> Step:
    """Simulate the reconstruction sample (``_reco_events``: the displayed tracks and
    ``DEMO_SAMPLE_EVENTS`` muons and electrons) and reconstruct it with the optics of
    ``<out_dir>/calibration.json`` (the calibration step's; the preset's defaults where
    it is missing), each event under the hypothesis of its simulated particle
    (``photonflow reconstruct --particle auto`` fits both), write ``reco.h5``, print
    the resolution table and draw the error and pull pictures (``reco_errors.png``,
    ``reco_pulls.png``)."""

    def run(context: DemoContext) -> StepResult:
        from .calibration import load_params
        from .io import read_events
        from .io.reco_file import RecoWriter, read_reco, reco_row
        from .reconstruction.batch import reconstruct_or_fail
        from .reconstruction.evaluation import format_summary, summarize
        from .reconstruction.settings import RecoSettings
        from .transport.optics import TransportConfig
        from .viz.reco_plots import plot_reconstruction

        calibration = context.out_dir / "calibration.json"
        path = context.out_dir / "reco.h5"
        settings = RecoSettings(fits=DEMO_RECO_FITS)
        config = TransportConfig(n_rays=1024, emission_model=DEMO_EMISSION_MODEL)
        events_path = _reco_events(name, context)
        with read_events(events_path) as events:
            params = load_params(calibration) if calibration.exists() else events.params
            run_settings = {"events": events_path.name, "particle": "simulated",
                            "method": "gradient", "fits": DEMO_RECO_FITS,
                            "emission_model": DEMO_EMISSION_MODEL,
                            "variability_events": settings.variability_events,
                            "bias_correction": settings.bias_correction,
                            "params": calibration.name if calibration.exists() else
                            "event file"}
            with RecoWriter(path, events.detector, run_settings, mode="recreate") as writer:
                for index in range(len(events)):
                    event = events[index]
                    context.console.print(f"  reconstructing event {index + 1} of"
                                          f" {len(events)} ({event.truth.particle}) ...",
                                          highlight=False)
                    result = reconstruct_or_fail(events.detector, params, event,
                                                 event.truth.particle, "gradient", config,
                                                 settings)
                    writer.write(reco_row(index, result, event.truth))
        table = read_reco(path)
        summary = summarize(table)
        context.console.print(format_summary(summary), highlight=False)
        pictures = plot_reconstruction(table, context.out_dir, summary, prefix="reco_")
        errors = ", ".join(
            f"{p} {entry['vertex_68_cm']:.0f} cm / {entry['direction_68_deg']:.1f} deg /"
            f" {100 * entry['energy_68_frac']:.1f} %" for p, entry in
            summary["particles"].items() if entry["vertex_68_cm"] is not None)
        return StepResult(f"{len(table)} events with the calibrated optics (fit - truth:"
                          f" {errors}); results in {path}", (events_path, path, *pictures))

    return Step(f"reconstruction in {name}", run)


def demo_steps(with_fit: bool = True) -> list[Step]:
    """The steps of the main job, in order (``with_fit=False`` leaves out the optics
    calibration fit and the reconstruction with its result, the steps that take
    minutes)."""
    steps = [
        presets_step(),
        geometry_step(DEFAULT_DETECTOR),
        geometry_step(SPHERE_DETECTOR),
        calibration_run_step(DEFAULT_DETECTOR),
        track_events_step(DEFAULT_DETECTOR),
    ]
    fits = [optics_calibration_step(DEFAULT_DETECTOR), reconstruction_step(DEFAULT_DETECTOR)]
    return steps + fits if with_fit else steps


def run_demo(
    out_dir: str | Path = "demo_output",
    console: Console | None = None,
    steps: Sequence[Step] | None = None,
) -> list[Path]:
    """Run the demo steps in order, reporting each (with its wall time in s).

    Args:
        out_dir: folder for the outputs (created if missing).
        console: where to report (default: a new rich console on stdout).
        steps: the steps to run (default ``demo_steps()``).

    Returns:
        The files written, in order.
    """
    console = Console() if console is None else console
    steps = demo_steps() if steps is None else list(steps)
    context = DemoContext(Path(out_dir), console)
    written: list[Path] = []
    start = time.perf_counter()
    for number, step in enumerate(steps, start=1):
        label = f"[{number}/{len(steps)}] {step.title}"
        began = time.perf_counter()
        with console.status(f"{label} ..."):
            result = step.run(context)
        elapsed = time.perf_counter() - began
        console.print(
            f"[green]done[/green] {label}: {result.summary} [dim]({elapsed:.1f} s)[/dim]",
            highlight=False,
            soft_wrap=True,
        )
        written.extend(result.files)
    console.print(
        f"\nDemo finished in {time.perf_counter() - start:.1f} s;"
        f" {len(written)} files in {context.out_dir.resolve()}:",
        highlight=False,
        soft_wrap=True,
    )
    for path in written:
        console.print(f"  {path}", highlight=False, soft_wrap=True)
    return written
