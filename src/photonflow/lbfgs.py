"""Limited-memory BFGS steps driven from the host, for objectives whose value and gradient
come from one jitted program: the two-loop recursion over the kept (step, gradient
change) pairs and an Armijo backtracking line search, on flat float64 vectors.

Written here rather than taken from ``optax.lbfgs`` because that runs its zoom line
search inside the jitted step, which traces the objective's value and gradient three
times (at the start, at the first trial point and in the search loop): the compiled
step holds three copies of the gradient program, and compiling it takes ~3 times as
long (a track likelihood of the toy detector: 31 s against 13 s). Here the objective
is compiled once, and each trial point costs one call of it. Used by the calibration's
``LBFGS`` step rule and by the reconstruction's gradient fit.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

#: Sufficient decrease of the Armijo condition: value(x + a d) <= value(x) + ARMIJO a g.d.
ARMIJO = 1e-4
#: A (step, gradient change) pair is kept only if their product exceeds this (positive
#: curvature along the step keeps the inverse-Hessian estimate positive definite).
MIN_CURVATURE = 1e-12


@dataclasses.dataclass(frozen=True)
class LBFGSStep:
    """The outcome of one ``lbfgs_step``.

    Attributes:
        point: the new point (the old one if no step was accepted), float64.
        value: the objective there.
        gradient: its gradient there, float64.
        pairs: the (step, gradient change) pairs to pass to the next step.
        evaluations: calls of the objective the line search made.
        accepted: whether a point with sufficient decrease was found.
    """

    point: np.ndarray
    value: float
    gradient: np.ndarray
    pairs: tuple
    evaluations: int
    accepted: bool


def lbfgs_direction(gradient: np.ndarray, pairs) -> np.ndarray:
    """The L-BFGS search direction -H g (two-loop recursion over ``pairs``, oldest
    first; the initial inverse Hessian scaled by the newest pair's s.y / y.y, or by
    1 / max(1, |g|) without pairs), in the units of the point."""
    direction = -np.asarray(gradient, np.float64).copy()
    alphas = []
    for s, y in reversed(pairs):
        alpha = s @ direction / (y @ s)
        direction -= alpha * y
        alphas.append(alpha)
    if pairs:
        s, y = pairs[-1]
        direction *= (s @ y) / (y @ y)
    else:
        direction /= max(1.0, float(np.linalg.norm(gradient)))
    for (s, y), alpha in zip(pairs, reversed(alphas), strict=True):
        beta = y @ direction / (y @ s)
        direction += (alpha - beta) * s
    return direction


def lbfgs_step(value_and_grad: Callable, point, value: float, gradient, pairs=(),
               memory: int = 10, max_halvings: int = 30) -> LBFGSStep:
    """One L-BFGS step from ``point`` (whose objective ``value`` and ``gradient`` are
    known): along ``lbfgs_direction`` (the steepest descent if that does not descend),
    the first of the step lengths 1, 1/2, 1/4, ... (at most ``max_halvings``) with a
    finite value of sufficient decrease (``ARMIJO``) is taken, and its pair is kept
    among the newest ``memory`` when its curvature is positive.

    ``value_and_grad(x)``: the objective's value (float) and gradient (array) at a flat
    float64 point ``x``; a non-finite value counts as no decrease.
    """
    point = np.asarray(point, np.float64)
    gradient = np.asarray(gradient, np.float64)
    direction = lbfgs_direction(gradient, pairs)
    slope = float(gradient @ direction)
    if not slope < 0:
        direction, slope = -gradient, -float(gradient @ gradient)
    scale = 1.0
    for trial in range(1, max_halvings + 1):
        candidate = point + scale * direction
        new_value, new_gradient = value_and_grad(candidate)
        new_value = float(new_value)
        if np.isfinite(new_value) and new_value <= value + ARMIJO * scale * slope:
            new_gradient = np.asarray(new_gradient, np.float64)
            s, y = candidate - point, new_gradient - gradient
            kept = (tuple(pairs) + ((s, y),))[-memory:] if s @ y > MIN_CURVATURE else \
                tuple(pairs)
            return LBFGSStep(candidate, new_value, new_gradient, kept, trial, True)
        scale *= 0.5
    return LBFGSStep(point, value, gradient, tuple(pairs), max_halvings, False)
