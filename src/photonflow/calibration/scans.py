"""One-dimensional likelihood scans, the conventional way to fit one parameter at a time:
a coarse grid, a parabola through the lowest points, a finer parabola around its vertex
whose curvature gives the error (-log L rises by 1/2). Used by the sequential
calibration (``conventional.py``) for every field it scans; coordinates are the
unconstrained ones of ``params.py``."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..params import Params, to_unconstrained
from .layout import free_layout
from .objective import CalibrationProblem

#: Default step of the coarse scan grid in unconstrained units (log for lengths, logit
#: for probabilities, atanh for mie_g).
SCAN_STEP = 0.25


@dataclasses.dataclass(frozen=True)
class ScanResult:
    """Outcome of a one-dimensional likelihood scan (unconstrained coordinates).

    Attributes:
        value: position of the minimum.
        sigma: 1-sigma error from the parabola's curvature (inf if it is not convex).
        n_evaluations: likelihood evaluations used.
        at_edge: the minimum ran into the scan's extension limit.
    """

    value: float
    sigma: float
    n_evaluations: int
    at_edge: bool


def _parabola(u: np.ndarray, f: np.ndarray) -> tuple[float, float]:
    """(vertex, second derivative) of the parabola through three points."""
    a, b, _ = np.polyfit(u - u[1], f - f[1], 2)
    curvature = 2.0 * a
    if curvature <= 0:
        return float(u[np.argmin(f)]), 0.0
    return float(u[1] - b / (2.0 * a)), float(curvature)


def scan_minimum(function: Callable[[float], float], start: float, step: float = SCAN_STEP,
                 max_extensions: int = 8) -> ScanResult:
    """Minimise a 1-D function (-log L in unconstrained coordinates) by scanning.

    A coarse grid of five points ``start + k step`` (k = -2..2), extended by ``step`` while
    the minimum lies on an edge (at most ``max_extensions`` times); the parabola through
    the lowest point and its neighbours; then three points at a quarter step around that
    vertex and their parabola, whose vertex is the result and whose curvature gives the
    1-sigma error (-log L rises by 1/2).
    """
    points = {start + k * step: function(start + k * step) for k in range(-2, 3)}
    at_edge = False
    for _ in range(max_extensions):
        grid = sorted(points)
        best = min(grid, key=points.get)
        if best == grid[0]:
            points[grid[0] - step] = function(grid[0] - step)
        elif best == grid[-1]:
            points[grid[-1] + step] = function(grid[-1] + step)
        else:
            break
    else:
        at_edge = True
    grid = sorted(points)
    index = int(np.clip(np.argmin([points[u] for u in grid]), 1, len(grid) - 2))
    around = np.array(grid[index - 1:index + 2])
    vertex, _ = _parabola(around, np.array([points[u] for u in around]))
    vertex = float(np.clip(vertex, around[0], around[-1]))
    fine = vertex + 0.25 * step * np.array([-1.0, 0.0, 1.0])
    values = np.array([function(u) for u in fine])
    value, curvature = _parabola(fine, values)
    value = float(np.clip(value, fine[0] - step, fine[-1] + step))
    sigma = 1.0 / math.sqrt(curvature) if curvature > 0 else math.inf
    return ScanResult(value, sigma, len(points) + 3, at_edge)


def physical_value(name: str, unconstrained: float, sigma: float, params: Params) -> tuple:
    """(value, error) of field ``name`` in physical units from its unconstrained value
    and error, by the derivative of the inverse transform."""
    base = to_unconstrained(params)
    moved = dataclasses.replace(base, **{name: jnp.asarray(unconstrained, base.efficiency.dtype)})

    def value_of(u):
        return getattr(Params.from_unconstrained(dataclasses.replace(moved, **{name: u})), name)

    point = getattr(moved, name)
    value, slope = jax.jvp(value_of, (point,), (jnp.ones_like(point),))
    return float(value), abs(float(slope)) * sigma


class LikelihoodScanner:
    """-log L of all runs (charge likelihood) as a function of one field, the others at
    ``params``; a new problem per scan, compiled code shared across them. ``evaluations``
    counts the evaluations of -log L of all runs."""

    def __init__(self, detector, prepared, config, key):
        self.detector, self.prepared, self.config, self.key = detector, prepared, config, key
        self.evaluations = 0

    def problem(self, params: Params, name: str) -> CalibrationProblem:
        """The charge-likelihood problem of the runs with only ``name`` free at ``params``."""
        layout = free_layout([name], self.detector.n_sensors)
        return CalibrationProblem(self.detector, self.prepared, params, layout, "charge",
                                  self.config, self.key)

    def loss(self, params: Params) -> float:
        """-log L at ``params``."""
        problem = self.problem(params, "absorption_length")
        self.evaluations += 1
        return problem.value(problem.initial_theta())

    def scan(self, params: Params, name: str, step: float) -> ScanResult:
        """``scan_minimum`` of -log L over field ``name`` (unconstrained, coarse ``step``)."""
        problem = self.problem(params, name)
        dtype = problem.initial_theta()[name].dtype

        def function(u: float) -> float:
            self.evaluations += 1
            return problem.value({name: jnp.asarray(u, dtype)})

        return scan_minimum(function, float(problem.initial_theta()[name]), step)
