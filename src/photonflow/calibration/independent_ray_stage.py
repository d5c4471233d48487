"""The independent-ray stage of a calibration fit (charge likelihood, free optics,
indirect light): Newton steps from the minimum of -log L to the root of the
independent-ray score (``independent_rays.IndependentRays``), and with ray extrapolation
a second root with the expected charges averaged over ``EXTRAPOLATION_SETS`` ray sets,
the two extrapolated to infinitely many rays. Why: docs/calibration.md, "Ray noise and
the independent-ray score"."""

from __future__ import annotations

import dataclasses

import numpy as np

from .guards import refuse_non_finite, refuse_runaway
from .history import record_iteration
from .independent_rays import IndependentRayParts, RayNoiseSets
from .methods import sigma_step_size, take_step
from .structured import SandwichCovariance

#: Newton steps of the independent-ray stage before it is reported as not converged.
INDEPENDENT_RAY_STEPS = 10


#: Independent ray sets over which the independent-ray score's weights J_b are averaged
#: once by default (``calibrate(jacobian_sets=)``; why 4: docs/calibration.md, "Ray noise
#: and the independent-ray score", and the validation in studies/).
DEFAULT_JACOBIAN_SETS = 4


#: Ray sets over which the expected charges are averaged for the stage's second root:
#: the root's ray-noise bias falls as 1/(rays), so the roots with one set and with this
#: many are extrapolated to infinitely many rays.
EXTRAPOLATION_SETS = 2


def ray_count_shift(one_set, many_sets, sets: int = EXTRAPOLATION_SETS):
    """The shift from the root with one ray set, ``one_set``, to the root with infinitely
    many rays, given the root with ``sets`` sets, ``many_sets`` (arrays in the same
    coordinates): the ray-noise bias falls as 1/(rays), so theta_inf = theta_1 +
    K/(K - 1) (theta_K - theta_1)."""
    return sets / (sets - 1) * (many_sets - one_set)


def root_steps(
    problem, theta: dict, history: list, started: float,
    step_tolerance: float, callback, *, charge_sets: int, ray_noise, stage: str,
    frozen: IndependentRayParts | None = None, jacobians: tuple | None = None,
) -> tuple[dict, IndependentRayParts, RayNoiseSets, bool, float, int]:
    """Newton steps to the root of the independent-ray score with M_a averaged over
    ``charge_sets`` ray sets (``CalibrationProblem.independent_ray_curvature``), until a
    step moves every free value by less than ``step_tolerance`` sigma. Without
    ``ray_noise`` the first step is uncorrected and the ray-noise sets are drawn after
    it. With ``frozen`` (the parts of a nearby point) the steps reuse its Newton matrix
    and derivatives J_b, and compute only the expected charges
    (``CalibrationProblem.independent_ray_score``); otherwise, with ``jacobians`` (per
    run, J_b), every step uses those weights and computes only M_a and J_a. Appends
    every step to ``history`` with ``"stage": stage``. Returns (theta, the parts of the
    last step (``frozen`` if given), the ray-noise sets, converged, last step size in
    sigma, steps)."""
    size, converged, count, parts = np.inf, False, 0, frozen
    while not converged and count < INDEPENDENT_RAY_STEPS:
        count += 1
        if frozen is None:
            parts = problem.independent_ray_curvature(theta, ray_noise, charge_sets, jacobians)
            loss, grad_dense, grad_sensor = parts.loss, parts.grad_dense, parts.grad_sensor
        else:
            loss, grad_dense, grad_sensor = problem.independent_ray_score(
                theta, frozen.jacobians, ray_noise, charge_sets)
        refuse_non_finite(problem, theta, stage, len(history) - 1, loss, grad_dense, grad_sensor,
                           parts.newton)
        step_dense, step_sensor = parts.newton.solve(-grad_dense, -grad_sensor)
        size = sigma_step_size(parts.covariance(), step_dense, step_sensor)
        theta = take_step(problem, theta, step_dense, step_sensor)
        refuse_runaway(theta, len(history))
        record_iteration(problem, theta, history, started, callback, loss, stage)
        if ray_noise is None:
            ray_noise = problem.ray_noise_sets(theta)
        else:
            converged = size < step_tolerance
    return theta, parts, ray_noise, converged, size, count


