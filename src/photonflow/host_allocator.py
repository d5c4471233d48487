"""The C library's allocator settings for XLA's CPU programs: large buffers are kept by
the process and reused, not returned to the system after every call.

XLA's CPU client allocates the buffers of each program call with the C library's
``malloc``, on its own threads (JAX dispatches CPU programs asynchronously). glibc
serves an allocation above its mmap threshold (adjusted at run time, at most 32 MB on
64-bit systems), and on a thread other than the main one any allocation too large for
that thread's arena (64 MB heaps), with fresh pages from the system, and returns them
when it is freed, so every call of a program whose temporaries are that large faults
all their pages in again. The expected response of a track and its gradient has such
temporaries: in a fit of an SK muon a value and gradient took ~70,000 page faults
(280 MB) per call and 113 ms, and the whole fit 5 million faults and 4.4 s of its 12 s
in the kernel (``BENCHMARKS.md``). On import photonflow therefore sets glibc's
allocator to one arena for all threads (the main one, which can grow) and its mmap and
trim thresholds to ``THRESHOLD`` bytes (``mallopt``): freed buffers stay in the
process's heap and the next call reuses them (the same fit: 78 ms per value and
gradient, 9.7 s, 32,000 page faults in all). The price: memory the process frees is kept by it (its
resident size stays near its peak) unless more than ``THRESHOLD`` lies free at the top
of its heap, and threads allocating at the same moment wait for each other (XLA's
compute threads hardly allocate).

``PHOTONFLOW_HOST_ALLOCATOR=system`` keeps the C library's own settings. Nothing changes
where the C library is not glibc (macOS, Windows, musl), and results never depend on
it. Written with ``ctypes`` because no maintained Python library sets these; glibc's
environment variables (``MALLOC_ARENA_MAX`` and the thresholds') do the same but must be
set before Python starts.
"""

from __future__ import annotations

import ctypes
import os

#: Environment variable: ``system`` keeps the C library's allocator settings.
ENVIRONMENT = "PHOTONFLOW_HOST_ALLOCATOR"
#: Bytes: allocations up to this come from the heap, and free memory up to this at its
#: top stays with the process (``mallopt`` takes a C int: 2 GiB - 1 is its largest) ...
THRESHOLD = 2**31 - 1
#: ... or, where glibc refuses an mmap threshold that high (versions that cap it at
#: half a thread heap's size), this one, the cap of 64-bit systems.
CAPPED_MMAP_THRESHOLD = 32 * 2**20
#: glibc's ``mallopt`` parameters (malloc.h).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, M_ARENA_MAX = -1, -3, -8


def glibc_version() -> str | None:
    """The running glibc's version ("2.36"), or None where the C library is another."""
    try:
        text = os.confstr("CS_GNU_LIBC_VERSION")
    except (AttributeError, ValueError, OSError):
        return None
    return text.split()[-1] if text and text.startswith("glibc") else None


def configure_host_allocator() -> bool:
    """Set glibc's allocator to one arena and its mmap and trim thresholds to
    ``THRESHOLD`` (module docstring), unless ``PHOTONFLOW_HOST_ALLOCATOR`` is ``system``
    or the C library is not glibc. Called once when photonflow is imported; threads
    that already hold an arena of their own (JAX run before photonflow was imported)
    keep it. Returns whether all three were set as asked (False also where glibc
    refuses the mmap threshold and ``CAPPED_MMAP_THRESHOLD`` is set instead)."""
    if os.environ.get(ENVIRONMENT, "").strip().lower() == "system" or glibc_version() is None:
        return False
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    mmap = bool(mallopt(M_MMAP_THRESHOLD, THRESHOLD))
    if not mmap:
        mallopt(M_MMAP_THRESHOLD, CAPPED_MMAP_THRESHOLD)  # the most this glibc allows
    return all([mallopt(M_ARENA_MAX, 1), mmap, mallopt(M_TRIM_THRESHOLD, THRESHOLD)])
