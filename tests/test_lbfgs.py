"""The host-side L-BFGS step (photonflow.lbfgs) on objectives with known minima."""

from __future__ import annotations

import numpy as np
import pytest

from photonflow.lbfgs import ARMIJO, lbfgs_direction, lbfgs_step, shrink_factor


def rosenbrock(x):
    """Rosenbrock's valley (minimum 0 at (1, 1)) and its gradient."""
    value = (1.0 - x[0]) ** 2 + 100.0 * (x[1] - x[0] ** 2) ** 2
    gradient = np.array([-2.0 * (1.0 - x[0]) - 400.0 * x[0] * (x[1] - x[0] ** 2),
                         200.0 * (x[1] - x[0] ** 2)])
    return value, gradient


def minimise(objective, start, steps):
    point = np.asarray(start, np.float64)
    value, gradient = objective(point)
    pairs, values = (), [value]
    for _ in range(steps):
        step = lbfgs_step(objective, point, value, gradient, pairs)
        assert step.accepted
        assert step.value <= value  # never uphill
        point, value, gradient, pairs = step.point, step.value, step.gradient, step.pairs
        values.append(value)
    return point, values


def test_rosenbrock_from_the_classic_start_reaches_the_minimum():
    point, _ = minimise(rosenbrock, [-1.2, 1.0], 60)
    np.testing.assert_allclose(point, [1.0, 1.0], atol=1e-6)


def test_an_ill_conditioned_quadratic_is_minimised_in_few_steps():
    """On a quadratic of condition number 1,000 in 6 dimensions the kept pairs rebuild
    the inverse Hessian: the gradient falls by 1e-8 within 40 steps (24 measured;
    steepest descent needs ~10^4)."""
    curvature = np.logspace(0.0, 3.0, 6)
    centre = np.linspace(-0.5, 0.5, 6)

    def quadratic(x):
        return 0.5 * np.sum(curvature * (x - centre) ** 2), curvature * (x - centre)

    point, _ = minimise(quadratic, np.zeros(6), 40)
    assert np.linalg.norm(quadratic(point)[1]) < 1e-8 * np.linalg.norm(quadratic(np.zeros(6))[1])


def test_the_search_backs_out_of_a_region_where_the_objective_is_not_finite():
    """Beyond x = 0.5 the objective is NaN: the step lengths shrink (by halves, with no
    finite value to fit) until the trial point is finite and lowers it by the Armijo
    condition."""
    def fenced(x):
        if x[0] > 0.5:
            return float("nan"), np.full(1, np.nan)
        return (x[0] - 2.0) ** 2, 2.0 * (x - 2.0)

    value, gradient = fenced(np.zeros(1))
    step = lbfgs_step(fenced, np.zeros(1), value, gradient)
    assert step.accepted and 0.0 < step.point[0] <= 0.5 and step.evaluations > 1
    slope = float(gradient @ lbfgs_direction(gradient, ()))
    assert step.value <= value + ARMIJO * (step.point[0] / lbfgs_direction(gradient, ())[0]) * slope


def test_a_pair_of_negative_curvature_is_not_kept_and_no_decrease_is_reported():
    """On a concave stretch the step is taken but its (s, y) pair is dropped; at a
    maximum of a function bounded above nothing lowers it after the allowed halvings."""
    def concave(x):
        return -float(x @ x), -2.0 * x

    value, gradient = concave(np.array([0.3]))
    step = lbfgs_step(concave, np.array([0.3]), value, gradient)
    assert step.accepted and step.pairs == ()

    def flat(x):
        return 0.0, np.ones(1)  # a gradient that promises a decrease the values never give

    step = lbfgs_step(flat, np.zeros(1), 0.0, np.ones(1), max_halvings=5)
    assert not step.accepted and step.evaluations == 5
    np.testing.assert_array_equal(step.point, np.zeros(1))


