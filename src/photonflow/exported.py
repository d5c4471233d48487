"""Traced programs kept on disk beside the persistent compilation cache (``jax.export``).

A new process that finds a program in the compilation cache still traces and lowers it
before it can look the compiled code up. For programs that are never differentiated
(the sampled mode's photon batches), ``call_exported`` keeps the traced and lowered
program itself as a ``jax.export`` artifact in ``<compilation cache>/photonflow-exported``,
so a later process loads it (kilobytes, milliseconds) instead of tracing and lowering;
the compiled code then comes from the compilation cache as before. On the 2-core
machine this takes the README snippet's sampling from ~0.6 s to ~0.25 s in a warm
process (docs/performance.md).

An artifact is keyed by the program's name and static settings, the arguments' tree
structure, shapes and dtypes, the JAX and jaxlib versions, the backend, the 64-bit
mode and a hash of photonflow's files (``provenance.source_hash``), so a changed
program never loads a stale artifact. Without a compilation-cache directory, or when
anything about the artifact fails (unreadable, incompatible, not exportable), the plain
jitted call runs: the results are the same either way (tested bit for bit). Written here
because JAX keeps no cache of traced programs across processes.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import jax
import jaxlib
import numpy as np
from jax import export as jax_export

from .provenance import source_hash

#: Subdirectory of the compilation-cache directory that holds the artifacts.
SUBDIRECTORY = "photonflow-exported"

#: Artifacts loaded or made by this process, by key.
_LOADED: dict[str, jax_export.Exported] = {}


def artifact_directory() -> Path | None:
    """Where artifacts live: ``SUBDIRECTORY`` of JAX's compilation-cache directory, or
    None when no compilation cache is configured (``photonflow.compilation_cache``)."""
    cache = jax.config.jax_compilation_cache_dir
    return Path(cache) / SUBDIRECTORY if cache else None


def call_exported(name: str, function, static, *args):
    """``function(*args)``, through its exported program when ``artifact_directory()`` is
    set (module docstring).

    Args:
        name: the program's name (part of the artifact's file name).
        function: a jitted function with its static arguments bound (e.g. a
            ``functools.partial``), called with ``args`` (pytrees of arrays).
        static: hashable, deterministic ``repr``: everything ``function`` depends on
            beyond the arguments' shapes and dtypes (its static arguments).
    """
    directory = artifact_directory()
    if directory is None:
        return function(*args)
    leaves, treedef = jax.tree.flatten(args)
    key = _key(name, static, treedef, leaves)
    exported = _LOADED.get(key)
    if exported is None:
        exported = _load_or_export(directory / f"{name}-{key[:32]}.jax", function, treedef,
                                   leaves)
        if exported is None:
            return function(*args)
        _LOADED[key] = exported
    return exported.call(*leaves)


def _key(name: str, static, treedef, leaves) -> str:
    """The artifact's key: a hash of everything the traced program depends on."""
    avals = [(np.shape(leaf), str(leaf.dtype if hasattr(leaf, "dtype") else type(leaf)),
              bool(getattr(getattr(leaf, "aval", None), "weak_type", False)))
             for leaf in leaves]
    parts = (name, repr(static), str(treedef), avals, jax.__version__, jaxlib.__version__,
             jax.default_backend(), bool(jax.config.jax_enable_x64), source_hash())
    return hashlib.sha256(repr(parts).encode()).hexdigest()


def _load_or_export(path: Path, function, treedef, leaves) -> jax_export.Exported | None:
    """The artifact at ``path``, or a new one exported from ``function`` and written there
    (atomically: a partial file is never read); None when neither works."""
    try:
        return jax_export.deserialize(bytearray(path.read_bytes()))
    except Exception:  # noqa: BLE001 (absent, unreadable or incompatible: export anew)
        pass
    try:
        flat = jax.jit(lambda *flat: function(*jax.tree.unflatten(treedef, flat)))
        exported = jax_export.export(flat)(*leaves)
    except Exception:  # noqa: BLE001 (a cache only: the plain call runs instead)
        return None
    partial = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial.write_bytes(exported.serialize())
        os.replace(partial, path)
    except Exception:  # noqa: BLE001 (not written: this process still uses the artifact)
        partial.unlink(missing_ok=True)
    return exported