def independent_ray_steps(
    problem, theta: dict, history: list, started: float,
    step_tolerance: float, callback, extrapolate: bool = False,
    jacobian_sets: int | None = None,
) -> tuple[dict, float, SandwichCovariance, bool, str]:
    """From the minimum of -log L to the root of the independent-ray score
    (``CalibrationProblem.independent_ray_curvature``), with ``extrapolate`` extrapolated
    to infinitely many rays (``extrapolated_root``).

    The score's weights J_b come from a fresh independent ray set at every step, or with
    ``jacobian_sets`` = K are averaged over K independent sets once, at the minimum, and
    kept. The first step goes from the minimum to near the root; there the ray-noise
    sets (``CalibrationProblem.ray_noise_sets``) are drawn once, and the later steps also
    remove the second-order (Jensen) bias that the ray noise of M puts into dL/dM. Why
    each of these: docs/calibration.md, "Ray noise and the independent-ray score".

    Appends to ``history`` the Newton steps (``"stage": "independent rays"``) and, with
    ``extrapolate``, those of ``extrapolated_root``. The last entry also has
    ``"ray_noise_share"`` (the fraction of each dense free value's variance that is the
    expected mode's ray noise rather than the data's) and ``"ray_noise_bias"`` (the
    shift, in sigma, by which the bias correction moved each dense free value). Returns
    (theta, -log L there, the root's covariance with the ray noise
    (``CalibrationProblem.ray_noise_covariance``), converged, message).
    """
    weights = None if jacobian_sets is None else problem.independent_jacobians(
        theta, jacobian_sets)
    theta_one, parts, ray_noise, converged, size, count = root_steps(
        problem, theta, history, started, step_tolerance, callback,
        charge_sets=1, ray_noise=None, stage="independent rays", jacobians=weights,
    )
    covariance = problem.ray_noise_covariance(parts, ray_noise)
    record_ray_noise(problem, history[-1], parts, covariance)
    if not converged:
        return theta_one, problem.value(theta_one), covariance, False, (
            "the independent-ray Newton steps did not settle within"
            f" {INDEPENDENT_RAY_STEPS} steps (last {size:.2g} sigma)"
        )
    message = (f"converged: the independent-ray score's Newton step was {size:.2g} sigma"
               f" < {step_tolerance:g} after {count} step(s) from the minimum of -log L")
    if not extrapolate:
        return theta_one, problem.value(theta_one), covariance, True, message
    if weights is None:
        frozen = dataclasses.replace(
            parts, jacobians=problem.independent_jacobians(theta_one, EXTRAPOLATION_SETS))
    else:  # theta_1's own weights: their noise cancels in theta_K - theta_1
        frozen = parts
    return extrapolated_root(problem, theta_one, frozen, ray_noise, covariance, history,
                             started, step_tolerance, callback, message)


def extrapolated_root(problem, theta_one: dict, frozen: IndependentRayParts,
                      ray_noise: RayNoiseSets, covariance: SandwichCovariance,
                      history: list, started: float, step_tolerance: float, callback,
                      message: str) -> tuple[dict, float, SandwichCovariance, bool, str]:
    """The root theta_K with the expected charges averaged over K = ``EXTRAPOLATION_SETS``
    ray sets, found from the one-set root ``theta_one`` with its Newton matrix and the
    weights J_b of ``frozen`` (only expected charges are computed), and the extrapolation
    theta_1 + K/(K - 1) (theta_K - theta_1) (``ray_count_shift``): the ray-noise bias of
    the root falls as 1/(rays). To first order its noise is that of one set (K = 2), so
    ``covariance`` (theta_1's) is returned. Appends the steps (``"independent rays, K
    sets"``) and the extrapolated point (``"extrapolated"``, with
    ``"ray_count_extrapolation"``: the shift in sigma) to ``history``. Returns as
    ``independent_ray_steps``; when the K-set steps do not settle, theta_1 not
    extrapolated (not converged)."""
    sets = EXTRAPOLATION_SETS
    theta_many, _, _, converged, size_many, count_many = root_steps(
        problem, theta_one, history, started, step_tolerance, callback,
        charge_sets=sets, ray_noise=ray_noise, stage=f"independent rays, {sets} sets",
        frozen=frozen,
    )
    if not converged:
        record_ray_noise(problem, history[-1], frozen, covariance)
        return theta_one, problem.value(theta_one), covariance, False, (
            f"the Newton steps to the root with {sets} ray sets did not settle within"
            f" {INDEPENDENT_RAY_STEPS} steps (last {size_many:.2g} sigma); not"
            " extrapolated"
        )
    layout = problem.layout
    (one_dense, one_sensor), (many_dense, many_sensor) = (
        [np.asarray(x, np.float64) for x in layout.split(t)] for t in (theta_one, theta_many)
    )
    shift_dense = ray_count_shift(one_dense, many_dense, sets)
    theta = take_step(problem, theta_one, shift_dense,
                      ray_count_shift(one_sensor, many_sensor, sets))
    loss = problem.value(theta)
    record_iteration(problem, theta, history, started, callback, loss, "extrapolated")
    record_ray_noise(problem, history[-1], frozen, covariance)
    sigma = np.sqrt(np.diag(covariance.covariance()[0]))
    history[-1]["ray_count_extrapolation"] = dict(
        zip(layout.dense_names(), map(float, shift_dense / sigma), strict=True))
    return theta, loss, covariance, True, (
        f"{message}, and {size_many:.2g} sigma after {count_many} step(s) with {sets} ray"
        " sets; extrapolated to infinitely many rays"
    )


def record_ray_noise(problem, entry: dict, parts, covariance) -> None:
    """Add to a history ``entry`` each dense free value's ray-noise share of the variance
    (``"ray_noise_share"``) and the shift of the Jensen correction in sigma
    (``"ray_noise_bias"``)."""
    names = problem.layout.dense_names()
    sigma = np.sqrt(np.diag(covariance.covariance()[0]))
    bias, _ = parts.newton.solve(parts.bias_dense, parts.bias_sensor)
    entry["ray_noise_share"] = dict(zip(names, map(float, covariance.noise_share()),
                                        strict=True))
    entry["ray_noise_bias"] = dict(zip(names, map(float, bias / sigma), strict=True))
