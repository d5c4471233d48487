"""XLA settings photonflow makes on import, before JAX starts a backend.

**A correctness setting (always).** jaxlib 0.10's CPU compiler hands a reduction fused
with element-wise work to its YNNPACK fusions, and those return wrong values for all
but the first rows of a batched reduction of detector size: a sum over the time
mixture's components of 4 events of SK's 11,146 sensors (``vmap``ped or batched by
hand) came back wrong by up to ~10 in log p for events 2 and 3, in float32 (the first
two events, single events, float64 and smaller arrays were right). The calibration's
likelihood terms and event Fisher information on SK were affected; the expected mode,
the fit's likelihood and its gradients were not. photonflow adds
``--xla_cpu_experimental_ynn_fusion_type=-reduce`` (``YNN_REDUCE_OFF``: no YNNPACK
fusion of reductions) to ``XLA_FLAGS`` on import, which restores the right values, when

- ``XLA_FLAGS`` does not already set ``xla_cpu_experimental_ynn_fusion_type``;
- no JAX backend has started yet (XLA reads ``XLA_FLAGS`` once, when JAX first starts
  a backend: import photonflow before running other JAX code);
- the installed jaxlib is a version known to have the fault and to accept the flag
  (``YNN_JAXLIB``): an unknown flag in ``XLA_FLAGS`` stops the process when XLA starts.

``tests/test_xla_settings.py`` checks the batched reduction against single calls in a
fresh process, so a jaxlib that has the fault without knowing the flag fails the suite.

**An opt-in setting for short jobs on the CPU: XLA's classic CPU emitters.**
photonflow's programs (the expected mode and its gradient, the sampled mode, the
likelihood) are large element-wise graphs. On the CPU, XLA's classic emitters compile
them about a third faster than the MLIR fusion emitters that are XLA's default, but
some compiled programs run slower (BENCHMARKS.md, docs/performance.md): they suit
short, interactive jobs dominated by compilation, not long fits. With
``PHOTONFLOW_XLA_CPU_EMITTERS=classic`` photonflow adds
``--xla_cpu_use_fusion_emitters=false`` to ``XLA_FLAGS`` on import, when also

- ``XLA_FLAGS`` does not already say which emitters to use;
- no JAX backend has started yet;
- the installed jaxlib is a version known to accept the flag (``KNOWN_JAXLIB``).

Both flags only concern XLA's CPU compiler; programs for a GPU are compiled as before.
Child processes (``simulate --workers``) inherit the environment and with it the flags.
"""

from __future__ import annotations

import os
import warnings

#: Environment variable: ``classic`` asks for XLA's classic CPU emitters.
ENVIRONMENT = "PHOTONFLOW_XLA_CPU_EMITTERS"
#: The flag photonflow adds to ``XLA_FLAGS``.
CLASSIC_EMITTERS = "--xla_cpu_use_fusion_emitters=false"
#: jaxlib (major, minor) versions on which the flag was checked to be accepted.
KNOWN_JAXLIB = ((0, 10),)
#: The flag that keeps reductions out of XLA's YNNPACK fusions on the CPU ...
YNN_REDUCE_OFF = "--xla_cpu_experimental_ynn_fusion_type=-reduce"
#: ... and the jaxlib (major, minor) versions that need it and accept it.
YNN_JAXLIB = ((0, 10),)


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


def configure_reduction_fusion() -> bool:
    """Add ``YNN_REDUCE_OFF`` to ``XLA_FLAGS`` under the module docstring's rules (called
    once when photonflow is imported). Returns whether it was added."""
    from jax._src import xla_bridge  # only to ask whether a backend has started

    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_experimental_ynn_fusion_type" in flags or jaxlib_version() not in YNN_JAXLIB:
        return False
    if xla_bridge.backends_are_initialized():
        warnings.warn(f"JAX started before photonflow was imported, so XLA runs without"
                      f" {YNN_REDUCE_OFF}: on the CPU, batched sums of detector size can"
                      f" come out wrong; import photonflow first or set the flag in"
                      f" XLA_FLAGS (photonflow.xla_settings)", RuntimeWarning, stacklevel=2)
        return False
    os.environ["XLA_FLAGS"] = f"{flags} {YNN_REDUCE_OFF}".strip()
    return True
