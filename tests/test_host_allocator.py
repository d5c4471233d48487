"""The host allocator's settings (photonflow.host_allocator): a large buffer freed and
allocated again is reused, not faulted in afresh from the system."""

import os
import subprocess
import sys

import pytest

from photonflow import host_allocator

pytestmark = pytest.mark.skipif(host_allocator.glibc_version() is None,
                                reason="the settings concern glibc only")

#: Allocates, fills and frees a 256 MB buffer four times, each time on a new thread (as
#: XLA's threads do), after configuring the allocator (the module loaded from its file:
#: no JAX in the child), and prints the page faults of each round.
SCRIPT = """
import ctypes, importlib.util, resource, sys, threading
spec = importlib.util.spec_from_file_location("host_allocator", sys.argv[1])
module = importlib.util.module_from_spec(spec)
spec.loader.exec_module(module)
print(module.configure_host_allocator())
libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, (ctypes.c_size_t,)
libc.free.argtypes = (ctypes.c_void_p,)
libc.memset.argtypes = (ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t)
size = 256 << 20

def fill():
    buffer = libc.malloc(size)
    libc.memset(buffer, 1, size)
    libc.free(buffer)

for _ in range(4):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    thread = threading.Thread(target=fill)
    thread.start()
    thread.join()
    print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(setting: str) -> tuple[str, list[int]]:
    env = {**os.environ, host_allocator.ENVIRONMENT: setting}
    lines = subprocess.run([sys.executable, "-c", SCRIPT, host_allocator.__file__],
                           env=env, capture_output=True, text=True, check=True
                           ).stdout.split()
    return lines[0], [int(x) for x in lines[1:]]


def test_a_freed_large_buffer_is_reused_by_default_and_returned_with_system():
    pages = (256 << 20) // os.sysconf("SC_PAGE_SIZE")
    configured, faults = _faults("")
    assert configured == "True"
    assert faults[0] > pages // 2  # the first round takes its pages from the system ...
    assert max(faults[1:]) < pages // 100  # ... the later ones reuse them
    configured, faults = _faults("system")
    assert configured == "False"
    assert min(faults) > pages // 2  # every round faults its pages in afresh
