"""Names a package imports when they are first used (PEP 562), so that ``import`` stays
cheap: ``photonflow`` defers the calibration and the event files, ``photonflow.io`` its
h5py modules."""

from __future__ import annotations

import importlib
import sys


def lazy_names(package: str, names: dict[str, str]):
    """The module-level ``(__getattr__, __dir__)`` of ``package`` (its ``__name__``) that
    import ``names`` (name -> submodule, relative to the package) on first use and keep
    them as module attributes from then on."""

    def __getattr__(name: str):
        if name in names:
            value = getattr(importlib.import_module(f".{names[name]}", package), name)
            setattr(sys.modules[package], name, value)
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(names))

    return __getattr__, __dir__
