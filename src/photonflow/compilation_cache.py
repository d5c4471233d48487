"""The persistent compilation cache: XLA programs compiled once are kept on disk and
reused by later processes.

Most of the time of a first call of the expected mode (or its gradient) is XLA
compiling it; with the cache a second process loads the compiled program instead
(docs/performance.md). photonflow turns JAX's persistent cache on when it is imported,
in ``~/.cache/photonflow/jax`` (``$XDG_CACHE_HOME/photonflow/jax`` where that is set),
unless the environment says otherwise:

- ``PHOTONFLOW_COMPILATION_CACHE=off`` (or ``0``, ``false``, ``no``, empty): no cache;
- ``PHOTONFLOW_COMPILATION_CACHE=/some/dir``: that directory;
- a cache directory already configured for JAX (``JAX_COMPILATION_CACHE_DIR`` or
  ``jax.config.update("jax_compilation_cache_dir", ...)`` before the import) is kept.

Programs that took 20 ms or more to compile are kept (JAX's own threshold, 1 s, is
only ever lowered, and ``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS`` wins). A
directory that cannot be created leaves the cache off (it only saves time).
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

#: Environment variable that turns the cache off or moves it.
ENVIRONMENT = "PHOTONFLOW_COMPILATION_CACHE"
_OFF = {"", "0", "off", "false", "no", "none"}
#: Programs that took at least this long (s) to compile are kept (JAX's default is 1 s;
#: the likelihood, the sampled mode's pieces and an event's keys take 0.05-0.5 s to compile
#: and are loaded in a few ms).
MIN_COMPILE_SECONDS = 0.02


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/photonflow/jax``, or ``~/.cache/photonflow/jax``."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "photonflow" / "jax"


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Keep compiled XLA programs in ``path`` (default ``default_cache_dir()``) for later
    processes. Returns the directory, or None when it cannot be created."""
    directory = Path(path).expanduser() if path is not None else default_cache_dir()
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(directory))
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:  # only ever lowered
        threshold = jax.config.jax_persistent_cache_min_compile_time_secs
        jax.config.update("jax_persistent_cache_min_compile_time_secs",
                          min(threshold, MIN_COMPILE_SECONDS))
    return directory


def configure_from_environment() -> Path | None:
    """Apply the rules of the module docstring (called once when photonflow is
    imported). Returns the cache directory in use, or None."""
    setting = os.environ.get(ENVIRONMENT)
    if setting is not None and setting.strip().lower() in _OFF:
        return None
    configured = jax.config.jax_compilation_cache_dir
    if configured and setting is None:
        return Path(configured)
    return enable_compilation_cache(setting)
