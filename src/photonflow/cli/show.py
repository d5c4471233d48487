"""The commands that show a detector or an event file without simulating or fitting:
``presets``, ``geometry``, ``info`` and ``display``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..cli_errors import check_output_file
from ..terminal_tables import preset_rich_table
from .root import console


def presets() -> None:
    """List the built-in detector presets."""
    console(width=200).print(preset_rich_table())


def geometry(
    detector: Annotated[str, typer.Argument(
        metavar="NAME_OR_CONFIG", help="Preset name (see 'photonflow presets') or config file.",
    )],
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Picture to write (.png, .pdf, .svg); default geometry_NAME.png.",
    )] = None,
) -> None:
    """Draw the sensor layout of a detector on a flat map of its wall (lengths in m)."""
    from ..config import load_detector
    from ..viz import plot_detector
    from ..viz.geometry_plot import check_picture_path

    if out is not None:
        check_picture_path(out)
        check_output_file(out, "--out")
    loaded = load_detector(detector)
    path = out if out is not None else Path(f"geometry_{loaded.name}.png")
    plot_detector(loaded, path)
    console().print(f"wrote {path} ({loaded.describe()})", highlight=False, soft_wrap=True)


def info(
    path: Annotated[Path, typer.Argument(metavar="FILE", help="Event file (HDF5).")],
) -> None:
    """Summarise an event file: detector, events, hits, charge and time ranges."""
    from ..io import format_summary, summarize_events

    print(format_summary(summarize_events(path)))


def display(
    path: Annotated[Path, typer.Argument(metavar="FILE", help="Event file (HDF5).")],
    event: Annotated[int, typer.Option("--event", "-e", help="Event index (0-based).")] = 0,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Picture to write; default FILE_event<N>.png.")] = None,
    predicted: Annotated[bool, typer.Option(
        "--predicted", help="Draw a track event against its expected-mode prediction"
                            " (from the stored truth and parameters).")] = False,
) -> None:
    """Draw one event: charge and first-hit time of every sensor on the wall map, or with
    --predicted the observed and predicted charge, residuals and time residuals."""
    from ..errors import EventFileError
    from ..io import read_events
    from ..viz import plot_event
    from ..viz.geometry_plot import check_picture_path

    if out is not None:
        check_picture_path(out)
        check_output_file(out, "--out")
    with read_events(path) as events:
        if not -len(events) <= event < len(events):
            held = f"events 0..{len(events) - 1}" if len(events) else "no events"
            raise EventFileError(f"{path}: --event = {event}: the file holds {held}")
        record = events[event]
        target = out if out is not None else path.with_name(f"{path.stem}_event{event}.png")
        if predicted:
            _plot_predicted(path, event, events.detector, events.params, record, target)
        else:
            plot_event(events.detector, record, target)
    console().print(f"wrote {target} ({record.n_hits} hit sensors)", highlight=False)


def _plot_predicted(path, index, detector, params, record, target) -> None:
    """``viz.plot_prediction`` of a track event against ``expected`` of its truth."""
    from ..errors import EventFileError
    from ..generator import Track
    from ..response.spe import single_pe_moments
    from ..transport import expected
    from ..viz.prediction_display import plot_prediction

    truth = record.truth
    if truth is None or truth.source_kind != "track":
        kind = "no truth" if truth is None else f"truth of kind {truth.source_kind!r}"
        raise EventFileError(f"{path}: --event = {index} has {kind}; --predicted needs a"
                             " track event")
    track = Track(truth.particle, truth.position, truth.direction, truth.energy, truth.time)
    prediction = expected(detector, params, track)
    spe_mean = float(single_pe_moments(params.spe_width)[0])
    plot_prediction(detector, record, prediction, target, spe_mean=spe_mean)
