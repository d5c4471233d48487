"""Python's cyclic garbage collector, run less often in processes that trace large JAX
programs.

Tracing a program (``jit``, ``grad``, lowering to XLA) creates and drops millions of
small Python objects. With Python's default thresholds, (700, 10, 10) allocations, the
collector runs every few hundred of them and scans the young objects each time, which
takes about a fifth of the tracing: the toy cylinder's expected mode with its gradient
traced in 3.7 s and lowered in 1.05 s with the default thresholds, 3.0 s and 0.79 s
with ``THRESHOLDS`` (one process each, 2-core Intel Xeon; XLA's compilation is not
affected). Collections still run, only less often: objects in reference cycles are
freed a little later.

The ``photonflow`` command uses these thresholds (its process is its own); a library
import leaves the interpreter's settings alone, and a user who wants the same can call
``collect_less_often()`` (docs/performance.md). The test suite uses them in its worker
processes.
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
