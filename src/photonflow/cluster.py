"""Dask for photonflow's batch jobs: a client of a local cluster or of an existing one
(``dask_client``), and blocks of work computed as tasks whose results come back in
order (``ordered_results``). ``photonflow simulate`` and ``photonflow reconstruct`` run
their ``--workers N`` / ``--scheduler ADDRESS`` jobs with these."""

from __future__ import annotations

import collections
import contextlib
import logging
import numbers
import signal
from collections.abc import Callable, Iterable, Iterator

from .errors import ConfigError, format_value
from .garbage_collection import collect_less_often

#: Blocks kept in flight per worker (bounds the parent's memory for out-of-order blocks).
BLOCKS_PER_WORKER = 4


def check_count(name: str, value, minimum: int) -> int:
    """``value`` as an int, or a one-line ``ConfigError`` naming ``name`` unless it is an
    integer >= ``minimum``."""
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < minimum:
        raise ConfigError(f"{name} = {format_value(value)}: must be an integer >= {minimum}")
    return int(value)


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None):
    """A ``distributed.Client``: of a new local cluster of ``workers`` processes with one
    thread each (closed on exit; their garbage collector set as the command's,
    ``garbage_collection.collect_less_often``), or connected to the scheduler at
    ``scheduler`` (its workers' settings left alone).

    Raises:
        ConfigError: not exactly one of the two, workers < 1, or no scheduler there.
    """
    if (workers is None) == (scheduler is None):
        raise ConfigError("workers / scheduler: give exactly one for a Dask job")
    from distributed import Client, LocalCluster

    with contextlib.ExitStack() as stack:
        if scheduler is None:
            n_workers = check_count("workers", workers, 1)
            # Ctrl-C stops the parent, which closes the cluster; a worker's error reaches
            # the parent as its task's, so the cluster's own logs (which, when it is
            # closed while starting, are tracebacks of lost heartbeats) stay silent
            with _sigint_ignored():
                cluster = stack.enter_context(LocalCluster(
                    n_workers=n_workers, threads_per_worker=1, processes=True,
                    dashboard_address=None, silence_logs=logging.CRITICAL,
                ))
            client = stack.enter_context(Client(cluster))
            # the workers are this job's processes: they trace photonflow's programs, as
            # the command does, with the collector run less often (garbage_collection)
            client.run(collect_less_often)
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
            # a cluster closed while busy logs the tasks it drops: the job stops anyway
            for name in ("asyncio", "distributed", "tornado"):
                logging.getLogger(name).setLevel(logging.CRITICAL + 1)
            raise


@contextlib.contextmanager
def _sigint_ignored():
    """Ignore SIGINT within the block (in the main thread), so that worker processes
    started in it inherit that: a Ctrl-C, sent to the whole process group, then reaches
    only the parent, which stops the job and closes the cluster cleanly."""
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def ordered_results(client, function: Callable, shared: tuple,
                    blocks: Iterable[tuple]) -> Iterator:
    """Yield ``function(*shared, *block)`` for each of ``blocks`` in their order, each
    computed as a Dask task on ``client``; ``shared`` (e.g. the detector and its
    parameters) is sent to every worker once, and ``BLOCKS_PER_WORKER`` tasks per worker
    are kept in flight. An error in a task is raised here."""
    n_workers = max(1, len(client.scheduler_info().get("workers", {})))
    shared_futures = client.scatter(list(shared), broadcast=True, hash=False)
    blocks = iter(blocks)
    pending = collections.deque()

    def submit() -> bool:
        block = next(blocks, None)
        if block is None:
            return False
        pending.append(client.submit(function, *shared_futures, *block, pure=False))
        return True

    try:
        while len(pending) < BLOCKS_PER_WORKER * n_workers and submit():
            pass
        while pending:
            result = pending.popleft().result()
            submit()
            yield result
    finally:
        for future in pending:
            future.cancel()
