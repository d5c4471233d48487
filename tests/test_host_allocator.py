"""The host allocator's settings (photonflow.host_allocator): a large buffer freed and
allocated again is reused, not faulted in afresh from the system."""

import os
import subprocess
import sys

import pytest

from photonflow import host_allocator

pytestmark = pytest.mark.skipif(host_allocator.glibc_version() is None,
                                reason="the settings concern glibc only")

#: ``rounds(count)``: page faults of each of ``count`` rounds that allocate, fill and
#: free a 256 MB buffer, each on a new thread (as XLA's threads do).
ROUNDS = """
import ctypes, resource, threading
libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, (ctypes.c_size_t,)
libc.free.argtypes = (ctypes.c_void_p,)
libc.memset.argtypes = (ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t)
SIZE = 256 << 20

def fill():
    buffer = libc.malloc(SIZE)
    libc.memset(buffer, 1, SIZE)
    libc.free(buffer)

def rounds(count):
    faults = []
    for _ in range(count):
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        thread = threading.Thread(target=fill)
        thread.start()
        thread.join()
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    return faults
"""
#: The child: configures the allocator (the module loaded from its file: no JAX in the
#: child), then prints whether it did and the faults of four rounds.
SCRIPT = """
import importlib.util, sys
spec = importlib.util.spec_from_file_location("host_allocator", sys.argv[1])
module = importlib.util.module_from_spec(spec)
spec.loader.exec_module(module)
print(module.configure_host_allocator())
""" + ROUNDS + """
print(*rounds(4))
"""
#: Pages of the buffer.
PAGES = (256 << 20) // os.sysconf("SC_PAGE_SIZE")


def _faults(setting: str) -> tuple[str, list[int]]:
    env = {name: value for name, value in os.environ.items()
           if not name.startswith("MALLOC_")}  # glibc's own settings, if any, left out
    env[host_allocator.ENVIRONMENT] = setting
    lines = subprocess.run([sys.executable, "-c", SCRIPT, host_allocator.__file__],
                           env=env, capture_output=True, text=True, check=True
                           ).stdout.split()
    return lines[0], [int(x) for x in lines[1:]]


def test_a_freed_large_buffer_is_reused_by_default_and_returned_with_system():
    """In a child process: with the settings a freed 256 MB buffer is reused by the next
    thread; with ``system`` every round faults its pages in again."""
    configured, faults = _faults("")
    if configured != "True":
        pytest.skip("this glibc refuses a 2 GiB mmap threshold")
    assert faults[0] > PAGES // 2  # the first round takes its pages from the system ...
    assert max(faults[1:]) < PAGES // 100  # ... the later ones reuse them
    configured, faults = _faults("system")
    assert configured == "False"
    assert min(faults) > PAGES // 2  # every round faults its pages in afresh


def test_importing_photonflow_configures_the_process():
    """A process that imports photonflow first (as its commands do) reuses a freed
    256 MB buffer on the next new thread. (Not checked in the test process itself:
    threads started before photonflow's import keep arenas of their own.)"""
    env = {name: value for name, value in os.environ.items()
           if not name.startswith("MALLOC_") and name != host_allocator.ENVIRONMENT}
    script = "import photonflow\n" + ROUNDS + "\nprint(*rounds(2))\n"
    faults = [int(x) for x in subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True,
        check=True).stdout.split()]
    assert faults[1] < PAGES // 100, faults