def test_a_rejected_step_shrinks_to_the_minimum_of_the_fitted_cubic():
    """Along a quadratic (x - 0.3)^2 from 0 with a unit trial step, the cubic through both
    ends' values and slopes is the quadratic itself: the next step length is 0.3. On
    x^3 - x from 0 with a trial step of 2 it is the cubic, minimal at 1/sqrt(3) (a
    factor 0.2887). Factors are clamped to [0.1, 0.5]: a halving when the cubic's
    minimum lies beyond half the step, a tenth when it lies very close to 0, a halving
    when the trial value is not finite."""
    assert shrink_factor(0.09, -0.6, 1.0, 0.49, 1.4) == pytest.approx(0.3, rel=1e-12)
    assert shrink_factor(0.0, -1.0, 2.0, 6.0, 11.0) == pytest.approx(
        1.0 / np.sqrt(3.0) / 2.0, rel=1e-12)
    # (x - 0.9)^2 from 0, trial step 1: minimum at 0.9 of the step, beyond half
    assert shrink_factor(0.81, -1.8, 1.0, 0.01, 0.2) == 0.5
    # (x - 0.01)^2: minimum at 0.01 of the step
    assert shrink_factor(1e-4, -0.02, 1.0, 0.9801, 1.98) == 0.1
    assert shrink_factor(0.0, -1.0, 1.0, float("nan"), float("nan")) == 0.5


def test_a_search_stops_where_no_step_could_lower_the_objective_by_min_decrease():
    """At a point whose full step promises a first-order decrease of 1e-3 (slope -1e-3 at
    unit length), a search with min_decrease = 1e-2 evaluates nothing; with 1e-4 it
    evaluates and takes the step; on the flat function of the test above it stops after
    the one trial whose promised decrease is above min_decrease."""
    def quadratic(x):
        return float(0.5 * x @ x), x.copy()

    point = np.array([1e-3 ** 0.5])  # gradient norm^2 = 1e-3: slope -1e-3 along -g
    value, gradient = quadratic(point)
    calls = []

    def counted(x):
        calls.append(x)
        return quadratic(x)

    step = lbfgs_step(counted, point, value, gradient, min_decrease=1e-2)
    assert not step.accepted and step.evaluations == 0 and not calls
    step = lbfgs_step(counted, point, value, gradient, min_decrease=1e-4)
    assert step.accepted and step.value < value

    def flat(x):
        return 0.0, np.ones(1)

    step = lbfgs_step(flat, np.zeros(1), 0.0, np.ones(1), min_decrease=0.6)
    # the unit step promises 1 and is tried; a shrink by at most 0.5 promises < 0.6
    assert not step.accepted and step.evaluations == 1


def test_an_initial_inverse_hessian_matrix_takes_a_quadratic_to_its_minimum_at_once():
    """With the exact inverse Hessian of a correlated quadratic as ``initial_inverse``,
    the first step (length 1) lands on the minimum; without it, the identity's steps do
    not: the matrix replaces the scaled identity of the two-loop recursion."""
    rng = np.random.default_rng(3)
    basis = np.linalg.qr(rng.normal(size=(5, 5)))[0]
    hessian = basis @ np.diag(np.logspace(0.0, 3.0, 5)) @ basis.T
    centre = rng.normal(size=5)

    def quadratic(x):
        return 0.5 * (x - centre) @ hessian @ (x - centre), hessian @ (x - centre)

    value, gradient = quadratic(np.zeros(5))
    step = lbfgs_step(quadratic, np.zeros(5), value, gradient,
                      initial_inverse=np.linalg.inv(hessian))
    assert step.accepted and step.evaluations == 1
    np.testing.assert_allclose(step.point, centre, atol=1e-9)
    plain = lbfgs_step(quadratic, np.zeros(5), value, gradient)
    assert np.linalg.norm(plain.point - centre) > 0.1 * np.linalg.norm(centre)
    assert plain.pairs
    # with pairs, the matrix is still the recursion's start: on a quadratic the pairs are
    # consistent with it, so the next step is again the exact Newton step
    later = lbfgs_step(quadratic, plain.point, plain.value, plain.gradient, plain.pairs,
                       initial_inverse=np.linalg.inv(hessian))
    np.testing.assert_allclose(later.point, centre, atol=1e-8)
