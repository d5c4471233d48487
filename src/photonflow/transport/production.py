"""Event production: ``sample_events`` serially or in blocks on a Dask cluster.

Event i depends only on the seed and i (``sample_events``), so a run cut into blocks of
consecutive events, each computed anywhere, gives the same events as one serial run.
``produce_events`` computes the blocks as Dask tasks (a local cluster of worker
processes, or an existing cluster) and yields their events in event order as they
arrive, for the caller to write (``photonflow simulate --workers N / --scheduler
ADDRESS``). Workers need nothing but an importable photonflow: the detector and
parameters are sent to each once, and each block carries its own sources. Positions
m, times ns, charges p.e.
"""

from __future__ import annotations

from collections.abc import Iterator

from ..cluster import BLOCKS_PER_WORKER, check_count, dask_client, ordered_results
from ..errors import ConfigError
from ..generator import GeneratorSettings
from ..geometry.detector import Detector
from ..io.events import Event
from ..params import Params
from ..progress import with_progress
from .optics import DEFAULT_CONFIG, TransportConfig
from .pseudo_data import sample_events

#: Largest default block, events.
MAX_BLOCK_EVENTS = 8


def block_size(n_events: int, n_workers: int) -> int:
    """Default events per Dask task: about ``BLOCKS_PER_WORKER`` blocks per worker over
    the run, between 1 and ``MAX_BLOCK_EVENTS``."""
    return max(1, min(MAX_BLOCK_EVENTS, n_events // (BLOCKS_PER_WORKER * max(n_workers, 1))))


def sample_block(detector, params, source, seed, first_event, n_events, config, medium,
                 generator) -> list[Event]:
    """Events ``first_event`` to ``first_event + n_events - 1`` as a list: one Dask task
    (``sample_events`` with the same arguments)."""
    return list(
        sample_events(detector, params, source, seed, n_events, config=config, medium=medium,
                      generator=generator, first_event=first_event)
    )


def _dask_events(client, detector, params, source, seed, first_event, n_events, block,
                 config, medium, generator) -> Iterator[Event]:
    """Yield the events of Dask tasks of ``block`` events each, in event order."""
    per_event = isinstance(source, list | tuple)

    def blocks():
        for start in range(first_event, first_event + n_events, block):
            count = min(block, first_event + n_events - start)
            sources = source[start - first_event : start - first_event + count] \
                if per_event else source
            yield sources, seed, start, count, config, medium, generator

    for events in ordered_results(client, sample_block, (detector, params), blocks()):
        yield from events


def produce_events(
    detector: Detector,
    params: Params,
    source,
    seed: int,
    n_events: int,
    *,
    first_event: int = 0,
    config: TransportConfig = DEFAULT_CONFIG,
    medium: str | None = None,
    generator: GeneratorSettings | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    block_events: int | None = None,
    progress: bool = False,
) -> Iterator[Event]:
    """Yield events ``first_event`` to ``first_event + n_events - 1`` in event order,
    equal (bit for bit) to ``sample_events`` with the same arguments.

    Without ``workers`` and ``scheduler`` this is ``sample_events`` in this process.
    With ``workers`` = N a local Dask cluster of N processes (one thread each) is
    started, with ``scheduler`` = ADDRESS (e.g. "tcp://host:8786") an existing cluster
    is used, whose workers must import photonflow; blocks of ``block_events`` events
    (default ``block_size``) are computed as tasks and their events yielded as soon as
    every earlier one has been. ``progress=True`` shows a rich progress bar counting
    events from 0 to ``first_event + n_events`` (a resumed run starts part way). Local
    workers are spawned processes: a script that passes ``workers`` needs the usual
    ``if __name__ == "__main__":`` guard.

    Args:
        source: one calibration source or ``Track`` for every event, or a sequence of
            ``n_events`` of them, the k-th for event ``first_event + k``.
        seed, config, medium, generator: as in ``sample_events``.

    Raises:
        ConfigError: bad input (one line), checked before any cluster starts (of a
            sequence of sources, the first; the others in their tasks); an error in a
            task is raised again here.
    """
    n_events = check_count("n_events", n_events, 0)
    first_event = check_count("first_event", first_event, 0)
    options = {"config": config, "medium": medium, "generator": generator}
    if workers is None and scheduler is None:
        events = sample_events(detector, params, source, seed, n_events,
                               first_event=first_event, **options)
        return _with_progress(events, first_event, n_events, "sampling events", progress)
    if workers is not None and scheduler is not None:
        raise ConfigError(f"workers = {workers} and scheduler = {scheduler!r}: choose one")
    if workers is not None:
        check_count("workers", workers, 1)
    per_event = isinstance(source, list | tuple)
    if per_event and len(source) != n_events:
        raise ConfigError(f"{len(source)} sources for n_events = {n_events}: need one per event")
    if n_events:  # check params, config, seed, medium and the first source (no event made)
        first = source[0] if per_event else source
        list(sample_events(detector, params, first, seed, 0, **options))
    block = block_size(n_events, workers or 1) if block_events is None else check_count(
        "block_events", block_events, 1)
    return _with_progress(
        _cluster_events(detector, params, source, seed, first_event, n_events, block,
                        workers, scheduler, options),
        first_event, n_events,
        f"sampling events ({f'{workers} workers' if workers else scheduler})", progress,
    )


def _cluster_events(detector, params, source, seed, first_event, n_events, block, workers,
                    scheduler, options) -> Iterator[Event]:
    """The events of ``_dask_events`` on the client of ``dask_client``."""
    if n_events == 0:
        return
    with dask_client(workers, scheduler) as client:
        yield from _dask_events(client, detector, params, source, seed, first_event,
                                n_events, block, options["config"], options["medium"],
                                options["generator"])


def _with_progress(events, first_event: int, n_events: int, label: str, progress: bool):
    """``events``, counted by a transient rich progress bar when ``progress``."""
    return with_progress(events, label, total=first_event + n_events, completed=first_event,
                         show=progress)
