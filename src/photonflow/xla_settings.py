"""An opt-in XLA setting for short jobs on the CPU: XLA's classic CPU emitters.

photonflow's programs (the expected mode and its gradient, the sampled mode, the
likelihood) are large element-wise graphs. On the CPU, XLA's classic emitters compile
them about a third faster than the MLIR fusion emitters that are XLA's default, but
some compiled programs run slower (BENCHMARKS.md, docs/performance.md): they suit
short, interactive jobs dominated by compilation, not long fits. XLA reads its flags
from the environment variable ``XLA_FLAGS`` once, when JAX first starts a backend, so
with ``PHOTONFLOW_XLA_CPU_EMITTERS=classic`` photonflow adds
``--xla_cpu_use_fusion_emitters=false`` to it on import, when also

- ``XLA_FLAGS`` does not already say which emitters to use;
- no JAX backend has started yet (otherwise the flag would not be read: nothing
  changes);
- the installed jaxlib is a version known to accept the flag (``KNOWN_JAXLIB``): an
  unknown flag in ``XLA_FLAGS`` stops the process when XLA starts, so for any other
  version nothing is added.

The flag only concerns XLA's CPU compiler; programs for a GPU are compiled as before.
Child processes (``simulate --workers``) inherit the environment and with it the flag.
"""

from __future__ import annotations

import os

#: Environment variable: ``classic`` asks for XLA's classic CPU emitters.
ENVIRONMENT = "PHOTONFLOW_XLA_CPU_EMITTERS"
#: The flag photonflow adds to ``XLA_FLAGS``.
CLASSIC_EMITTERS = "--xla_cpu_use_fusion_emitters=false"
#: jaxlib (major, minor) versions on which the flag was checked to be accepted.
KNOWN_JAXLIB = ((0, 10),)


def jaxlib_version() -> tuple[int, int] | None:
    """(major, minor) of the installed jaxlib, or None when it cannot be read."""
    try:
        import jaxlib

        major, minor = jaxlib.__version__.split(".")[:2]
        return int(major), int(minor)
    except (ImportError, AttributeError, ValueError):
        return None


def configure_xla_flags() -> bool:
    """Add ``CLASSIC_EMITTERS`` to ``XLA_FLAGS`` when ``PHOTONFLOW_XLA_CPU_EMITTERS`` is
    ``classic`` and the module docstring's rules allow it (called once when photonflow
    is imported). Returns whether it was added."""
    from jax._src import xla_bridge  # only to ask whether a backend has started

    flags = os.environ.get("XLA_FLAGS", "")
    if (
        os.environ.get(ENVIRONMENT, "").strip().lower() != "classic"
        or "xla_cpu_use_fusion_emitters" in flags
        or xla_bridge.backends_are_initialized()
        or jaxlib_version() not in KNOWN_JAXLIB
    ):
        return False
    os.environ["XLA_FLAGS"] = f"{flags} {CLASSIC_EMITTERS}".strip()
    return True
