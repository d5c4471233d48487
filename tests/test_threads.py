"""photonflow.threads: independent calls spread over threads, in order, each under the
caller's JAX precision."""

from __future__ import annotations

import threading

import jax
import pytest

from photonflow.threads import host_cores, parallel_map


def test_results_come_back_in_the_order_of_the_items_from_concurrent_threads():
    """Two calls are in flight at once (each waits for the other at a barrier, which
    would time out if they ran one after the other), and the results keep the items'
    order."""
    barrier = threading.Barrier(2, timeout=10.0)

    def square(k):
        if k < 2:
            barrier.wait()
        return k * k

    assert parallel_map(square, range(40), threads=3) == [k * k for k in range(40)]
    assert parallel_map(square, [], threads=2) == []
    assert parallel_map(lambda k: k + 1, range(3), threads=1) == [1, 2, 3]
    assert host_cores() >= 1


def test_each_call_runs_under_the_callers_precision():
    """JAX's x64 setting is local to a thread: a float64 caller's calls stay float64."""
    precision = lambda _: bool(jax.config.jax_enable_x64)  # noqa: E731
    for x64 in (True, False):
        with jax.enable_x64(x64):
            assert parallel_map(precision, range(4), threads=2) == [x64] * 4


def test_an_exception_of_a_call_is_raised_to_the_caller():
    def fail(k):
        if k == 3:
            raise ValueError("event 3")
        return k

    with pytest.raises(ValueError, match="event 3"):
        parallel_map(fail, range(6), threads=2)
