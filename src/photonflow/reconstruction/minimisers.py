"""The two minimisers of ``reconstruct`` (``fit``), each from one start, with the
reference refreshes of the module docstring of ``fit``:

- ``minimise_gradient``: L-BFGS (``photonflow.lbfgs``) on exact gradients, the
  covariance from the Hessian of central differences of exact gradients
  (``local_hessian``);
- ``minimise_minuit``: MIGRAD with numerical derivatives, errors by HESSE.

Both return a ``RecoResult`` (``converged`` only at a minimum with a positive-definite
Hessian). Lengths m, times ns, energies MeV.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..generator.track import Track
from ..lbfgs import lbfgs_step, pair_scale
from ..threads import parallel_map
from ..transport.optics import orthonormal_basis
from .coordinates import (
    fit_frame,
    free_from_track,
    local_from_track,
    track_from_free,
    track_from_local,
)
from .result import RecoResult


def cast_track(track: Track, dtype) -> Track:
    """``track`` with every float field as a JAX array of ``dtype``."""
    return jax.tree.map(lambda x: jnp.asarray(x, dtype), track)


def _moved(a: Track, b: Track, settings) -> bool:
    """Whether track ``b`` is further from ``a`` than the refresh thresholds."""
    distance = float(np.linalg.norm(np.asarray(a.position) - np.asarray(b.position)))
    cosine = float(np.clip(np.dot(np.asarray(a.direction), np.asarray(b.direction)), -1, 1))
    return distance > settings.refresh_distance or \
        math.degrees(math.acos(cosine)) > settings.refresh_angle


#: A fit stage's likelihood and held light: (with the first-hit times, with the held
#: light's slopes).
CHARGE_ONLY, FROZEN, SLOPED = (False, False), (True, False), (True, True)


def frozen_light(settings) -> bool:
    """Whether a fit with ``settings`` holds the indirect light frozen: without its
    slopes, in its stages, its Hessian, its polish and the scores of its simulated
    events (``frozen_stages`` > 0 with ``hold_indirect``; ``fit_stages``)."""
    return bool(settings.hold_indirect and settings.frozen_stages)


def fit_stages(settings, charge_stage: bool = True):
    """The stages of one fit, each a ``(use_time, slopes)`` pair: a generator that is
    sent, after each stage, whether its fitted track moved from the stage's reference by
    more than the refresh thresholds (``_moved``).

    - ``CHARGE_ONLY`` (if ``charge_stage``): the charge-only likelihood, whose landscape
      is smoother;
    - with ``frozen_light(settings)``: ``FROZEN`` stages, at most ``frozen_stages``,
      while the track moves. The indirect light is held without its slopes: its pattern
      frozen at the reference (its charge following the direct light's total, its times
      the track's start time). The slopes' noise (from the rays' weights) is a false
      curvature about the reference that held a fit near it, so that where a fit ended
      depended on its path (``docs/reconstruction.md``, "Fit"). Refreshed, the frozen
      stages settle where the reference and the fit agree, and the Hessian, the polish
      and the scores are those of this likelihood at the fit;
    - otherwise ``SLOPED`` stages, at most ``settings.refreshes`` + 1, while the track
      moves (with rays at every evaluation, ``hold_indirect`` False, the slopes are the
      rays' own)."""
    frozen = frozen_light(settings)
    if charge_stage:
        yield (False, not frozen)  # CHARGE_ONLY, with the slopes where not frozen
    stage, count = (FROZEN, settings.frozen_stages) if frozen else (
        SLOPED, settings.refreshes + 1)
    for _ in range(count):
        if not (yield stage):
            break


def _concrete(track: Track) -> Track:
    """A checked, float64 copy of a traced or device track."""
    return Track(track.particle, np.asarray(track.position, np.float64),
                 np.asarray(track.direction, np.float64) / np.linalg.norm(
                     np.asarray(track.direction, np.float64)),
                 float(track.energy), float(track.time))


#: A line search stops once a step could lower the likelihood by less than this share of
#: ``RecoSettings.tolerance`` (``lbfgs_step``'s ``min_decrease``).
MIN_DECREASE = 0.1


def minimise_gradient(functions, detector, model, data, start, settings) -> RecoResult:
    """L-BFGS from ``start``, with reference refreshes (module docstring)."""
    dtype = data.charge.dtype
    reference, iterations, evaluations, converged = start, 0, 0, False
    scale = None  # the last stage's inverse curvature: the first step's of the next
    stage_metric = None  # the inverse information at a stage's start (``score_metric``)
    schedule = fit_stages(settings)
    use_time, slopes = next(schedule)
    for stage in itertools.count():
        frame = fit_frame(detector.shape, reference.direction, model.energy_range,
                          start.particle, settings.margin, dtype)
        fixed = cast_track(reference, dtype)
        weight = jnp.asarray(float(use_time), dtype)
        staged = staged_data(functions, data, fixed, settings, slopes)

        def value_and_grad(x, frame=frame, fixed=fixed, weight=weight, staged=staged):
            value, gradient = functions.value_and_grad(jnp.asarray(x, dtype), FREE, frame,
                                                       fixed, staged, weight)
            return float(value), np.asarray(gradient, np.float64)

        free = np.asarray(free_from_track(frame, fixed), np.float64)
        value, gradient = value_and_grad(free)
        first = value
        evaluations += 1
        if not math.isfinite(value):
            return _failure("the likelihood is not finite", start, iterations)
        if not np.all(np.isfinite(gradient)):
            return _failure("the gradient is not finite", start, iterations)
        if settings.score_metric and stage < 2:
            stage_metric = _inverse_metric(np.asarray(functions.score_information(
                jnp.asarray(free, dtype), frame, fixed, staged, weight), np.float64))
        # a refresh stage (2, ...) reuses the first full stage's metric (one score
        # information less, ~0.4 s in SK): its coordinates differ by the move of the
        # frame's axis, and where that spoils the metric the stage goes on without it
        metric = stage_metric
        pairs, history, converged, stopped = (), [], False, False
        for _ in range(settings.max_iterations):
            step = lbfgs_step(value_and_grad, free, value, gradient, pairs,
                              min_decrease=MIN_DECREASE * settings.tolerance,
                              initial_scale=scale, initial_inverse=metric)
            iterations += 1
            evaluations += step.evaluations
            if not step.accepted and metric is not None:
                # no lower point along the metric's direction (it is not the Hessian
                # where the model misfits, or the stage is at its minimum): once more
                # with the pairs alone
                metric = None
                continue
            if not step.accepted and pairs:  # once more along the steepest descent
                scale, pairs = pair_scale(pairs), ()
                continue
            if not step.accepted:
                # not even a steepest-descent step lowers the likelihood (within its float
                # precision): a minimum if the stage's steps so far (the last ``patience``
                # of them) lowered it by little (a refresh starts at the minimum before)
                history.append(value)
                converged = _stalled([first, *history], min(settings.patience, len(history)),
                                     settings.tolerance)
                stopped = True
                break
            free, value, gradient, pairs = step.point, step.value, step.gradient, step.pairs
            scale = pair_scale(pairs) if pairs else scale
            if not np.all(np.isfinite(gradient)):
                return _failure("the gradient is not finite", start, iterations)
            history.append(value)
            if _stalled(history, settings.patience, settings.tolerance):
                converged = True
                break
        free = jnp.asarray(free, dtype)
        fitted = _concrete(track_from_free(frame, free))
        moved = _moved(reference, fitted, settings)
        reference = fitted
        try:
            use_time, slopes = schedule.send(moved)
        except StopIteration:
            break
    # the last stage's held light: held at that stage's reference, within the refresh
    # thresholds of the fitted track unless the stages ran out
    data = staged
    hessian, local_frame, centre = hessian_at(functions, detector, model, data, reference,
                                              settings.threads)
    evaluations += 1
    covariance = covariance_from_hessian(hessian)
    # a point whose Hessian is not positive definite is not a minimum (a saddle, or a
    # ridge the tolerance stopped on): never reported as converged
    minimum = bool(np.all(np.isfinite(covariance)))
    converged = converged and minimum
    if minimum:
        reference, value, remaining, polished = polish(functions, detector, model,
                                                       local_frame, reference, data, hessian,
                                                       settings.tolerance, centre)
        evaluations += polished
        # a line search that found no lower point in the last stage (float32's
        # resolution of the likelihood), at a minimum the Newton step cannot improve
        converged = converged or (stopped and remaining <= settings.tolerance)
    else:
        value = centre[0]
    return RecoResult(position=np.asarray(reference.position), time=float(reference.time),
                      direction=np.asarray(reference.direction),
                      energy=float(reference.energy), covariance=covariance, nll=value,
                      particle=start.particle, converged=converged, iterations=iterations,
                      seconds=0.0, method="gradient", evaluations=evaluations)


def _inverse_metric(information: np.ndarray) -> np.ndarray | None:
    """The inverse of a (7, 7) information matrix, regularised by 1e-6 of its diagonal
    (a coordinate without information, such as the time in a charge-only stage, gets a
    unit diagonal: the likelihood does not depend on it); None where it is not finite or
    not positive definite."""
    if not np.all(np.isfinite(information)):
        return None
    diagonal = np.diag(information)
    ridge = information + np.diag(np.where(diagonal > 0, 1e-6 * diagonal, 1.0))
    try:
        np.linalg.cholesky(ridge)
    except np.linalg.LinAlgError:
        return None
    return np.linalg.inv(ridge)


def staged_data(functions, data, track: Track, settings, slopes: bool | None = None):
    """``data`` for a fit stage about ``track`` (the reference): with the indirect light
    held at it (with its ``slopes``, or without; None: without where
    ``frozen_light(settings)``) where ``settings.hold_indirect``, else as it is (rays
    from the reference at every evaluation)."""
    if not settings.hold_indirect:
        return data
    if slopes is None:
        slopes = not frozen_light(settings)
    return dataclasses.replace(data, held=functions.hold(track, data, slopes))


def _stalled(values, patience: int, tolerance: float) -> bool:
    """Whether each of the last ``patience`` steps of a fit (the changes between its
    ``values`` of the negative log-likelihood) lowered it by less than ``tolerance``."""
    return len(values) > patience and all(
        values[-k - 1] - values[-k] < tolerance for k in range(1, patience + 1))


#: ``value_and_grad``'s coordinates: free (the fit's) or ``LOCAL`` (the covariance's);
#: bool arrays, traced, so that both use one compiled program.
FREE, LOCAL_COORDINATES = np.bool_(False), np.bool_(True)
#: Steps of the Hessian's first pass of forward differences in ``LOCAL`` coordinates
#: (m, m, m, ns, direction tangents, direction tangents, log of MeV) ...
HESSIAN_STEPS = (0.01, 0.01, 0.01, 0.05, 0.002, 0.002, 0.002)
#: ... and of the second, as a fraction of each coordinate's 1 sigma (with the others
#: fixed) from the first.
HESSIAN_STEP_SIGMA = 1.0


def local_value_and_grad(functions, frame, track: Track, data):
    """A function of a point (7,) of ``LOCAL`` coordinates about ``frame``'s axis giving
    the full likelihood's value (float) and gradient (float64 (7,)) there, the rays
    fixed by ``track``."""
    dtype = data.charge.dtype
    one = jnp.asarray(1.0, dtype)

    def value_and_grad(point):
        value, gradient = functions.value_and_grad(jnp.asarray(point, dtype),
                                                   LOCAL_COORDINATES, frame, track, data, one)
        return float(value), np.asarray(gradient, np.float64)

    return value_and_grad


def local_hessian(functions, frame, track: Track, data, wall: float = math.inf,
                  centre_gradient: np.ndarray | None = None,
                  threads: int | None = None) -> np.ndarray:
    """(7, 7) Hessian of the negative log-likelihood at ``track`` in ``LOCAL``
    coordinates about ``frame``'s axis (units of the coordinates: m, ns, tangents, log
    of MeV), symmetrised: differences of the exact gradient, a first pass of forward
    differences from the gradient at ``track`` (``centre_gradient``, if known) with
    ``HESSIAN_STEPS``, then central differences with steps of ``HESSIAN_STEP_SIGMA`` of
    each coordinate's 1 sigma from the first (7 + 14 gradients, and one more at
    ``track`` when ``centre_gradient`` is None), within 0.1-10x the
    first steps and, for the vertex, half the distance ``wall`` (m) to the detector's
    wall. Where the first pass has a curvature that is not positive, its (not positive
    definite) Hessian is returned. The gradients of a pass run on ``threads`` threads
    (``photonflow.threads.parallel_map``).

    Differences of exact gradients over one sigma rather than forward-over-reverse
    second derivatives: they run the fit's own gradient program (a second program took
    ~2.5x as long to compile as the gradient's, 20 s on the toy detector; 67 s against
    5 s in SK, and 12x a value and gradient to run), and they measure the likelihood's
    curvature over its error region, where a track likelihood has curvature structure
    on sub-sigma scales that can make pointwise or 0.1-sigma second derivatives
    indefinite at a minimum (``docs/reconstruction.md``). The first pass only sets the
    second's steps, so its one-sided differences (half the gradients) suffice."""
    centre = np.asarray(local_from_track(track, data.charge.dtype), np.float64)
    value_and_grad = local_value_and_grad(functions, frame, track, data)

    def gradients(points):
        return parallel_map(lambda point: value_and_grad(point)[1], points, threads)

    def symmetric(columns):
        hessian = np.stack(columns, axis=1)
        return 0.5 * (hessian + hessian.T)

    axes = np.eye(centre.size)

    first = np.asarray(HESSIAN_STEPS, np.float64)
    highest = 10.0 * first
    highest[:3] = np.minimum(highest[:3], max(0.5 * wall, 1e-5))
    steps = np.minimum(first, highest)
    at_centre = gradients([centre])[0] if centre_gradient is None else centre_gradient
    ahead = gradients([centre + h * e for h, e in zip(steps, axes, strict=True)])
    hessian = symmetric([(g - at_centre) / h for g, h in zip(ahead, steps, strict=True)])
    curvature = np.diag(hessian)
    if not np.all(np.isfinite(hessian)) or np.any(curvature <= 0):
        return hessian  # not a minimum: the first pass says so
    lowest = np.minimum(0.1 * first, highest)
    steps = np.clip(HESSIAN_STEP_SIGMA / np.sqrt(curvature), lowest, highest)
    ends = gradients([centre + sign * h * e for h, e in zip(steps, axes, strict=True)
                      for sign in (1.0, -1.0)])
    return symmetric([(ends[2 * k] - ends[2 * k + 1]) / (2.0 * h)
                      for k, h in enumerate(steps)])


def hessian_at(functions, detector, model, data, track, threads: int | None = None):
    """``local_hessian`` at ``track`` about its own direction, that ``FitFrame``, and
    the (value, gradient) there (``local_value_and_grad``; the Hessian's first pass and
    ``polish`` start from it)."""
    dtype = data.charge.dtype
    frame = fit_frame(detector.shape, track.direction, model.energy_range, track.particle,
                      0.0, dtype)
    fixed = cast_track(track, dtype)
    centre = local_value_and_grad(functions, frame, fixed, data)(
        np.asarray(local_from_track(fixed, dtype), np.float64))
    wall = float(detector.shape.distance_to_wall(np.asarray(track.position, np.float64)))
    return local_hessian(functions, frame, fixed, data, wall, centre[1], threads), frame, \
        centre


def covariance_from_hessian(hessian) -> np.ndarray:
    """The covariance: the inverse of a (7, 7) ``hessian`` of the negative
    log-likelihood (units: inverse squares of the coordinates'); all NaN where it is not
    positive definite."""
    try:
        np.linalg.cholesky(hessian)
    except np.linalg.LinAlgError:
        return np.full_like(hessian, np.nan)
    return np.linalg.inv(hessian)


#: Most Newton steps of ``polish``.
POLISH_STEPS = 3


def polish(functions, detector, model, frame, track: Track, data, hessian,
           tolerance: float, centre=None) -> tuple[Track, float, float, int]:
    """Newton steps from a fitted ``track`` on its positive-definite ``hessian``
    (``local_hessian``, ``LOCAL`` coordinates about ``frame``'s axis, the rays fixed by
    ``track``), while a step is predicted to lower the negative log-likelihood by more
    than ``tolerance`` and does lower it, at most ``POLISH_STEPS``; a step that would
    leave the detector or the emission model's energy range is not taken. ``centre``:
    None, or the (value, gradient) at ``track`` in those coordinates, if known.

    L-BFGS stops along the flat vertex-energy valley of a track likelihood where its
    last steps lowered it by less than the tolerance, which can leave several tenths of
    a unit of -log L (and a centimetre) to the minimum; the Hessian from differences
    over one sigma sees that valley's curvature, and its Newton step closes the gap.

    Returns:
        The track (the Hessian's point, or where the last accepted step ended), -log L
        there, the decrease a Newton step from there predicts (g H^-1 g / 2, units of
        -log L; infinite where the step would leave the detector or the energy range),
        and the number of likelihood evaluations.
    """
    dtype = data.charge.dtype
    fixed = cast_track(track, dtype)
    value_and_grad = local_value_and_grad(functions, frame, fixed, data)
    point = np.asarray(local_from_track(fixed, dtype), np.float64)
    value, gradient = value_and_grad(point) if centre is None else centre
    evaluations, moved = int(centre is None), False
    low, high = (math.log(e) for e in model.energy_range)

    def newton(point, gradient):
        step = -np.linalg.solve(hessian, gradient)
        trial = point + step
        inside = float(detector.shape.distance_to_wall(trial[:3])) > 0.0 and \
            low < trial[6] < high
        return trial, -0.5 * float(gradient @ step) if inside else math.inf

    trial, remaining = newton(point, gradient)
    for _ in range(POLISH_STEPS):
        if not tolerance < remaining < math.inf:
            break
        trial_value, trial_gradient = value_and_grad(trial)
        evaluations += 1
        if not trial_value < value:
            break
        point, value, gradient, moved = trial, trial_value, trial_gradient, True
        trial, remaining = newton(point, gradient)
    fitted = _concrete(track_from_local(frame, jnp.asarray(point, dtype))) if moved \
        else track
    return fitted, value, remaining, evaluations


def _failure(reason, start, iterations) -> RecoResult:
    result = RecoResult.failed(reason, start.particle, "gradient", 0.0)
    return dataclasses.replace(result, iterations=iterations)


def minimise_minuit(functions, detector, model, data, start, settings) -> RecoResult:
    """MIGRAD (numerical derivatives) from ``start``, errors by HESSE, with the same
    reference refreshes."""
    from iminuit import Minuit

    dtype = data.charge.dtype
    reference, iterations, evaluations, converged = start, 0, 0, False
    minuit = None
    schedule = fit_stages(settings, charge_stage=False)
    _, slopes = next(schedule)
    for _ in itertools.count():
        frame = fit_frame(detector.shape, reference.direction, model.energy_range,
                          start.particle, settings.margin, dtype)
        fixed = cast_track(reference, dtype)
        staged = staged_data(functions, data, fixed, settings, slopes)

        def objective(x, frame=frame, fixed=fixed, staged=staged):
            return float(functions.value(jnp.asarray(x, dtype), frame, fixed, staged))

        free = np.asarray(free_from_track(frame, fixed), np.float64)
        minuit = Minuit(objective, free, name=FREE_NAMES)
        minuit.errordef = Minuit.LIKELIHOOD
        minuit.errors = INITIAL_STEPS
        minuit.migrad(ncall=settings.max_iterations * 20)
        evaluations += minuit.nfcn
        iterations += 1
        converged = bool(minuit.valid)
        if not math.isfinite(minuit.fval):
            return _failure("the likelihood is not finite", start, evaluations)
        fitted = _concrete(track_from_free(frame, jnp.asarray(np.asarray(minuit.values),
                                                              dtype)))
        moved = _moved(reference, fitted, settings)
        reference = fitted
        try:
            _, slopes = schedule.send(moved)
        except StopIteration:
            break
    before = minuit.nfcn  # a running count: MIGRAD's calls are counted above
    minuit.hesse()
    evaluations += minuit.nfcn - before
    covariance = _local_covariance(frame, np.asarray(minuit.values), reference,
                                   np.asarray(minuit.covariance, np.float64), dtype)
    converged = converged and bool(minuit.fmin.has_posdef_covar)
    return RecoResult(position=np.asarray(reference.position), time=float(reference.time),
                      direction=np.asarray(reference.direction),
                      energy=float(reference.energy), covariance=covariance,
                      nll=float(minuit.fval), particle=start.particle, converged=converged,
                      iterations=iterations, seconds=0.0, method="minuit",
                      evaluations=evaluations)


#: Names of the free coordinates (``coordinates``), for MINUIT.
FREE_NAMES = ("q1", "q2", "q3", "t", "a", "b", "eta")
#: MINUIT's first step sizes in the free coordinates (about 10 cm at the centre of SK,
#: 1 ns, 1 degree, a few % of the energy).
INITIAL_STEPS = (0.01, 0.01, 0.01, 1.0, 0.02, 0.02, 0.05)


def _local_covariance(frame, free, fitted: Track, covariance, dtype) -> np.ndarray:
    """A covariance of the free coordinates at ``free`` as one in ``LOCAL`` coordinates
    about the ``fitted`` track (the Jacobian of the coordinate change)."""
    axis = jnp.asarray(fitted.direction, dtype)
    first, second = orthonormal_basis(axis)  # the angles' basis of ``_covariance``

    def local(x):
        track = track_from_free(frame, x)
        along = jnp.sum(track.direction * axis)
        return jnp.concatenate([track.position, jnp.stack([
            track.time, jnp.sum(track.direction * first) / along,
            jnp.sum(track.direction * second) / along, jnp.log(track.energy)])])

    jacobian = np.asarray(jax.jacfwd(local)(jnp.asarray(free, dtype)), np.float64)
    return jacobian @ covariance @ jacobian.T

