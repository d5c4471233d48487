"""Shared test settings: strict dtype promotion, no persistent compilation cache, a
hypothesis profile for CI, and the slow modules first."""

import os
import subprocess
import sys

import jax
from hypothesis import HealthCheck, settings

jax.config.update("jax_numpy_dtype_promotion", "strict")

#: XLA's classic CPU emitters instead of the MLIR fusion emitters: on the toy detectors
#: compilation, most of the suite's time, takes ~20 % less (26.5 -> 21.0 s for a
#: likelihood gradient) and the compiled programs run ~15 % faster. Set for the workers
#: and the command-line subprocesses alike, and only where this XLA knows the flag (an
#: unknown flag in XLA_FLAGS aborts the process, so a child process asks first).
CLASSIC_EMITTERS = "--xla_cpu_use_fusion_emitters=false"
#: Not set: JAX_DISABLE_MOST_OPTIMIZATIONS (LLVM at O0). For the whole run it took
#: 1,769 s against 1,386 s (2026-11-27: the fits run ~3x slower); in the compile-bound
#: modules alone it would save ~285 worker-seconds of ~2,700, but there the gradient of
#: the track light with its own reference (test_track_expected) came out 12 % off, so
#: the suite compiles its programs as users get them (test_robustness's checker aside).


def _use_classic_emitters() -> None:
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" in flags:
        return
    flags = f"{flags} {CLASSIC_EMITTERS}".strip()
    probe = subprocess.run([sys.executable, "-c", "import jax; jax.numpy.zeros(1)"],
                           env={**os.environ, "XLA_FLAGS": flags}, capture_output=True)
    if probe.returncode == 0:
        os.environ["XLA_FLAGS"] = flags


_use_classic_emitters()
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
