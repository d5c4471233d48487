"""The calibration's step rules (photonflow.calibration.methods) on problems whose
minimum is known in closed form: a stand-in problem with the calibration's free-value
layout and an analytic -log L."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from photonflow.calibration.layout import free_layout
from photonflow.calibration.methods import LBFGS, Adam, make_method

N_SENSORS = 6


@dataclasses.dataclass
class _Problem:
    """-log L of free values theta: an ill-conditioned quadratic in the per-sensor
    efficiencies (minimum at ``centre``) plus Rosenbrock's valley in the two dense
    values (minimum at (1, 1))."""

    layout = free_layout(["absorption_length", "scattering_length", "efficiency"], N_SENSORS)
    centre = jnp.linspace(-0.5, 0.5, N_SENSORS)
    curvature = jnp.logspace(0.0, 3.0, N_SENSORS)  # condition number 1,000

    def loss(self, theta):
        a, b = theta["absorption_length"], theta["scattering_length"]
        rosenbrock = (1.0 - a) ** 2 + 100.0 * (b - a * a) ** 2
        quadratic = 0.5 * jnp.sum(self.curvature * (theta["efficiency"] - self.centre) ** 2)
        return rosenbrock + quadratic

    def value(self, theta):
        return float(_LOSS(theta))

    def value_and_grad(self, theta):
        value, gradient = _VALUE_AND_GRAD(theta)
        return float(value), gradient


_LOSS = jax.jit(_Problem.loss.__get__(_Problem()))
_VALUE_AND_GRAD = jax.jit(jax.value_and_grad(_Problem.loss.__get__(_Problem())))


def _start():
    return {"absorption_length": jnp.asarray(-1.2), "scattering_length": jnp.asarray(1.0),
            "efficiency": jnp.zeros(N_SENSORS)}


def _run(method, steps):
    problem = _Problem()
    theta = _start()
    state = method.init(problem, theta)
    values = [problem.value(theta)]
    for _ in range(steps):
        theta, state, step = method.update(problem, theta, state)
        values.append(step.loss)
    return problem, theta, np.asarray(values)


def test_lbfgs_reaches_the_analytic_minimum_without_ever_going_uphill():
    problem, theta, values = _run(LBFGS(), 200)
    assert np.all(np.diff(values) <= 1e-12)  # the Armijo search never accepts an increase
    np.testing.assert_allclose([theta["absorption_length"], theta["scattering_length"]],
                               [1.0, 1.0], atol=1e-3)
    np.testing.assert_allclose(theta["efficiency"], problem.centre, atol=1e-4)
    assert values[-1] < 1e-6


def test_lbfgs_beats_adam_on_the_ill_conditioned_problem():
    """The reason to offer a quasi-Newton rule: in the same number of steps it gets far
    closer to the minimum than first-order steps."""
    _, _, lbfgs = _run(LBFGS(), 60)
    with jax.numpy_dtype_promotion("standard"):  # optax mixes int and float internally
        _, _, adam = _run(Adam(), 60)
    assert lbfgs[-1] < 1e-3 * adam[-1]


@pytest.mark.parametrize("name", ["gauss-newton", "lbfgs", "adam"])
def test_methods_by_name(name):
    assert hasattr(make_method(name), "update")


def test_only_the_curvature_rule_measures_its_steps_in_sigma():
    """The fit's handover to the independent-ray stage and its "no step lowers -log L"
    convergence rest on steps measured in sigma (``StepRule.steps_in_sigma``)."""
    assert make_method("gauss-newton").steps_in_sigma
    assert not make_method("lbfgs").steps_in_sigma
    assert not make_method("adam").steps_in_sigma
