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
