"""``inline_jit``: ``jax.jit`` for calls from Python, the plain function inside a trace.

A jitted function called inside another jitted function is a nested program: JAX
traces it into a jaxpr of its own and, under ``grad``, linearises that jaxpr again
equation by equation. XLA inlines the nested program anyway, so under an outer ``jit``
the boundary buys nothing and costs trace time. Measured on the toy cylinder's
value-and-gradient of the expected mode's likelihood (2 bounces, probes, mirror
quadrature): 10.6 s to trace with the nested programs, 5.9 s with them inlined; the
same values. ``jax.jit(..., inline=True)`` still builds the nested jaxpr (8.1 s).

JAX has no public "am I under a jit" test; ``inline_jit`` asks its private one where
it exists and otherwise keeps the nested program (the behaviour of plain ``jax.jit``).
Eager autodiff (``jax.grad`` with no ``jit`` around it) keeps the nested program too:
run inline, every operation would be dispatched on its own.
"""

from __future__ import annotations

import functools

import jax

try:  # private, present in the JAX versions this package is tested with
    from jax._src.core import unsafe_am_i_under_a_jit as _under_jit
except ImportError:  # pragma: no cover - older or newer JAX: always the nested program
    def _under_jit() -> bool:
        return False


class InlineJit:
    """A function with ``jax.jit``'s behaviour from Python and inlined in a trace;
    attributes (``lower``, ``trace``, ``_cache_size``) are the jitted function's."""

    def __init__(self, function, **jit_options):
        self.function = function
        self.jitted = jax.jit(function, **jit_options)
        functools.update_wrapper(self, function)

    def __call__(self, *args, **kwargs):
        if _under_jit():
            return self.function(*args, **kwargs)
        return self.jitted(*args, **kwargs)

    def __getattr__(self, name):
        if name in ("function", "jitted"):  # not yet set (a copy being built)
            raise AttributeError(name)
        return getattr(self.jitted, name)


def inline_jit(function=None, **jit_options):
    """``jax.jit(function, **jit_options)`` (used bare or with options, as a decorator)
    that runs ``function`` inline when called inside another jitted function's trace."""
    if function is None:
        return functools.partial(inline_jit, **jit_options)
    return InlineJit(function, **jit_options)
