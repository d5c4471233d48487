"""Step rules of a calibration, each an object with ``init`` and ``update``.

``update(problem, theta, state) -> (theta, state, Step)`` takes one step from free
values ``theta`` (unconstrained) and reports the loss and how far it moved, so one
loop (``fit.calibrate``) drives them all:

- ``GaussNewton``: Fisher scoring on the expected Fisher information (charge, or
  charge and first-hit time) in a Levenberg-Marquardt trust region (a step never
  increases -log L), each step solved in the per-sensor block structure; a handful of
  steps. Default.
- ``LBFGS``: limited-memory BFGS steps with a backtracking (Armijo) line search.
- ``Adam``: ``optax.adam`` steps, for very large problems where even one curvature is
  too costly.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError, format_value
from ..lbfgs import lbfgs_step
from .objective import CalibrationProblem


class StepRule(Protocol):
    """What ``fit.calibrate`` needs of a step rule.

    ``steps_in_sigma``: ``Step.step_size`` is in units of the free values' 1-sigma
    uncertainties (a second-order rule that knows the curvature). Only then does the fit
    treat a step below ``HANDOVER_SIGMA`` as the moment to hand over to the
    independent-ray stage, and "no step lowers -log L further" as convergence; a rule
    without the attribute counts as False.
    """

    steps_in_sigma: ClassVar[bool]

    def init(self, problem: CalibrationProblem, theta: dict) -> dict[str, Any]: ...

    def update(self, problem: CalibrationProblem, theta: dict, state: dict): ...


@dataclasses.dataclass(frozen=True)
class Step:
    """What one update did.

    Attributes:
        loss: -log L after the step.
        loss_change: loss before minus loss after (>= 0 for an accepted step).
        step_size: largest |change| of a free value in units of its 1-sigma uncertainty
            when the method knows it (Gauss-Newton), else in unconstrained units.
    """

    loss: float
    loss_change: float
    step_size: float


def _add(theta: dict, delta: dict, scale: float = 1.0) -> dict:
    return {name: theta[name] + scale * delta[name] for name in theta}


def _flat(problem: CalibrationProblem, theta: dict) -> np.ndarray:
    dense, sensor = problem.layout.split(theta)
    return np.concatenate([np.asarray(dense, np.float64), np.asarray(sensor, np.float64).ravel()])


def _unflat(problem: CalibrationProblem, vector: np.ndarray, dtype) -> dict:
    layout = problem.layout
    dense = jnp.asarray(vector[: layout.n_dense], dtype)
    sensor = jnp.asarray(
        vector[layout.n_dense:].reshape(layout.n_sensors, len(layout.sensor_fields)), dtype
    )
    return layout.join(dense, sensor)


def _dtype(theta: dict):
    return jnp.result_type(*theta.values())


def take_step(problem: CalibrationProblem, theta: dict, step_dense, step_sensor) -> dict:
    """``theta`` moved by a step given as (dense (P,), per-sensor (N, F)) numpy arrays."""
    dtype = _dtype(theta)
    delta = problem.layout.join(jnp.asarray(step_dense, dtype), jnp.asarray(step_sensor, dtype))
    return _add(theta, delta)


def sigma_step_size(curvature, step_dense, step_sensor) -> float:
    """Largest |step| of a free value in units of its 1-sigma error from ``curvature``'s
    inverse (0 where that error is 0)."""
    dense_var, sensor_var = curvature.covariance()
    sigma = np.concatenate(
        [np.sqrt(np.abs(np.diag(dense_var))), np.sqrt(np.abs(sensor_var)).ravel()]
    )
    moved = np.concatenate([np.abs(step_dense), np.abs(step_sensor).ravel()])
    return float(np.max(moved / np.where(sigma > 0, sigma, np.inf), initial=0.0))


def _predicted_decrease(curvature, grad_dense, grad_sensor, step_dense, step_sensor) -> float:
    """Decrease of -log L that the quadratic model g.d + d.H.d / 2 predicts for step d."""
    full = curvature.multiply(step_dense, step_sensor)
    linear = float(grad_dense @ step_dense + np.sum(grad_sensor * step_sensor))
    quadratic = float(step_dense @ full[0] + np.sum(step_sensor * full[1]))
    return -(linear + 0.5 * quadratic)


@dataclasses.dataclass(frozen=True)
class GaussNewton:
    """Fisher scoring (a Gauss-Newton step on the expected Fisher information) inside a
    Levenberg-Marquardt trust region.

    Every step solves (H + damping diag H) d = -g; it is taken only if -log L does not
    increase, else the damping grows (x4) and the step is solved again. After an
    accepted step the damping shrinks (/3) when the decrease matched the quadratic
    model's prediction well (ratio > 0.75), stays for a fair match and grows (x2) for a
    poor one (< 0.25).

    Attributes:
        damping: initial Levenberg-Marquardt damping (relative to the diagonal).
        max_retries: damping increases (x4) tried per step before giving up.
    """

    steps_in_sigma: ClassVar[bool] = True
    damping: float = 1e-3
    max_retries: int = 12

    def init(self, problem: CalibrationProblem, theta: dict) -> dict[str, Any]:
        """State: the current damping and the last curvature (None before a step)."""
        return {"damping": self.damping, "curvature": None}

    def update(self, problem: CalibrationProblem, theta: dict, state: dict):
        """One accepted damped step (or a zero step if none lowers the loss)."""
        value, grad_dense, grad_sensor, curvature = problem.curvature(theta)
        curvature = curvature.positive()
        damping = state["damping"]
        for _ in range(self.max_retries):
            step_dense, step_sensor = curvature.damped(damping).solve(-grad_dense, -grad_sensor)
            candidate = take_step(problem, theta, step_dense, step_sensor)
            new_value = problem.value(candidate)
            if np.isfinite(new_value) and new_value <= value:
                predicted = _predicted_decrease(
                    curvature, grad_dense, grad_sensor, step_dense, step_sensor
                )
                ratio = (value - new_value) / predicted if predicted > 0 else 1.0
                factor = 1.0 / 3.0 if ratio > 0.75 else (2.0 if ratio < 0.25 else 1.0)
                size = sigma_step_size(curvature, step_dense, step_sensor)
                new_state = {
                    "damping": min(max(damping * factor, 1e-9), 1e9), "curvature": curvature
                }
                return candidate, new_state, Step(new_value, value - new_value, size)
            damping = max(damping, 1e-6) * 4.0
        return theta, {"damping": damping, "curvature": curvature}, Step(value, 0.0, 0.0)


@dataclasses.dataclass(frozen=True)
class LBFGS:
    """Limited-memory BFGS with a backtracking line search.

    Attributes:
        memory: number of (step, gradient change) pairs kept.
        max_halvings: line-search trials (each shrinking the step by 0.1-0.5, as
            ``lbfgs.shrink_factor`` says) before giving up a step.
    """

    steps_in_sigma: ClassVar[bool] = False
    memory: int = 10
    max_halvings: int = 30

    def init(self, problem: CalibrationProblem, theta: dict) -> dict[str, Any]:
        """State: the loss and flat gradient at ``theta`` and the memory pairs."""
        value, gradient = problem.value_and_grad(theta)
        return {"value": value, "gradient": _flat(problem, gradient), "pairs": ()}

    def update(self, problem: CalibrationProblem, theta: dict, state: dict):
        """One L-BFGS step with an Armijo backtracking search (``lbfgs.lbfgs_step``)."""
        dtype = _dtype(theta)

        def value_and_grad(x):
            value, gradient = problem.value_and_grad(_unflat(problem, x, dtype))
            return value, _flat(problem, gradient)

        x0 = _flat(problem, theta)
        step = lbfgs_step(value_and_grad, x0, state["value"], state["gradient"],
                          state["pairs"], self.memory, self.max_halvings)
        if not step.accepted:
            return theta, state, Step(state["value"], 0.0, 0.0)
        new_state = {"value": step.value, "gradient": step.gradient, "pairs": step.pairs}
        size = float(np.max(np.abs(step.point - x0), initial=0.0))
        return (_unflat(problem, step.point, dtype), new_state,
                Step(step.value, state["value"] - step.value, size))


@dataclasses.dataclass(frozen=True)
class Adam:
    """First-order steps from ``optax.adam``.

    Attributes:
        learning_rate: step size in unconstrained units.
    """

    steps_in_sigma: ClassVar[bool] = False
    learning_rate: float = 0.02

    def _optimizer(self):
        import optax

        return optax.adam(self.learning_rate)

    def init(self, problem: CalibrationProblem, theta: dict) -> dict[str, Any]:
        """State: optax's state and the loss at ``theta``."""
        return {"optax": self._optimizer().init(theta), "value": problem.value(theta)}

    def update(self, problem: CalibrationProblem, theta: dict, state: dict):
        """One Adam step (always taken)."""
        value, gradient = problem.value_and_grad(theta)
        updates, optax_state = self._optimizer().update(gradient, state["optax"], theta)
        new_theta = jax.tree.map(jnp.add, theta, updates)
        size = max(float(jnp.max(jnp.abs(u))) for u in jax.tree.leaves(updates))
        new_value = problem.value(new_theta)
        return new_theta, {"optax": optax_state, "value": new_value}, Step(
            new_value, value - new_value, size
        )


#: Method names accepted by ``calibrate(method=...)`` and ``photonflow calibrate``.
METHODS = {"gauss-newton": GaussNewton, "lbfgs": LBFGS, "adam": Adam}


def make_method(method) -> StepRule:
    """A step rule from a name in ``METHODS`` or a step-rule object (returned as is)."""
    if isinstance(method, str):
        if method not in METHODS:
            raise ConfigError(
                f"method = {format_value(method)}: must be one of {', '.join(METHODS)}"
            )
        return METHODS[method]()
    if not all(hasattr(method, name) for name in ("init", "update")):
        raise ConfigError(f"method = {format_value(method)}: needs init and update")
    return method
