"""Independent calls of compiled programs on the host's cores.

JAX releases Python's GIL while a compiled program runs, so independent calls, such as
the likelihood at a fit's starts or the gradients of a Hessian's differences, overlap
their host-side work (argument handling, dispatch, results) with each other's programs
from several threads. The gain is modest on the CPU: XLA's CPU client runs the programs
of one device mostly one after the other (an SK value and gradient: 98 ms per call
from two threads against 112 ms from one, measured before ``host_allocator``,
``BENCHMARKS.md``). The results do not
depend on the number of threads: every call computes what it would alone, and results
come back in the order of the items. Keep the calls short: an interrupt waits for the
calls in flight.

Written here rather than taken from ``concurrent.futures`` alone because JAX's
precision setting (``jax.enable_x64``) is local to a thread: a worker thread runs each
call under the caller's setting, so that a float64 fit stays float64.
"""

from __future__ import annotations

import collections
import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor

import jax


def host_cores() -> int:
    """Cores this process may run on (at least 1)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def parallel_map(function: Callable, items: Iterable, threads: int | None = None) -> list:
    """``[function(item) for item in items]``, the calls spread over ``threads`` threads
    (None: ``host_cores()``; 1: in this thread), each under this thread's
    ``jax_enable_x64`` (the only thread-local JAX setting photonflow changes); an
    exception of any call is raised here."""
    items = list(items)
    threads = host_cores() if threads is None else int(threads)
    threads = max(1, min(threads, len(items)))
    if threads == 1:
        return [function(item) for item in items]
    with ThreadPoolExecutor(threads) as pool:
        return list(pool.map(_with_this_precision(function), items))


def ordered_map(function: Callable, items: Iterable, threads: int | None = None) -> Iterator:
    """Yield ``function(item)`` for each of ``items`` in their order, computed on
    ``threads`` threads (None: ``host_cores()``; 1: in this thread, lazily) with at most
    ``threads`` calls in flight or waiting to be taken (a long stream is not computed
    ahead of its reader), each under this thread's ``jax_enable_x64``. For calls that
    mix host work in Python (holding the GIL) with compiled programs (releasing it): a
    thread's host work overlaps another's program."""
    threads = host_cores() if threads is None else int(threads)
    if threads <= 1:
        for item in items:
            yield function(item)
        return
    call = _with_this_precision(function)
    with ThreadPoolExecutor(threads) as pool:
        pending = collections.deque()
        for item in items:
            pending.append(pool.submit(call, item))
            if len(pending) >= threads:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


def _with_this_precision(function: Callable) -> Callable:
    """``function`` run, in whichever thread calls it, under the calling thread's
    ``jax_enable_x64`` as it is now."""
    x64 = bool(jax.config.jax_enable_x64)

    def call(item):
        with jax.enable_x64(x64):
            return function(item)

    return call
