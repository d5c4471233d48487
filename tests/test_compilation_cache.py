"""The persistent compilation cache (photonflow.compilation_cache): where it goes, how the
environment turns it off or moves it, and that a second process loads what the first
compiled. Each case is a fresh Python process, as the cache is set when photonflow is
imported."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

#: Prints the cache directory JAX uses after ``import photonflow`` ("None" if off).
SHOW = "import jax, photonflow; print(jax.config.jax_compilation_cache_dir)"

#: Compiles one small program (cached whatever its compile time) and prints how many
#: programs were loaded from the persistent cache.
COMPILE = """
import jax, jax.numpy as jnp
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
import photonflow
hits = []
jax.monitoring.register_event_listener(
    lambda event, **kw: hits.append(event) if event.endswith("cache_hits") else None)
print(float(jax.jit(lambda x: jnp.sin(x).sum() * 3.0)(jnp.arange(7.0))), len(hits))
"""


def _run(code: str, tmp_path: Path, **environment: str) -> str:
    env = {k: v for k, v in os.environ.items()
           if k not in ("PHOTONFLOW_COMPILATION_CACHE", "JAX_COMPILATION_CACHE_DIR")}
    env.update(XDG_CACHE_HOME=str(tmp_path / "xdg"), **environment)
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=120, check=True)
    return done.stdout.strip().splitlines()[-1]


def test_default_directory_is_in_the_users_cache(tmp_path):
    assert _run(SHOW, tmp_path) == str(tmp_path / "xdg" / "photonflow" / "jax")


@pytest.mark.parametrize("setting", ["off", "0", "false", ""])
def test_environment_turns_the_cache_off(tmp_path, setting):
    assert _run(SHOW, tmp_path, PHOTONFLOW_COMPILATION_CACHE=setting) == "None"


def test_environment_moves_the_cache_and_a_jax_setting_is_kept(tmp_path):
    assert _run(SHOW, tmp_path, PHOTONFLOW_COMPILATION_CACHE=str(tmp_path / "here")) == str(
        tmp_path / "here")
    assert _run(SHOW, tmp_path, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "jax")) == str(
        tmp_path / "jax")


def test_a_second_process_loads_the_compiled_program(tmp_path):
    directory = tmp_path / "cache"
    first = _run(COMPILE, tmp_path, PHOTONFLOW_COMPILATION_CACHE=str(directory))
    assert first.split()[1] == "0"
    assert any(directory.iterdir())
    second = _run(COMPILE, tmp_path, PHOTONFLOW_COMPILATION_CACHE=str(directory))
    assert second.split()[0] == first.split()[0]
    assert int(second.split()[1]) >= 1


def test_programs_of_20_ms_are_kept_unless_jax_is_told_otherwise(tmp_path):
    threshold = ("import jax, photonflow;"
                 " print(jax.config.jax_persistent_cache_min_compile_time_secs)")
    assert float(_run(threshold, tmp_path)) == 0.02
    assert float(_run(threshold, tmp_path, PHOTONFLOW_COMPILATION_CACHE="off")) == 1.0
    assert float(_run(threshold, tmp_path,
                      JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="3")) == 3.0
