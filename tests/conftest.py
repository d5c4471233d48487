"""Shared test settings: strict dtype promotion, a compilation cache shared by the test
workers, and a hypothesis profile for CI."""

import os
from pathlib import Path

import jax
from hypothesis import HealthCheck, settings

jax.config.update("jax_numpy_dtype_promotion", "strict")
# The parallel test workers (pytest-xdist) compile many of the same programs (the
# expected mode of the toy detectors above all): a persistent cache lets the second
# worker load what the first compiled. Local to the checkout; PHOTONFLOW_TEST_JAX_CACHE=""
# turns it off.
_cache = os.environ.get("PHOTONFLOW_TEST_JAX_CACHE",
                        str(Path(__file__).resolve().parents[1] / ".pytest_cache" / "jax"))
if _cache:
    jax.config.update("jax_compilation_cache_dir", _cache)

settings.register_profile(
    "photonflow",
    max_examples=int(os.environ.get("HYPOTHESIS_EXAMPLES", "60")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("photonflow")


#: Test modules that take minutes (mostly compiling): collected first, so that the
#: parallel workers (``--dist loadfile``, one module per worker) start them early and
#: the short modules fill in around them instead of one long module ending the run.
SLOW_MODULES = ("test_calibration_ensemble.py", "test_robustness.py", "test_expected.py",
                "test_calibration.py", "test_mirror.py", "test_jax_transforms.py")


def pytest_collection_modifyitems(config, items):
    """Order the slow modules first (stable: the order within a module is kept)."""
    def rank(item):
        name = item.path.name
        return SLOW_MODULES.index(name) if name in SLOW_MODULES else len(SLOW_MODULES)

    items.sort(key=rank)
