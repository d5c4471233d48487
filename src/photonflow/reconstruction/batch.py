"""Reconstruction of many events: in this process or as Dask tasks, in event order, one
``RecoResult`` per event whatever happens to it.

An event whose fit raises is recorded as a failure with the error as its reason, and
the batch goes on (``reconstruct_or_fail``). ``reconstruct_events`` yields the results
of events ``first_event`` onwards in event order, serially or from blocks computed on a
local Dask cluster (``workers``) or an existing one (``scheduler``); a fit depends only
on its event and the settings, so the results are the same either way.
"""

from __future__ import annotations

import dataclasses
import time as clock
import traceback
from collections.abc import Iterator, Sequence

from ..cluster import check_count, dask_client, ordered_results
from ..errors import ConfigError
from ..threads import host_cores
from ..transport.optics import TransportConfig
from .fit import METHODS, PARTICLES, reconstruct
from .result import RecoResult
from .settings import RecoSettings

#: Largest default block of events per Dask task (a fit takes seconds to minutes).
MAX_BLOCK_EVENTS = 4


def reconstruct_or_fail(detector, params, event, particle: str, method: str,
                        config: TransportConfig, settings: RecoSettings) -> RecoResult:
    """``reconstruct``, with an error raised by the fit (not by the settings, which are
    checked before a batch starts) recorded as the event's failure: "error:
    <ExceptionType>: <message>" (one line)."""
    began = clock.perf_counter()
    try:
        return reconstruct(detector, params, event, particle, method, config=config,
                           settings=settings)
    except ConfigError:
        raise
    except Exception as error:  # noqa: BLE001 -- one event's fit must not stop a batch
        text = " ".join(str(error).split()) or traceback.format_exception_only(error)[-1]
        reason = f"error: {type(error).__name__}: {text}"[:400]
        return RecoResult.failed(reason, particle, method, clock.perf_counter() - began)


def reconstruct_block(detector, params, events, particle, method, config,
                      settings) -> list[RecoResult]:
    """The results of ``events`` (a list): one Dask task."""
    return [reconstruct_or_fail(detector, params, event, particle, method, config,
                                settings) for event in events]


def check_batch_options(particle: str, method: str) -> None:
    """One-line ``ConfigError`` for an unknown particle or method."""
    if particle not in PARTICLES:
        raise ConfigError(f"particle = {particle!r}: must be one of {', '.join(PARTICLES)}")
    if method not in METHODS:
        raise ConfigError(f"method = {method!r}: must be one of {', '.join(METHODS)}")


def reconstruct_events(detector, params, events: Sequence, particle: str = "mu-",
                       method: str = "gradient", *, config: TransportConfig | None = None,
                       settings: RecoSettings | None = None, first_event: int = 0,
                       workers: int | None = None, scheduler: str | None = None,
                       block_events: int | None = None) -> Iterator[RecoResult]:
    """Yield the ``RecoResult`` of ``events[first_event:]`` in event order.

    Args:
        detector, params, particle, method, config, settings: as in ``reconstruct``.
        events: a sequence of ``Event`` (a list, or an open ``EventFile``: read in
            blocks as the job goes).
        first_event: the first event to reconstruct (a resumed job's).
        workers: reconstruct on a local Dask cluster of this many processes (each with
            ``RecoSettings.threads``, unless set, the host's cores shared among them);
            scheduler: on the existing cluster at this address; neither: here.
        block_events: events per Dask task (default: a few per worker and at most
            ``MAX_BLOCK_EVENTS``).

    Raises:
        ConfigError: an unknown particle or method, both ``workers`` and
            ``scheduler`` (one line), before any fit.
    """
    check_batch_options(particle, method)
    config = TransportConfig() if config is None else config
    settings = RecoSettings() if settings is None else settings
    n_events = len(events)
    first_event = check_count("first_event", first_event, 0)
    if workers is None and scheduler is None:
        return (reconstruct_or_fail(detector, params, events[i], particle, method, config,
                                    settings) for i in range(first_event, n_events))
    if workers is not None and scheduler is not None:
        raise ConfigError(f"workers = {workers} and scheduler = {scheduler!r}: choose one")
    if workers is not None and settings.threads is None:
        # the local cluster's processes share this host's cores
        settings = dataclasses.replace(settings, threads=max(1, host_cores() // workers))
    remaining = max(0, n_events - first_event)
    block = block_events or max(1, min(MAX_BLOCK_EVENTS, remaining // (2 * (workers or 1))))
    block = check_count("block_events", block, 1)
    return _cluster_results(detector, params, events, particle, method, config, settings,
                            first_event, block, workers, scheduler)


def _cluster_results(detector, params, events, particle, method, config, settings,
                     first_event, block, workers, scheduler) -> Iterator[RecoResult]:
    n_events = len(events)
    if first_event >= n_events:
        return

    def blocks():
        for start in range(first_event, n_events, block):
            yield (list(events[start:min(start + block, n_events)]), particle, method,
                   config, settings)

    with dask_client(workers, scheduler) as client:
        for results in ordered_results(client, reconstruct_block, (detector, params),
                                       blocks()):
            yield from results

