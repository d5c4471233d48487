"""What identifies the code that computed a result: photonflow's version and a hash of
its installed files (Python sources and shipped data). A resumed reconstruction job
(``photonflow reconstruct --resume``) must run the code of the job it continues, and
exported programs (``photonflow.exported``) are keyed by it."""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

from ._version import __version__

#: The package's folder: every file below it is hashed, compiled bytecode apart.
_PACKAGE = Path(__file__).resolve().parent


@functools.cache
def source_hash() -> str:
    """SHA-256 hex digest of photonflow's files (their paths relative to the package and
    their bytes; ``__pycache__`` left out), computed once per process."""
    digest = hashlib.sha256()
    for path in sorted(_PACKAGE.rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts:
            digest.update(str(path.relative_to(_PACKAGE)).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def code_identity() -> str:
    """The code a result is computed with: ``"photonflow VERSION, files HASH"`` (the
    first 16 hex digits of ``source_hash``)."""
    return f"photonflow {__version__}, files {source_hash()[:16]}"
