"""What a first call costs besides photonflow's own programs: no small eager programs
(every ``jnp.asarray`` of a numpy array, cast or addition on concrete values outside
``jit`` compiles one of its own in every new process), the run's keys of an event in
one program, and the XLA flags photonflow sets on import (photonflow.xla_settings)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from photonflow import xla_settings
from photonflow.numerics import default_float_dtype, strict_array
from photonflow.transport.pseudo_data import event_keys

pytestmark = pytest.mark.compile_bound

README = Path(__file__).resolve().parents[1] / "README.md"


def _readme_snippet() -> str:
    text = README.read_text()
    return text.split("## Simulating light", 1)[1].split("```python\n", 1)[1].split("```")[0]


def _compiled_programs(code: str) -> tuple[list[str], str]:
    """Names of the programs XLA compiles while ``code`` runs in a fresh process (no
    persistent cache), and what it printed."""
    env = {**os.environ, "PHOTONFLOW_COMPILATION_CACHE": "off", "JAX_LOG_COMPILES": "1"}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=400, check=True)
    return re.findall(r"Finished XLA compilation of jit\((\w+)\)", done.stderr), done.stdout


#: Appended to the README's snippet: what it computed (host-side only: nothing compiles).
README_CHECKS = """
import numpy as _np
assert event.n_hits > 10, event.n_hits
assert all(_np.all(_np.isfinite(_np.asarray(leaf))) for leaf in jax.tree.leaves(gradient))
assert float(gradient.absorption_length) != 0.0
print("README snippet: checked")
"""


def test_readme_snippet_runs_and_compiles_only_photonflows_programs():
    """The README's 'Simulating light' example, as a fresh process: it gives an event
    with hits and finite gradients (a nonzero one in the absorption length), and XLA
    compiles photonflow's own programs only."""
    names, printed = _compiled_programs(_readme_snippet() + README_CHECKS)
    assert "README snippet: checked" in printed, printed
    # before: 39 programs, 30 of them eager casts, additions, key steps and array staging
    eager = {"stage", "add", "broadcast_in_dim", "_threefry_seed", "_threefry_fold_in",
             "_threefry_split", "unstack", "_reduce_max"}
    assert not eager & set(names), names
    own = {"_event_keys", "_transport_source_batch", "expected_jit", "_summed_sensor_nll"}
    assert own <= set(names), names
    # besides them: the cotangent casts of the backward pass and the snippet's own sum
    assert len(names) <= 9, names


def test_strict_array_places_host_values_without_compiling():
    compiled = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, duration, **kw: compiled.append(event)
        if event == "/jax/core/compile/backend_compile_duration" else None)
    values = np.linspace(0.0, 1.0, 13)  # a shape nothing else uses
    before = len(compiled)
    array = strict_array(values)
    scalar = strict_array(2.5)
    assert len(compiled) == before
    assert array.dtype == default_float_dtype() and not array.aval.weak_type
    assert scalar.dtype == default_float_dtype() and not scalar.aval.weak_type
    np.testing.assert_allclose(np.asarray(array), values, rtol=1e-7)
    assert strict_array(array) is array  # right already: returned as it is


def test_strict_array_casts_a_tracer_inside_its_trace():
    def f(x):
        y = strict_array(x * 2, np.float32)
        assert y.dtype == np.float32 and not y.aval.weak_type
        return y.sum()

    assert float(jax.jit(f)(np.arange(3, dtype=np.int32))) == 6.0
    gradient = jax.grad(lambda x: strict_array(x).sum())(np.ones(2, np.float32))
    np.testing.assert_array_equal(np.asarray(gradient), [1.0, 1.0])


@pytest.mark.parametrize("seed", [0, 7, 2**31 + 5, 2**40 + 3, 2**63 - 1])
@pytest.mark.parametrize("index", [0, 9, 2**31 + 1])
def test_event_keys_are_the_documented_split_of_the_run_key(seed, index):
    reference = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(seed), index))
    transport, response = event_keys(seed, index)
    np.testing.assert_array_equal(np.asarray(transport), np.asarray(reference[0]))
    np.testing.assert_array_equal(np.asarray(response), np.asarray(reference[1]))


def test_xla_flag_rules(monkeypatch):
    from jax._src import xla_bridge

    monkeypatch.setenv(xla_settings.ENVIRONMENT, "classic")
    monkeypatch.setattr(xla_settings, "jaxlib_version", lambda: xla_settings.KNOWN_JAXLIB[0])
    monkeypatch.setattr(xla_bridge, "backends_are_initialized", lambda: False)
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/nowhere")
    assert xla_settings.configure_xla_flags()
    assert os.environ["XLA_FLAGS"] == f"--xla_dump_to=/nowhere {xla_settings.CLASSIC_EMITTERS}"
    # already chosen by the user (or by the call above): left alone
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    assert not xla_settings.configure_xla_flags()
    assert os.environ["XLA_FLAGS"] == "--xla_cpu_use_fusion_emitters=true"
    monkeypatch.setenv("XLA_FLAGS", "")
    for setting in ("", "default", "fusion"):  # not asked for: XLA's own choice
        monkeypatch.setenv(xla_settings.ENVIRONMENT, setting)
        assert not xla_settings.configure_xla_flags()
    monkeypatch.setenv(xla_settings.ENVIRONMENT, "classic")
    monkeypatch.setattr(xla_settings, "jaxlib_version", lambda: (99, 0))  # unknown flag set
    assert not xla_settings.configure_xla_flags()
    monkeypatch.setattr(xla_settings, "jaxlib_version", lambda: xla_settings.KNOWN_JAXLIB[0])
    monkeypatch.setattr(xla_bridge, "backends_are_initialized", lambda: True)  # too late
    assert not xla_settings.configure_xla_flags()
    assert os.environ["XLA_FLAGS"] == ""


def test_the_calibration_is_imported_when_first_used():
    code = ("import sys, photonflow as pf; before = 'photonflow.calibration' in sys.modules;"
            " f = pf.calibrate; print(before, 'photonflow.calibration' in sys.modules,"
            " f is pf.calibration.calibrate, 'calibrate' in dir(pf))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=True)
    assert done.stdout.split() == ["False", "True", "True", "True"]
