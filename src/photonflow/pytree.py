"""Immutable dataclasses registered as JAX pytrees.

Fields marked ``static_field()`` are part of the tree structure (hashable, compared
by value, changing them recompiles a jitted function); all other fields are leaves
(arrays one may differentiate; changing their values never recompiles).
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax

T = TypeVar("T")

_STATIC = "photonflow_static"


def static_field(**kwargs: Any) -> Any:
    """A dataclass field that is static configuration, not a pytree leaf."""
    metadata = dict(kwargs.pop("metadata", {}) or {})
    metadata[_STATIC] = True
    return dataclasses.field(metadata=metadata, **kwargs)


def pytree_dataclass(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen dataclass and register it with JAX as a pytree.

    Example::

        @pytree_dataclass
        class Source:
            position: jax.Array              # leaf, m
            name: str = static_field(default="laser")
    """
    cls = dataclasses.dataclass(frozen=True, eq=False)(cls)
    fields = dataclasses.fields(cls)
    data = [f.name for f in fields if not f.metadata.get(_STATIC, False)]
    meta = [f.name for f in fields if f.metadata.get(_STATIC, False)]
    jax.tree_util.register_dataclass(cls, data_fields=data, meta_fields=meta)
    return cls


def replace(obj: T, **changes: Any) -> T:
    """Return a copy of a pytree dataclass with some fields changed."""
    return dataclasses.replace(obj, **changes)
