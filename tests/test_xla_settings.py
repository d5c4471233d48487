"""The XLA flag photonflow sets on import for right batched reductions on the CPU
(photonflow.xla_settings)."""

import json
import os
import subprocess
import sys

import pytest

from photonflow import xla_settings

#: A batched reduction of detector size that jaxlib 0.10's YNNPACK fusions got wrong
#: (rows from the third on): a sum over the 8 components of an arrival-time mixture, of 4 events of
#: SK's 11,146 sensors, against the same function called per event.
_BATCHED_SUM = """
import json, numpy as np
import photonflow  # first: its XLA flags are read when JAX starts its backend
import jax, jax.numpy as jnp
from jax.scipy.special import ndtr
n, k, b = 11146, 8, 4
rng = np.random.default_rng(0)
mean = jnp.asarray(rng.uniform(0, 100, (n, k)), jnp.float32)
sigma = jnp.asarray(rng.uniform(1, 5, (n, k)), jnp.float32)
tau = jnp.asarray(np.where(rng.uniform(size=(n, k)) < 0.5, 0, rng.uniform(1, 10, (n, k))),
                  jnp.float32)
weight = jnp.asarray(rng.dirichlet(np.ones(k), n), jnp.float32)
t = jnp.asarray(rng.uniform(0, 100, (b, n)), jnp.float32)
def f(t):
    z = (t[:, None] - mean) / sigma
    ratio = sigma / jnp.where(tau > 0, tau, 1.0)
    tail = jnp.exp(0.5 * ratio * ratio - z * ratio - (z - ratio) ** 2)
    return jnp.sum(weight * (ndtr(z) - tail), axis=1) + t
batched = np.asarray(jax.jit(jax.vmap(f))(t))
single = np.stack([np.asarray(jax.jit(f)(row)) for row in t])
print(json.dumps({"rows_wrong": [int(np.sum(np.abs(batched[i] - single[i]) > 1e-3))
                                 for i in range(b)]}))
"""


def test_a_batched_reduction_of_detector_size_equals_single_calls():
    environment = {key: value for key, value in os.environ.items() if key != "XLA_FLAGS"}
    done = subprocess.run([sys.executable, "-c", _BATCHED_SUM], env=environment,
                          capture_output=True, text=True, timeout=300, check=True)
    rows_wrong = json.loads(done.stdout.strip().splitlines()[-1])["rows_wrong"]
    assert rows_wrong == [0, 0, 0, 0]


def test_reduction_flag_rules(monkeypatch):
    from jax._src import xla_bridge

    monkeypatch.setattr(xla_settings, "jaxlib_version", lambda: xla_settings.YNN_JAXLIB[0])
    monkeypatch.setattr(xla_bridge, "backends_are_initialized", lambda: False)
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/nowhere")
    assert xla_settings.configure_reduction_fusion()
    assert os.environ["XLA_FLAGS"] == f"--xla_dump_to=/nowhere {xla_settings.YNN_REDUCE_OFF}"
    # already set (by the user, or by the call above): left alone
    assert not xla_settings.configure_reduction_fusion()
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_experimental_ynn_fusion_type=dot")
    assert not xla_settings.configure_reduction_fusion()
    monkeypatch.setenv("XLA_FLAGS", "")
    monkeypatch.setattr(xla_settings, "jaxlib_version", lambda: (99, 0))  # flag unknown
    assert not xla_settings.configure_reduction_fusion()
    monkeypatch.setattr(xla_settings, "jaxlib_version", lambda: xla_settings.YNN_JAXLIB[0])
    monkeypatch.setattr(xla_bridge, "backends_are_initialized", lambda: True)  # too late
    with pytest.warns(RuntimeWarning, match="import photonflow first"):
        assert not xla_settings.configure_reduction_fusion()
    assert os.environ["XLA_FLAGS"] == ""
