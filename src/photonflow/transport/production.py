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

import collections
import contextlib
import logging
import numbers
import signal
from collections.abc import Iterator

from ..errors import ConfigError, format_value
from ..generator import GeneratorSettings
from ..geometry.detector import Detector
from ..io.events import Event
from ..params import Params
from ..progress import with_progress
from .optics import DEFAULT_CONFIG, TransportConfig
from .pseudo_data import sample_events

#: Blocks kept in flight per worker (bounds the parent's memory for out-of-order blocks).
BLOCKS_PER_WORKER = 4
#: Largest default block, events.
MAX_BLOCK_EVENTS = 8


def _check_count(name: str, value, minimum: int) -> int:
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < minimum:
        raise ConfigError(f"{name} = {format_value(value)}: must be an integer >= {minimum}")
    return int(value)


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


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None):
    """A ``distributed.Client``: of a new local cluster of ``workers`` processes with one
    thread each (closed on exit), or connected to the scheduler at ``scheduler``.

    Raises:
        ConfigError: not exactly one of the two, workers < 1, or no scheduler there.
    """
    if (workers is None) == (scheduler is None):
        raise ConfigError("workers / scheduler: give exactly one for a Dask production")
    from distributed import Client, LocalCluster

    with contextlib.ExitStack() as stack:
        if scheduler is None:
            n_workers = _check_count("workers", workers, 1)
            # Ctrl-C stops the parent, which closes the cluster; a worker's error reaches
            # the parent as its task's, so the cluster's own logs (which, when it is
            # closed while starting, are tracebacks of lost heartbeats) stay silent
            with _sigint_ignored():
                cluster = stack.enter_context(LocalCluster(
                    n_workers=n_workers, threads_per_worker=1, processes=True,
                    dashboard_address=None, silence_logs=logging.CRITICAL,
                ))
            client = stack.enter_context(Client(cluster))
        else:
            try:
                client = stack.enter_context(Client(scheduler, timeout="15s"))
            except (OSError, TimeoutError, ValueError) as error:
                reason = " ".join(str(error).split()) or type(error).__name__
                raise ConfigError(
                    f"scheduler = {scheduler!r}: cannot connect ({reason})"
                ) from None
        try:
            yield client
        except (KeyboardInterrupt, GeneratorExit):
            # a cluster closed while busy logs the tasks it drops: the run stops anyway
            for name in ("asyncio", "distributed", "tornado"):
                logging.getLogger(name).setLevel(logging.CRITICAL + 1)
            raise


@contextlib.contextmanager
def _sigint_ignored():
    """Ignore SIGINT within the block (in the main thread), so that worker processes
    started in it inherit that: a Ctrl-C, sent to the whole process group, then reaches
    only the parent, which stops the run and closes the cluster cleanly."""
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _dask_events(client, detector, params, source, seed, first_event, n_events, block,
                 config, medium, generator) -> Iterator[Event]:
    """Yield the events of Dask tasks of ``block`` events each, in event order, keeping
    ``BLOCKS_PER_WORKER`` blocks per worker in flight."""
    n_workers = max(1, len(client.scheduler_info().get("workers", {})))
    detector_f, params_f = client.scatter([detector, params], broadcast=True, hash=False)
    per_event = isinstance(source, list | tuple)
    starts = iter(range(first_event, first_event + n_events, block))
    pending = collections.deque()

    def submit() -> bool:
        start = next(starts, None)
        if start is None:
            return False
        count = min(block, first_event + n_events - start)
        sources = source[start - first_event : start - first_event + count] if per_event \
            else source
        pending.append(client.submit(
            sample_block, detector_f, params_f, sources, seed, start, count, config,
            medium, generator, pure=False,
        ))
        return True

    try:
        while len(pending) < BLOCKS_PER_WORKER * n_workers and submit():
            pass
        while pending:
            events = pending.popleft().result()
            submit()
            yield from events
    finally:
        for future in pending:
            future.cancel()


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
    n_events = _check_count("n_events", n_events, 0)
    first_event = _check_count("first_event", first_event, 0)
    options = {"config": config, "medium": medium, "generator": generator}
    if workers is None and scheduler is None:
        events = sample_events(detector, params, source, seed, n_events,
                               first_event=first_event, **options)
        return _with_progress(events, first_event, n_events, "sampling events", progress)
    if workers is not None and scheduler is not None:
        raise ConfigError(f"workers = {workers} and scheduler = {scheduler!r}: choose one")
    if workers is not None:
        _check_count("workers", workers, 1)
    per_event = isinstance(source, list | tuple)
    if per_event and len(source) != n_events:
        raise ConfigError(f"{len(source)} sources for n_events = {n_events}: need one per event")
    if n_events:  # check params, config, seed, medium and the first source (no event made)
        first = source[0] if per_event else source
        list(sample_events(detector, params, first, seed, 0, **options))
    block = block_size(n_events, workers or 1) if block_events is None else _check_count(
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
