"""``calibrate``: fit detector parameters to calibration runs by gradient-based steps on
the expected mode's exact likelihood (``docs/calibration.md``)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..geometry.detector import Detector
from ..params import PARAM_SPECS, Params, from_unconstrained, validate_params
from ..transport.optics import TransportConfig
from .guards import (
    UNCONSTRAINED_SIGMA,
    Stage,
    refuse_runaway,
    unconstrained_labels,
)
from .history import dense_values, record_iteration
from .independent_ray_stage import (
    DEFAULT_JACOBIAN_SETS,
    EXTRAPOLATION_SETS,
    independent_ray_steps,
    ray_count_shift,
)
from .layout import free_layout
from .methods import make_method
from .objective import CalibrationProblem
from .result import CalibrationResult
from .runs import prepare_runs, run_provenance

__all__ = [
    "DEFAULT_JACOBIAN_SETS",
    "EXTRAPOLATION_SETS",
    "UNCONSTRAINED_SIGMA",
    "calibrate",
    "ray_count_shift",
    "unconstrained_labels",
]


#: A free value whose physical units change by less than this per unit of its
#: unconstrained coordinate sits at the edge of its range (a probability within 1e-6 of
#: 0 or 1, an efficiency below 1e-6): its error is reported as infinite, since a
#: linearised error there is meaningless (a toy fit that ended at a sensor reflectivity
#: of 6e-8 had a slope of 6e-8 and a meaningless error of 1e-16).
BOUNDARY_SLOPE = 1e-6


def _physical_errors(problem: CalibrationProblem, theta: dict, curvature) -> tuple:
    """(errors ``Params`` in physical units, dense correlation matrix); inf for a value
    at the edge of its range (``BOUNDARY_SLOPE``)."""
    layout = problem.layout
    dense_cov, sensor_var = curvature.covariance()
    sigma_dense = np.sqrt(np.abs(np.diag(dense_cov)))
    with np.errstate(divide="ignore", invalid="ignore"):
        correlation = dense_cov / np.outer(sigma_dense, sigma_dense)
    sigma_theta = layout.join(sigma_dense, np.sqrt(np.abs(sensor_var)))
    unconstrained = dataclasses.replace(problem.base, **theta)
    tangent = jax.tree.map(jnp.ones_like, unconstrained)
    _, slope = jax.jvp(from_unconstrained, (unconstrained,), (tangent,))
    errors = {}
    for spec in PARAM_SPECS:
        value = np.asarray(getattr(slope, spec.name), np.float64)
        if spec.name in sigma_theta:
            # a flat direction stays infinite where the map to physical units is flat too
            # (a probability saturated at 0 or 1), instead of 0 x inf = nan
            sigma = np.asarray(sigma_theta[spec.name], np.float64)
            at_edge = np.isinf(sigma) | (np.abs(value) < BOUNDARY_SLOPE)
            with np.errstate(invalid="ignore"):
                errors[spec.name] = np.where(at_edge, np.inf, np.abs(value) * sigma)
        else:
            errors[spec.name] = np.zeros_like(value)
    return Params.from_dict(errors), correlation


#: Gauss-Newton hands over to the independent-ray stage once its step is below this many
#: sigma: the stage moves the optics by several sigma from the minimum of -log L, so
#: polishing that minimum further is wasted work.
HANDOVER_SIGMA = 1.0


def calibrate(
    detector: Detector,
    runs: Sequence | Iterable,
    init_params: Params,
    free: Sequence[str] | str,
    method="gauss-newton",
    likelihood: str = "charge",
    *,
    config: TransportConfig | None = None,
    key=None,
    max_iterations: int = 50,
    loss_tolerance: float = 1e-3,
    step_tolerance: float = 1e-2,
    truth: Params | None = None,
    callback: Callable[[int, float, dict], None] | None = None,
    offset_start: str = "median",
    ray_extrapolation: bool = True,
    jacobian_sets: int | None = DEFAULT_JACOBIAN_SETS,
) -> CalibrationResult:
    """Fit the ``free`` fields of ``Params`` to calibration runs.

    Args:
        detector: the detector the runs were recorded in.
        runs: (source, events) pairs or ``CalibrationRun``s; events are one ``Event``, a
            list of them or an open ``EventFile``. A run's events are all flashes of its
            source; "charge" sums them per sensor (exactly), "charge+time" fits them
            jointly event by event.
        init_params: starting values; fields not in ``free`` stay fixed at them.
        free: names of the fields to fit (scalars and per-sensor arrays), a list or a
            comma-separated string.
        method: "gauss-newton" (default: Fisher scoring / Newton, a few iterations),
            "lbfgs", "adam", or a step-rule object (``methods.py``).
        likelihood: "charge" (run-summed charge per sensor) or "charge+time" (per-event
            charge and first-hit time).
        config: expected-mode settings (rays, bounces, readout window in ns relative to
            the source time, which must match the one the events were recorded with).
        key: ``jax.random`` key of the expected mode's rays (default ``key(0)``).
        max_iterations: step limit.
        loss_tolerance: converged when an iteration lowers -log L by less than this ...
        step_tolerance: ... and moves every free value by less than this many sigma
            (Gauss-Newton; other methods: unconstrained units).
        truth: the true parameters, kept in the result for pulls (pseudo-data).
        callback: called after every iteration with (iteration, loss, values), values
            the physical values of the dense free entries.
        offset_start: with free time offsets and the charge+time likelihood, "median"
            (default) first moves every sensor's offset by the median of its recorded
            first-hit times minus the predicted median first-hit time
            (``CalibrationProblem.median_time_shift``); "init" starts from
            ``init_params`` as given.
        ray_extrapolation: with the independent-ray stage (charge likelihood, free
            optics, indirect light), also find the root with the expected charges
            averaged over 2 ray sets and extrapolate the two roots to infinitely many
            rays (``independent_ray_steps``): removes the ray-noise bias of order
            1/(rays) (its size on the toy and on SK: docs/calibration.md, "Accuracy to
            expect"). With ``jacobian_sets`` both roots use the same
            averaged weights J_b, whose noise then cancels in the extrapolation. On by
            default; False returns the one-set root.
        jacobian_sets: with the independent-ray stage, the number K of independent ray
            sets over which the score's weights J_b are averaged once, where the stage
            starts, and kept for all its steps (one Jacobian per run and step instead of
            two; K more once). Default ``DEFAULT_JACOBIAN_SETS`` (4); None: a fresh set
            at every step, which on SK scatters a third more and, extrapolated, widens
            the pulls to 1.25-1.32.

    Returns:
        ``CalibrationResult`` (fitted params, errors, correlation, history).

    Raises:
        ConfigError: bad runs, parameters, names or settings; runs from another detector;
            a run whose expected charge is not finite; or free parameters these runs
            cannot constrain (flat directions of the curvature), each one line.
        CalibrationError: a numerical failure during the fit (a linear-algebra error,
            memory exhausted, ...), one line naming the stage.
    """
    started = time.perf_counter()
    validate_params(init_params, detector.n_sensors)
    layout = free_layout(free, detector.n_sensors)
    step_rule = make_method(method)
    _check_settings(max_iterations, offset_start, jacobian_sets)
    config = TransportConfig() if config is None else config
    key = jax.random.key(0) if key is None else key
    prepared = prepare_runs(runs, detector, likelihood)
    stage = Stage("preparing the expected mode of the runs")
    with stage:  # a numerical failure becomes one CalibrationError naming the stage
        problem = CalibrationProblem(detector, prepared, init_params, layout, likelihood,
                                     config, key)
        theta = _starting_point(problem, offset_start, stage)
        history = [{"iteration": 0, "loss": problem.value(theta), "time_s": 0.0,
                    "values": dense_values(problem, problem.params_of(theta))}]
        theta, converged, message = _iterate(
            problem, step_rule, theta, history, stage, started, callback,
            int(max_iterations), loss_tolerance, step_tolerance,
        )
        if problem.has_independent_rays and converged:
            stage.name = "the independent-ray stage"
            theta, loss, curvature, converged, message = independent_ray_steps(
                problem, theta, history, started, step_tolerance, callback, ray_extrapolation,
                jacobian_sets,
            )
        else:
            stage.name = "the curvature at the optimum"
            loss, _, _, curvature = problem.curvature(theta)
        stage.name = "the errors at the optimum"
        errors, correlation = _physical_errors(problem, theta, curvature)
        converged, message = _errors_finite(layout, errors, converged, message)
        return CalibrationResult(
            params=problem.params_of(theta),
            errors=errors,
            correlation=correlation,
            correlation_names=tuple(layout.dense_names()),
            history=tuple(history),
            free=layout.names,
            method=method if isinstance(method, str) else type(method).__name__,
            likelihood=likelihood,
            converged=converged,
            message=message,
            loss=loss,
            settings={
                "n_rays": config.n_rays,
                "n_bounces": config.n_bounces,
                "window_ns": list(config.window),
                "max_iterations": int(max_iterations),
                "loss_tolerance": loss_tolerance,
                "step_tolerance": step_tolerance,
                "ray_extrapolation": bool(ray_extrapolation),
                "jacobian_sets": jacobian_sets,
            },
            runs=run_provenance(prepared),
            detector={"name": detector.name, "n_sensors": detector.n_sensors},
            truth=truth,
            wall_time_s=time.perf_counter() - started,
        )


def _check_settings(max_iterations, offset_start, jacobian_sets) -> None:
    """One-line ``ConfigError`` for a bad iteration limit, offset start or set count."""
    if int(max_iterations) < 1:
        raise ConfigError(f"max_iterations = {max_iterations}: must be >= 1")
    if offset_start not in ("median", "init"):
        raise ConfigError(f"offset_start = {offset_start!r}: must be 'median' or 'init'")
    if jacobian_sets is not None and not (isinstance(jacobian_sets, int) and jacobian_sets >= 1):
        raise ConfigError(f"jacobian_sets = {jacobian_sets!r}: must be None or an integer >= 1")


def _starting_point(problem: CalibrationProblem, offset_start: str, stage: Stage) -> dict:
    """The free values the fit starts from: the initial ones, with free time offsets moved
    by the median first-hit residual (charge+time, ``offset_start="median"``). Checks
    the runs' predictions and refuses free values the runs cannot constrain (flat
    directions of the Fisher matrix) with a one-line ``ConfigError``."""
    theta = problem.initial_theta()
    problem.check_predictions(theta)
    stage.name = "the Fisher information at the starting parameters"
    median_start = offset_start == "median" and problem.likelihood == "charge+time"
    if median_start and "time_offset" in theta:
        shift = problem.median_time_shift(theta)
        theta = {**theta, "time_offset": theta["time_offset"] + jnp.asarray(
            shift, theta["time_offset"].dtype)}
    _, _, _, curvature = problem.curvature(theta)
    flat = unconstrained_labels(problem.layout, curvature.positive())
    if flat:
        raise ConfigError(
            f"free: {', '.join(flat)}: not constrained by these runs (1-sigma beyond"
            f" {UNCONSTRAINED_SIGMA:g} in unconstrained units: a flat direction of the"
            " Fisher matrix); fix them or add runs sensitive to them"
        )
    return theta


def _iterate(problem, step_rule, theta, history, stage, started, callback, max_iterations,
             loss_tolerance, step_tolerance) -> tuple[dict, bool, str]:
    """The step rule's iterations until convergence, a hand-over to the independent-ray
    stage (Gauss-Newton with free optics: once the steps are below ``HANDOVER_SIGMA``) or
    ``max_iterations``; appends to ``history``. Returns (theta, converged, message)."""
    state = step_rule.init(problem, theta)
    converged, message = False, f"stopped at max_iterations = {max_iterations}"
    in_sigma = getattr(step_rule, "steps_in_sigma", False)
    handover = problem.has_independent_rays and in_sigma
    for iteration in range(1, max_iterations + 1):
        stage.name = f"iteration {iteration}"
        theta, state, step = step_rule.update(problem, theta, state)
        refuse_runaway(theta, iteration)
        record_iteration(problem, theta, history, started, callback, step.loss)
        if step.loss_change == 0.0 and step.step_size == 0.0:
            converged = in_sigma
            suffix = "" if converged else f" ({step_rule.__class__.__name__})"
            return theta, converged, "no step lowers -log L further" + suffix
        if handover and step.step_size < HANDOVER_SIGMA:
            return theta, True, (
                f"handed over: the largest step was {step.step_size:.2g} < "
                f"{HANDOVER_SIGMA:g} sigma"
            )
        if step.loss_change < loss_tolerance and step.step_size < step_tolerance:
            return theta, True, (
                f"converged: -log L changed by {step.loss_change:.2g} < {loss_tolerance:g}"
                f" and the largest step was {step.step_size:.2g} < {step_tolerance:g}"
            )
    return theta, converged, message


def _errors_finite(layout, errors: Params, converged: bool, message: str) -> tuple[bool, str]:
    """(converged, message), not converged where a dense free value has no finite error
    (at the edge of its range, or unconstrained: no measurement)."""
    edge = [name for name in layout.dense_fields
            if not np.all(np.isfinite(np.asarray(getattr(errors, name))))]
    if not edge:
        return converged, message
    return False, (f"not converged: {', '.join(edge)} at the edge of the parameter range or"
                   f" unconstrained (error inf); the steps ended with: {message}")
