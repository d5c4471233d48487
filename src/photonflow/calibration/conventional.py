"""The conventional sequential calibration: the baseline the joint fit is measured against.

Detector calibrations are traditionally done one block at a time, each block with its
own dedicated method and the other parameters frozen at their current values:

a. **relative sensor efficiency** from a central isotropic source: each sensor's charge
   divided by its geometric expectation for direct light (the photons x the fraction
   emitted towards its disc (exact solid angle) x quantum efficiency x angular
   acceptance x the direct-light attenuation exp(-d / L_att) at the current lengths),
   normalised to the mean of the starting efficiencies (a relative table);
b. **attenuation length** from the slope of log(charge / (geometric expectation x
   efficiency)) versus source-sensor distance d, a weighted straight line through the
   isotropic runs other than the central one (whose charges made the efficiencies),
   one intercept per run: -slope = 1 / L_att = 1 / L_abs + 1 / L_scat + 1 / L_mie, so
   L_abs follows from the current scattering lengths;
c. **every other optical parameter** (scattering length, reflectivities, ...) by a
   one-dimensional scan of the full expected-mode likelihood of all runs
   (``objective.CalibrationProblem`` with that one field free), the others frozen: a
   coarse grid, then a parabola through a finer one, whose curvature gives the error;
d. the blocks repeated a few times, each starting from the others' latest values.

Blocks a and b treat the charge as direct light only (the geometric acceptance knows
nothing of scattered or reflected light), which is how these methods are used, and no
block sees the correlations between the blocks. Scattered and reflected light raise the
charge of far sensors relative to near ones, so the slope gives too long an effective
attenuation length, and the efficiencies absorb the indirect light's pattern over the
detector. ``indirect="subtract"`` is the Monte Carlo-corrected variant: before blocks a
and b, the indirect light the expected mode predicts at the current values is
subtracted. Units: m, ns, p.e.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import jax
import numpy as np

from ..errors import ConfigError
from ..geometry.detector import Detector
from ..params import Params, validate_params
from ..transport.optics import TransportConfig
from .direct_blocks import (
    DirectLightBlocks,
    DirectRun,
    attenuation_inverse,
    attenuation_slope,
    direct_run,
    predicted_indirect,
)
from .layout import free_layout
from .result import CalibrationResult
from .runs import prepare_runs, run_provenance
from .scans import SCAN_STEP, LikelihoodScanner, physical_value

#: Also importable from here: the direct-light blocks' reduction and fits.
__all__ = [
    "DirectRun",
    "attenuation_inverse",
    "attenuation_slope",
    "direct_run",
    "predicted_indirect",
    "sequential_calibration",
]

#: Scalar fields the sequential method fits by a one-dimensional likelihood scan (block c).
SCAN_FIELDS = (
    "scattering_length",
    "mie_length",
    "mie_g",
    "wall_reflectivity",
    "wall_specular_fraction",
    "sensor_reflectivity",
    "quantum_efficiency",
)

#: Every field ``sequential_calibration`` can fit.
SEQUENTIAL_FIELDS = ("absorption_length", "efficiency", *SCAN_FIELDS)

#: How blocks a and b treat scattered and reflected light (``sequential_calibration``).
INDIRECT = ("ignore", "subtract")

def _check_free(free, n_sensors: int) -> tuple[str, ...]:
    """The free field names in ``Params`` order; one-line error for any this method does
    not fit."""
    layout = free_layout(free, n_sensors)
    bad = [name for name in layout.names if name not in SEQUENTIAL_FIELDS]
    if bad:
        raise ConfigError(
            f"free: {', '.join(bad)}: the sequential calibration fits only"
            f" {', '.join(SEQUENTIAL_FIELDS)}"
        )
    return layout.names


def sequential_calibration(
    detector: Detector,
    runs,
    init_params: Params,
    free: Sequence[str] | str,
    *,
    config: TransportConfig | None = None,
    key=None,
    n_iterations: int = 3,
    indirect: str = "ignore",
    central_run: int | None = None,
    min_charge: float = 20.0,
    scan_step: float = SCAN_STEP,
    step_tolerance: float = 0.1,
    truth: Params | None = None,
    callback: Callable[[int, float, dict], None] | None = None,
) -> CalibrationResult:
    """Calibrate the ``free`` fields the conventional way: one block at a time, iterated.

    Blocks, in this order in every iteration (module docstring): ``efficiency`` from the
    central isotropic run corrected by its direct-light geometric acceptance;
    ``absorption_length`` from the slope of log charge versus distance over the other
    isotropic runs; every other free field (``SCAN_FIELDS``) by a one-dimensional scan
    of the expected-mode charge likelihood of all runs. Each block uses the others'
    current values.

    Args:
        detector: the detector the runs were recorded in.
        runs: (source, events) pairs or ``CalibrationRun``s, as for ``calibrate``;
            ``efficiency`` needs an isotropic run near the centre, ``absorption_length``
            isotropic runs that span a range of distances.
        init_params: starting values; fields not in ``free`` stay at them.
        free: fields to fit, a subset of ``SEQUENTIAL_FIELDS``.
        config: expected-mode settings for the scans (rays, bounces, readout window in
            ns relative to the source time, also used for the dark-noise subtraction).
        key: ``jax.random`` key of the expected mode's rays (default ``key(0)``).
        n_iterations: passes through the blocks (at most).
        indirect: "ignore" (the textbook method: blocks a and b take all charge for
            direct light) or "subtract" (before blocks a and b of every pass, the
            scattered and reflected light the expected mode predicts at the current
            values is subtracted: the Monte Carlo-corrected variant).
        central_run: index of the run for the efficiencies (default: the isotropic run
            nearest the centre of the sensor array).
        min_charge: sensors whose predicted direct light in a run (at the current values)
            is below this (p.e., summed over the run's events) are not used by the
            efficiency and slope blocks.
        scan_step: coarse-grid step of the scans, unconstrained units.
        step_tolerance: stop early when a pass moves every free value by less than this
            many of its errors.
        truth: the true parameters, kept for pulls (pseudo-data).
        callback: called after every pass with (iteration, -log L, values of the free
            scalars).

    Returns:
        ``CalibrationResult`` with ``method = "sequential"``. Its errors are each block's
        own (conditional on the other blocks; efficiencies from counting statistics of
        the central run, L_abs from the slope fit, scanned fields from the scan's
        curvature); the correlation matrix is NaN off the diagonal (not estimated).
        ``settings["likelihood_evaluations"]`` counts the evaluations of -log L of all
        runs (one expected-mode transport per run each).

    Raises:
        ConfigError: bad runs, parameters or names, a field this method does not fit,
            no isotropic run where one is needed (one line each).
    """
    started = time.perf_counter()
    validate_params(init_params, detector.n_sensors)
    names = _check_free(free, detector.n_sensors)
    if int(n_iterations) < 1:
        raise ConfigError(f"n_iterations = {n_iterations}: must be >= 1")
    if indirect not in INDIRECT:
        raise ConfigError(f"indirect = {indirect!r}: must be one of {', '.join(INDIRECT)}")
    config = TransportConfig() if config is None else config
    key = jax.random.key(0) if key is None else key
    prepared = prepare_runs(runs, detector, "charge")
    blocks = DirectLightBlocks.prepare(detector, prepared, init_params, names, central_run,
                                       config, key, indirect, min_charge)
    scanner = LikelihoodScanner(detector, prepared, config, key)
    params = init_params
    errors = {name: np.zeros_like(np.asarray(getattr(init_params, name), np.float64))
              for name in names}
    history = [{"iteration": 0, "loss": scanner.loss(params), "time_s": 0.0,
                "values": _scalar_values(params, names)}]
    converged, message = False, f"stopped after n_iterations = {n_iterations}"
    for iteration in range(1, int(n_iterations) + 1):
        before = params
        params = blocks.direct_light_blocks(params, errors)
        for name in (name for name in names if name in SCAN_FIELDS):
            result = scanner.scan(params, name, scan_step)
            value, errors[name] = physical_value(name, result.value, result.sigma, params)
            params = params.replace(**{name: value})
        loss = scanner.loss(params)
        values = _scalar_values(params, names)
        history.append({"iteration": iteration, "loss": loss,
                        "time_s": time.perf_counter() - started, "values": values})
        if callback is not None:
            callback(iteration, loss, values)
        moved = _largest_move(before, params, errors, names)
        if moved < step_tolerance:
            converged = True
            message = (f"converged: the last pass moved every free value by {moved:.2g}"
                       f" < {step_tolerance:g} of its error")
            break
    settings = {
        "n_rays": config.n_rays,
        "n_bounces": config.n_bounces,
        "window_ns": list(config.window),
        "n_iterations": int(n_iterations),
        "indirect": indirect,
        "min_charge_pe": float(min_charge),
        "scan_step": float(scan_step),
        "likelihood_evaluations": scanner.evaluations,
    }
    return _sequential_result(detector, prepared, params, errors, names, history, converged,
                              message, settings, truth, started)


def _sequential_result(detector, prepared, params, errors, names, history, converged, message,
                       settings, truth, started) -> CalibrationResult:
    """The ``CalibrationResult`` of a sequential calibration: each block's own errors, the
    correlation NaN off the diagonal (not estimated)."""
    error_params = Params.from_dict({
        name: errors.get(name, np.zeros_like(np.asarray(value, np.float64)))
        for name, value in params.to_dict().items()
    })
    dense = [name for name in names if name != "efficiency"]
    correlation = np.full((len(dense), len(dense)), np.nan)
    np.fill_diagonal(correlation, 1.0)
    return CalibrationResult(
        params=params,
        errors=error_params,
        correlation=correlation,
        correlation_names=tuple(dense),
        history=tuple(history),
        free=names,
        method="sequential",
        likelihood="charge",
        converged=converged,
        message=message,
        loss=history[-1]["loss"],
        settings=settings,
        runs=run_provenance(prepared),
        detector={"name": detector.name, "n_sensors": detector.n_sensors},
        truth=truth,
        wall_time_s=time.perf_counter() - started,
    )


def _scalar_values(params: Params, names: Sequence[str]) -> dict[str, float]:
    """Name -> physical value of every free scalar field."""
    return {name: float(getattr(params, name)) for name in names if name != "efficiency"}


def _largest_move(before: Params, after: Params, errors: dict, names) -> float:
    """The largest |change| / error over the free values in one pass (inf if an error
    is zero or not finite while the value moved)."""
    largest = 0.0
    for name in names:
        change = np.abs(np.asarray(getattr(after, name), np.float64)
                        - np.asarray(getattr(before, name), np.float64))
        error = np.asarray(errors[name], np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(change > 0, change / error, 0.0)
        ratio = np.where(np.isfinite(ratio), ratio, np.where(change > 0, np.inf, 0.0))
        largest = max(largest, float(np.max(ratio)) if ratio.size else 0.0)
    return largest
