"""Shared test settings: strict dtype promotion, XLA flags for a fast two-worker run,
unoptimised compilation in compile-bound modules, no persistent compilation cache,
Python's garbage collector run less often (as in the photonflow command), a hypothesis
profile for CI, and the slow modules first."""

import os
import subprocess
import sys

import jax
import pytest
from hypothesis import HealthCheck, settings

#: The environment variable JAX reads for ``jax_disable_most_optimizations``.
_UNOPTIMISED = "JAX_DISABLE_MOST_OPTIMIZATIONS"

jax.config.update("jax_numpy_dtype_promotion", "strict")

#: XLA's classic CPU emitters instead of the MLIR fusion emitters: on the toy detectors
#: compilation, most of the suite's time, takes ~20 % less (26.5 -> 21.0 s for a
#: likelihood gradient) and the compiled programs run ~15 % faster. Set for the workers
#: and the command-line subprocesses alike, and only where this XLA knows the flag (an
#: unknown flag in XLA_FLAGS aborts the process, so a child process asks first).
CLASSIC_EMITTERS = "--xla_cpu_use_fusion_emitters=false"
#: One thread per process for XLA's CPU code generation and its Eigen kernels: the two
#: test workers already keep both cores busy, and on two programs compiled side by side
#: (robustness, held light) this took 4-9 % less time (2026-11-29).
ONE_THREAD = "--xla_cpu_parallel_codegen_split_count=1 --xla_cpu_multi_thread_eigen=false"
#: LLVM at O1 without its expensive passes for the programs compiled optimised (those of
#: the modules not marked ``compile_bound``): on the toy reconstruction 12-20 % less
#: compilation (a fit's programs 45.7 -> 39.5 s, its simulated events' 20.5 -> 16.7 s)
#: and the calibration ensemble's first experiment 38.2 -> 35.0 s, with the same run
#: times there (2026-11-29; on SK's transport benchmark it saved no compilation).
LIGHT_LLVM = "--xla_backend_optimization_level=1 --xla_llvm_disable_expensive_passes=true"
#: JAX_DISABLE_MOST_OPTIMIZATIONS (LLVM at O0, no expensive passes) is set only for the
#: modules marked ``compile_bound`` (``pytestmark = pytest.mark.compile_bound``): those
#: whose time is mostly XLA compiling programs they then run a few times. There it
#: roughly halves the compilation; for the whole suite it would cost time, since the
#: fits and the calibration ensemble run ~2.5x slower unoptimised (2026-11-29, two
#: workers, before LIGHT_LLVM: the marked modules took 1,136 worker-seconds at XLA's
#: default optimisation against 836 unoptimised, the whole suite 2,566 against 3,253).
#: The numbers checked are the same either way: the whole suite also passes unoptimised.


def _use_test_xla_flags() -> None:
    """Put CLASSIC_EMITTERS, ONE_THREAD and LIGHT_LLVM ahead of the flags in XLA_FLAGS
    (a flag given there again wins), unless the emitters are chosen there already or
    this XLA refuses a flag."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" in flags:
        return
    flags = f"{CLASSIC_EMITTERS} {ONE_THREAD} {LIGHT_LLVM} {flags}".strip()
    probe = subprocess.run([sys.executable, "-c", "import jax; jax.numpy.zeros(1)"],
                           env={**os.environ, "XLA_FLAGS": flags}, capture_output=True)
    if probe.returncode == 0:
        os.environ["XLA_FLAGS"] = flags


_use_test_xla_flags()
# No persistent compilation cache in the test run, in the workers or in the command-line
# subprocesses they start (which inherit the environment): CI machines start empty, so a
# cache only adds writes, and one CI run died in JAX's cache write (a segmentation fault
# in put_executable_and_time, jaxlib 0.10.2). PHOTONFLOW_TEST_JAX_CACHE=/dir turns a
# shared cache on for local runs.
os.environ["PHOTONFLOW_COMPILATION_CACHE"] = "off"
_cache = os.environ.get("PHOTONFLOW_TEST_JAX_CACHE", "")
if _cache:
    os.environ["PHOTONFLOW_COMPILATION_CACHE"] = _cache
    jax.config.update("jax_compilation_cache_dir", _cache)

# photonflow is imported only now, after the environment it reads on import is set
from photonflow.garbage_collection import collect_less_often  # noqa: E402

collect_less_often()  # as in the photonflow command: tracing ~20 % faster


@pytest.fixture(autouse=True, scope="module")
def _compile_effort(request):
    """For a ``compile_bound`` module: programs compiled without most optimisations, in
    this process and in the command-line subprocesses it starts; others with LLVM at O1
    (LIGHT_LLVM)."""
    unoptimised = request.node.get_closest_marker("compile_bound") is not None
    previous = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", unoptimised)
    with pytest.MonkeyPatch.context() as patch:
        if unoptimised:
            patch.setenv(_UNOPTIMISED, "1")
        else:
            patch.delenv(_UNOPTIMISED, raising=False)
        yield
    jax.config.update("jax_disable_most_optimizations", previous)


settings.register_profile(
    "photonflow",
    max_examples=int(os.environ.get("HYPOTHESIS_EXAMPLES", "60")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("photonflow")


#: Test modules that take minutes (mostly compiling): collected first. pytest-xdist
#: (>= 3.5) then orders the files by their number of tests, so this order only decides
#: among files with as many tests; handing the files out longest first instead
#: (``--no-loadscope-reorder``, xdist >= 3.8) did not shorten the run (2026-11-27: 1,589 s
#: against 1,509 s, with 4.8 % more CPU time on a noisy machine: the two cores are busy
#: either way).
SLOW_MODULES = ("test_calibration_ensemble.py", "test_robustness.py", "test_expected.py",
                "test_calibration.py", "test_mirror.py", "test_jax_transforms.py")


def pytest_collection_modifyitems(config, items):
    """Order the slow modules first (stable: the order within a module is kept)."""
    def rank(item):
        name = item.path.name
        return SLOW_MODULES.index(name) if name in SLOW_MODULES else len(SLOW_MODULES)

    items.sort(key=rank)
