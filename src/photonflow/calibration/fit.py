"""``calibrate``: fit detector parameters to calibration runs by gradient-based steps on
the expected mode's exact likelihood (``docs/calibration.md``)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import CalibrationError, ConfigError, PhotonflowError
from ..geometry.detector import Detector
from ..params import PARAM_SPECS, Params, from_unconstrained, validate_params
from ..transport.optics import TransportConfig
from .layout import FreeLayout, free_layout
from .methods import make_method, sigma_step_size, take_step
from .objective import CalibrationProblem, IndependentRayParts, RayNoiseSets
from .result import CalibrationResult
from .runs import prepare_runs, run_provenance
from .structured import SandwichCovariance, StructuredMatrix

#: A free value whose 1-sigma uncertainty exceeds this, in unconstrained units (log for
#: lengths and rates: a factor e^3 = 20; logit for probabilities; ns for time offsets),
#: is reported as not constrained by the data.
UNCONSTRAINED_SIGMA = 3.0


def unconstrained_labels(
    layout: FreeLayout, curvature: StructuredMatrix, expected_information: bool = True
) -> list[str]:
    """Free entries that the curvature leaves (nearly) flat: no information at all, or
    (for an expected Fisher information, which both likelihoods use) a 1-sigma
    uncertainty above ``UNCONSTRAINED_SIGMA`` (a flat direction, e.g. a global
    efficiency degenerate with the per-sensor ones). An observed information away from
    the optimum does not measure identifiability, so for it
    (``expected_information=False``) only the first test applies. Empty when all are
    constrained."""
    labels = layout.dense_names()
    flat = [labels[i] for i in np.flatnonzero(~(np.diag(curvature.a) > 0))]
    for column, name in enumerate(layout.sensor_fields):
        dead = np.flatnonzero(~(curvature.b[:, column, column] > 0))
        if dead.size:
            flat.append(f"{name} of {dead.size} sensors (first: {int(dead[0])})")
    if flat or not expected_information:
        return flat
    try:
        dense_var, sensor_var = curvature.covariance()
    except np.linalg.LinAlgError:
        return labels + list(layout.sensor_fields)
    dense_var = np.diag(dense_var)
    wide = ~(dense_var > 0) | (np.sqrt(np.abs(dense_var)) > UNCONSTRAINED_SIGMA)
    flat = [labels[i] for i in np.flatnonzero(wide)]
    for column, name in enumerate(layout.sensor_fields):
        var = sensor_var[:, column]
        bad = np.flatnonzero(~(var > 0) | (np.sqrt(np.abs(var)) > UNCONSTRAINED_SIGMA))
        if bad.size:
            flat.append(f"{name} of {bad.size} sensors (first: {int(bad[0])})")
    return flat


class Stage:
    """What a fit is doing (``name``), and, as a context manager, the boundary that turns
    a numerical failure inside it (a linear-algebra error, a floating-point or XLA
    runtime error, memory exhausted) into a one-line ``CalibrationError`` naming the
    stage. ``PhotonflowError`` passes unchanged."""

    def __init__(self, name: str):
        self.name = name

    def __enter__(self):
        return self

    def __exit__(self, kind, error, traceback):
        if error is None or isinstance(error, PhotonflowError):
            return False
        if isinstance(error, (np.linalg.LinAlgError, ArithmeticError, RuntimeError,
                              MemoryError)):
            text = str(error).strip().splitlines()
            detail = f"{type(error).__name__}: {text[0][:160]}" if text else type(error).__name__
            raise CalibrationError(
                f"calibrate: {self.name} failed ({detail}); check the runs and the starting"
                " parameters, or fewer free fields / more rays (--rays)"
            ) from error
        return False


def _refuse_runaway(theta: dict, iteration: int) -> None:
    """Raise a one-line ``ConfigError`` naming the free fields whose unconstrained value
    left the finite range during the fit (a length run off to infinity, a probability
    saturated past float precision): the runs do not constrain them."""
    runaway = [name for name, value in theta.items() if not np.all(np.isfinite(np.asarray(value)))]
    if runaway:
        raise ConfigError(
            f"free: {', '.join(runaway)}: ran off to the edge of the parameter range at"
            f" iteration {iteration} (not constrained by these runs); fix them or add runs"
            " sensitive to them"
        )


def _refuse_non_finite(problem: CalibrationProblem, theta: dict, stage: str,
                       iteration: int, loss: float, grad_dense: np.ndarray,
                       grad_sensor: np.ndarray, newton: StructuredMatrix) -> None:
    """Raise a one-line ``ConfigError`` when -log L, the score or the Newton matrix at
    ``theta`` is not finite: a step took the free values where the expected charges
    vanish or overflow (e.g. an absorption length of 1e-36 m after a Newton step from a
    minimum that the expected mode's ray noise had run off), and solving on would fail
    inside the linear algebra. Names the dense free values there."""
    if (np.isfinite(loss) and np.all(np.isfinite(grad_dense))
            and np.all(np.isfinite(grad_sensor)) and newton.finite):
        return
    values = ", ".join(f"{name} {value:.3g}" for name, value in
                       _dense_values(problem, problem.params_of(theta)).items())
    raise ConfigError(
        f"{stage}, iteration {iteration}: -log L or its derivatives are not finite at"
        f" {values} (the fit ran off); use more rays (TransportConfig.n_rays, --rays) or runs"
        " that constrain the free values better"
    )


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


#: Newton steps of the independent-ray stage before it is reported as not converged.
INDEPENDENT_RAY_STEPS = 10

#: Gauss-Newton hands over to the independent-ray stage once its step is below this many
#: sigma: the stage moves the optics by several sigma from the minimum of -log L, so
#: polishing that minimum further is wasted work.
HANDOVER_SIGMA = 1.0


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


def _root_steps(
    problem: CalibrationProblem, theta: dict, history: list, started: float,
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
        _refuse_non_finite(problem, theta, stage, len(history) - 1, loss, grad_dense, grad_sensor,
                           parts.newton)
        step_dense, step_sensor = parts.newton.solve(-grad_dense, -grad_sensor)
        size = sigma_step_size(parts.covariance(), step_dense, step_sensor)
        theta = take_step(problem, theta, step_dense, step_sensor)
        _refuse_runaway(theta, len(history))
        _record(problem, theta, history, started, callback, loss, stage)
        if ray_noise is None:
            ray_noise = problem.ray_noise_sets(theta)
        else:
            converged = size < step_tolerance
    return theta, parts, ray_noise, converged, size, count


def _record(problem, theta, history, started, callback, loss, stage=None) -> None:
    """Append an iteration at ``theta`` to ``history`` (with ``"stage"`` when given) and
    tell ``callback``."""
    values = _dense_values(problem, problem.params_of(theta))
    entry = {"iteration": len(history), "loss": loss,
             "time_s": time.perf_counter() - started, "values": values}
    history.append(entry if stage is None else {**entry, "stage": stage})
    if callback is not None:
        callback(len(history) - 1, loss, values)


def _independent_ray_steps(
    problem: CalibrationProblem, theta: dict, history: list, started: float,
    step_tolerance: float, callback, extrapolate: bool = False,
    jacobian_sets: int | None = None,
) -> tuple[dict, float, SandwichCovariance, bool, str]:
    """From the minimum of -log L to the root of the independent-ray score
    (``CalibrationProblem.independent_ray_curvature``), with ``extrapolate`` extrapolated
    to infinitely many rays. Appends to ``history`` the Newton steps (``"stage":
    "independent rays"``); with ``extrapolate`` also the steps to the root with
    ``EXTRAPOLATION_SETS`` ray sets (``"independent rays, K sets"``) and the
    extrapolated point (``"extrapolated"``). The last entry also has
    ``"ray_noise_share"``: the fraction of each dense free value's variance that is the
    expected mode's ray noise rather than the data's; ``"ray_noise_bias"``: the shift,
    in sigma, by which the second-order bias correction moved each dense free value;
    and with ``extrapolate`` ``"ray_count_extrapolation"``: the extrapolation's shift
    in sigma. Returns (theta, -log L there, the root's covariance with the ray noise,
    ``CalibrationProblem.ray_noise_covariance``, converged, message).

    The minimum of -log L with the expected mode's ray noise is biased: the noise of the
    expected charges M and of their derivatives J comes from the same rays, and their
    correlation shifts the optical parameters by many sigma at campaign statistics
    (docs/calibration.md). The root of the score with J from independent rays has no
    such correlation; Newton steps on the score's expected derivative reach it in a few
    steps. The score's weights J_b come from a fresh independent ray set at every step,
    or with ``jacobian_sets`` = K are averaged over K independent sets once, at the
    minimum, and kept: weights independent of the noise of M_a and of the data leave
    the score unbiased at the truth wherever they are taken, a few sigma from the root
    they are as good as the root's own, and averaged they have 1/K of the ray noise
    that costs the root efficiency and scatter. The first step goes from the minimum to
    near the root; there the ray-noise sets (``CalibrationProblem.ray_noise_sets``) are
    drawn once, and the later steps also remove the second-order (Jensen) bias that the
    ray noise of M puts into dL/dM.
    What bias the ray noise leaves in the root is of order 1/(rays), from the noise of
    M_a (with J_a) and of J_b alike: the root with both averaged over K ray sets
    (K = ``EXTRAPOLATION_SETS``; ``CalibrationProblem.independent_jacobians``) has 1/K
    of it, so theta_1 + K/(K - 1) (theta_K - theta_1) has none to that order. To first
    order in the noise its noise is that of one set for K = 2 (theta_1's own sets
    cancel: 2 (a + b)/2 - a = b), so theta_1's covariance is returned; where the root
    responds to J_b's noise non-linearly (SK at 1,024 rays) the extrapolated root
    scatters more than that (studies/calibration-validation.md). The steps to
    theta_K start at theta_1, reuse the Newton matrix of theta_1's last step and the
    K-set J_b at theta_1, and compute only expected charges: the root of the score with
    J_b fixed at theta_1 differs from the one with J_b moving along only at the second
    order of the distance theta_K - theta_1 (a fraction of sigma). With ``jacobian_sets``
    the steps to theta_K keep theta_1's own averaged weights instead: the two roots then
    differ only by the ray sets of M_a, J_b's noise cancels in theta_K - theta_1, and the
    extrapolation removes the O(1/rays) bias of M_a's noise (correlated with J_a's)
    without the amplified J_b noise that widens the pulls."""
    weights = None if jacobian_sets is None else problem.independent_jacobians(
        theta, jacobian_sets)
    theta_one, parts, ray_noise, converged, size, count = _root_steps(
        problem, theta, history, started, step_tolerance, callback,
        charge_sets=1, ray_noise=None, stage="independent rays", jacobians=weights,
    )
    covariance = problem.ray_noise_covariance(parts, ray_noise)
    _record_ray_noise(problem, history[-1], parts, covariance)
    if not converged:
        return theta_one, problem.value(theta_one), covariance, False, (
            "the independent-ray Newton steps did not settle within"
            f" {INDEPENDENT_RAY_STEPS} steps (last {size:.2g} sigma)"
        )
    message = (f"converged: the independent-ray score's Newton step was {size:.2g} sigma"
               f" < {step_tolerance:g} after {count} step(s) from the minimum of -log L")
    if not extrapolate:
        return theta_one, problem.value(theta_one), covariance, True, message
    sets = EXTRAPOLATION_SETS
    if weights is None:
        frozen = dataclasses.replace(
            parts, jacobians=problem.independent_jacobians(theta_one, sets))
    else:  # theta_1's own weights: their noise cancels in theta_K - theta_1
        frozen = parts
    theta_many, _, _, converged, size_many, count_many = _root_steps(
        problem, theta_one, history, started, step_tolerance, callback,
        charge_sets=sets, ray_noise=ray_noise, stage=f"independent rays, {sets} sets",
        frozen=frozen,
    )
    if not converged:
        _record_ray_noise(problem, history[-1], parts, covariance)
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
    _record(problem, theta, history, started, callback, loss, "extrapolated")
    _record_ray_noise(problem, history[-1], parts, covariance)
    sigma = np.sqrt(np.diag(covariance.covariance()[0]))
    history[-1]["ray_count_extrapolation"] = dict(
        zip(layout.dense_names(), map(float, shift_dense / sigma), strict=True))
    return theta, loss, covariance, True, (
        f"{message}, and {size_many:.2g} sigma after {count_many} step(s) with {sets} ray"
        " sets; extrapolated to infinitely many rays"
    )


def _record_ray_noise(problem: CalibrationProblem, entry: dict, parts, covariance) -> None:
    """Add to a history ``entry`` each dense free value's ray-noise share of the variance
    (``"ray_noise_share"``) and the shift of the Jensen correction in sigma
    (``"ray_noise_bias"``)."""
    names = problem.layout.dense_names()
    sigma = np.sqrt(np.diag(covariance.covariance()[0]))
    bias, _ = parts.newton.solve(parts.bias_dense, parts.bias_sensor)
    entry["ray_noise_share"] = dict(zip(names, map(float, covariance.noise_share()),
                                        strict=True))
    entry["ray_noise_bias"] = dict(zip(names, map(float, bias / sigma), strict=True))


def _dense_values(problem: CalibrationProblem, params: Params) -> dict[str, float]:
    """Label -> physical value of every dense free entry."""
    values = {}
    for name in problem.layout.dense_fields:
        value = np.asarray(getattr(params, name), np.float64)
        if value.ndim:
            values.update({f"{name}[{k}]": float(v) for k, v in enumerate(value)})
        else:
            values[name] = float(value)
    return values


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
            rays (``_independent_ray_steps``): removes the ray-noise bias of order
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
    if int(max_iterations) < 1:
        raise ConfigError(f"max_iterations = {max_iterations}: must be >= 1")
    config = TransportConfig() if config is None else config
    key = jax.random.key(0) if key is None else key
    if offset_start not in ("median", "init"):
        raise ConfigError(f"offset_start = {offset_start!r}: must be 'median' or 'init'")
    if jacobian_sets is not None and not (isinstance(jacobian_sets, int) and jacobian_sets >= 1):
        raise ConfigError(f"jacobian_sets = {jacobian_sets!r}: must be None or an integer >= 1")
    prepared = prepare_runs(runs, detector, likelihood)
    stage = Stage("preparing the expected mode of the runs")
    with stage:  # a numerical failure becomes one CalibrationError naming the stage
        problem = CalibrationProblem(detector, prepared, init_params, layout, likelihood,
                                     config, key)
        theta = problem.initial_theta()
        problem.check_predictions(theta)
        stage.name = "the Fisher information at the starting parameters"
        if offset_start == "median" and likelihood == "charge+time" and "time_offset" in theta:
            shift = problem.median_time_shift(theta)
            theta = {**theta, "time_offset": theta["time_offset"] + jnp.asarray(
                shift, theta["time_offset"].dtype)}
        _, _, _, curvature = problem.curvature(theta)
        flat = unconstrained_labels(layout, curvature.positive())
        if flat:
            raise ConfigError(
                f"free: {', '.join(flat)}: not constrained by these runs (1-sigma beyond"
                f" {UNCONSTRAINED_SIGMA:g} in unconstrained units: a flat direction of the"
                " Fisher matrix); fix them or add runs sensitive to them"
            )

        state = step_rule.init(problem, theta)
        history = [{"iteration": 0, "loss": problem.value(theta), "time_s": 0.0,
                    "values": _dense_values(problem, problem.params_of(theta))}]
        converged, message = False, f"stopped at max_iterations = {max_iterations}"
        in_sigma = getattr(step_rule, "steps_in_sigma", False)
        handover = problem.has_independent_rays and in_sigma
        for iteration in range(1, int(max_iterations) + 1):
            stage.name = f"iteration {iteration}"
            theta, state, step = step_rule.update(problem, theta, state)
            _refuse_runaway(theta, iteration)
            _record(problem, theta, history, started, callback, step.loss)
            if step.loss_change == 0.0 and step.step_size == 0.0:
                converged = in_sigma
                message = "no step lowers -log L further" + (
                    "" if converged else f" ({step_rule.__class__.__name__})"
                )
                break
            if handover and step.step_size < HANDOVER_SIGMA:
                converged, message = True, (
                    f"handed over: the largest step was {step.step_size:.2g} < "
                    f"{HANDOVER_SIGMA:g} sigma"
                )
                break
            if step.loss_change < loss_tolerance and step.step_size < step_tolerance:
                converged, message = True, (
                    f"converged: -log L changed by {step.loss_change:.2g} < {loss_tolerance:g}"
                    f" and the largest step was {step.step_size:.2g} < {step_tolerance:g}"
                )
                break

        if problem.has_independent_rays and converged:
            stage.name = "the independent-ray stage"
            theta, loss, curvature, converged, message = _independent_ray_steps(
                problem, theta, history, started, step_tolerance, callback, ray_extrapolation,
                jacobian_sets,
            )
        else:
            stage.name = "the curvature at the optimum"
            loss, _, _, curvature = problem.curvature(theta)
        stage.name = "the errors at the optimum"
        params = problem.params_of(theta)
        errors, correlation = _physical_errors(problem, theta, curvature)
        edge = [name for name in layout.dense_fields
                if not np.all(np.isfinite(np.asarray(getattr(errors, name))))]
        if edge:  # a value without a finite error is no measurement: not converged
            converged = False
            message = (f"not converged: {', '.join(edge)} at the edge of the parameter range or"
                       f" unconstrained (error inf); the steps ended with: {message}")
        return CalibrationResult(
            params=params,
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
