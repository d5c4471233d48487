"""Limited-memory BFGS steps driven from the host, for objectives whose value and gradient
come from one jitted program: the two-loop recursion over the kept (step, gradient
change) pairs and an Armijo backtracking line search (each shrink from the cubic
through the values and slopes at both ends of the rejected step), on flat float64
vectors.

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


def lbfgs_direction(gradient: np.ndarray, pairs,
                    initial_scale: float | None = None,
                    initial_inverse: np.ndarray | None = None) -> np.ndarray:
    """The L-BFGS search direction -H g (two-loop recursion over ``pairs``, oldest
    first), in the units of the point. The initial inverse Hessian: the matrix
    ``initial_inverse`` (n, n), if given (e.g. the inverse of an approximate Fisher
    information: the pairs then correct a metric that already knows the problem's
    scales and correlations); else the identity scaled by the newest pair's s.y / y.y,
    or without pairs by ``initial_scale``, if given, else by 1 / max(1, |g|)."""
    direction = -np.asarray(gradient, np.float64).copy()
    alphas = []
    for s, y in reversed(pairs):
        alpha = s @ direction / (y @ s)
        direction -= alpha * y
        alphas.append(alpha)
    if initial_inverse is not None:
        direction = np.asarray(initial_inverse, np.float64) @ direction
    elif pairs:
        direction *= pair_scale(pairs)
    elif initial_scale is not None:
        direction *= initial_scale
    else:
        direction /= max(1.0, float(np.linalg.norm(gradient)))
    for (s, y), alpha in zip(pairs, reversed(alphas), strict=True):
        beta = y @ direction / (y @ s)
        direction += (alpha - beta) * s
    return direction


def pair_scale(pairs) -> float:
    """The scale s.y / y.y of the newest (step, gradient change) pair: the inverse
    curvature along it (units of the point squared per unit of the objective)."""
    s, y = pairs[-1]
    return float((s @ y) / (y @ y))


def lbfgs_step(value_and_grad: Callable, point, value: float, gradient, pairs=(),
               memory: int = 10, max_halvings: int = 30,
               min_decrease: float = 0.0, initial_scale: float | None = None,
               initial_inverse: np.ndarray | None = None) -> LBFGSStep:
    """One L-BFGS step from ``point`` (whose objective ``value`` and ``gradient`` are
    known): along ``lbfgs_direction`` (the steepest descent if that does not descend),
    the first of the shrinking step lengths 1, ... (at most ``max_halvings`` trials, each
    shrink by ``shrink_factor``) with a finite value of sufficient decrease (``ARMIJO``)
    is taken, and its pair is kept among the newest ``memory`` when its curvature is
    positive. The search gives up (no step accepted) once a step's first-order decrease
    -slope x length falls below ``min_decrease`` (units of the objective): at a minimum
    within that, shorter steps only spend evaluations. ``initial_scale``: the inverse
    curvature of the first step without pairs (e.g. ``pair_scale`` of an earlier run on
    a similar objective); None: a step of length 1. ``initial_inverse``: the initial
    inverse Hessian as a matrix (``lbfgs_direction``).

    ``value_and_grad(x)``: the objective's value (float) and gradient (array) at a flat
    float64 point ``x``; a non-finite value counts as no decrease.
    """
    point = np.asarray(point, np.float64)
    gradient = np.asarray(gradient, np.float64)
    direction = lbfgs_direction(gradient, pairs, initial_scale, initial_inverse)
    slope = float(gradient @ direction)
    if not slope < 0:
        direction, slope = -gradient, -float(gradient @ gradient)
    scale = 1.0
    for trial in range(1, max_halvings + 1):
        if -scale * slope < min_decrease:
            return LBFGSStep(point, value, gradient, tuple(pairs), trial - 1, False)
        candidate = point + scale * direction
        new_value, new_gradient = value_and_grad(candidate)
        new_value = float(new_value)
        new_gradient = np.asarray(new_gradient, np.float64)
        if np.isfinite(new_value) and new_value <= value + ARMIJO * scale * slope:
            s, y = candidate - point, new_gradient - gradient
            kept = (tuple(pairs) + ((s, y),))[-memory:] if s @ y > MIN_CURVATURE else \
                tuple(pairs)
            return LBFGSStep(candidate, new_value, new_gradient, kept, trial, True)
        scale *= shrink_factor(value, slope, scale, new_value, new_gradient @ direction)
    return LBFGSStep(point, value, gradient, tuple(pairs), max_halvings, False)


def shrink_factor(value: float, slope: float, scale: float, trial_value: float,
                  trial_slope: float) -> float:
    """The factor, in [0.1, 0.5], by which a rejected step length ``scale`` shrinks: the
    minimum of the cubic through the value and slope at 0 (``value``, ``slope`` < 0) and
    at ``scale`` (``trial_value``, ``trial_slope``, both along the direction), clamped;
    0.5 (a halving) where the trial point is not finite or the cubic has no minimum."""
    if not (np.isfinite(trial_value) and np.isfinite(trial_slope)):
        return 0.5
    # the cubic in t = step / scale: c(t) = value + a1 t + a2 t^2 + a3 t^3
    a1 = slope * scale
    b1 = trial_slope * scale
    difference = trial_value - value
    a3 = a1 + b1 - 2.0 * difference
    a2 = difference - a1 - a3
    if abs(a3) < 1e-12 * max(abs(a2), 1e-300):
        t = -a1 / (2.0 * a2) if a2 > 0 else 0.5
    else:
        discriminant = a2 * a2 - 3.0 * a3 * a1
        t = (-a2 + np.sqrt(discriminant)) / (3.0 * a3) if discriminant >= 0 else 0.5
    return float(np.clip(t, 0.1, 0.5)) if np.isfinite(t) else 0.5
