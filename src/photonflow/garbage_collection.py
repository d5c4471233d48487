"""Python's cyclic garbage collector, run less often in processes that trace large JAX
programs.

Tracing a program (``jit``, ``grad``, lowering to XLA) creates and drops millions of
small Python objects. With Python's default thresholds, (700, 10, 10), the collector
runs a young collection every 700 net allocations, which takes a sizeable share of the
tracing (docs/performance.md has the measurement); XLA's compilation is not affected.
With ``THRESHOLDS`` collections still run, only less often: objects in reference
cycles are freed a little later.

The ``photonflow`` command uses these thresholds (its process is its own); a library
import leaves the interpreter's settings alone, and a user who wants the same can call
``collect_less_often()``. The test suite uses them in its worker processes.
"""

from __future__ import annotations

import gc

#: Allocations (net of deallocations) between young collections, and young (middle)
#: collections between middle (full) ones.
THRESHOLDS = (50_000, 20, 20)


def collect_less_often() -> tuple[int, int, int]:
    """Set Python's garbage-collection thresholds to ``THRESHOLDS`` (counts of
    allocations and of collections, see ``gc.set_threshold``); returns the previous
    ones, for ``gc.set_threshold(*previous)``."""
    previous = gc.get_threshold()
    gc.set_threshold(*THRESHOLDS)
    return previous
