"""The calibration objective: -log L of every run, its gradient and its curvature.

Per run r with source s_r and E_r events, the expected-mode prediction is the light
transport's ``SensorLight`` followed by the sensor response
(``response.expected_response``), as in ``expected``: when only response fields are
free (efficiencies, time offsets, transit-time spread, dark rate, single-p.e. width)
the transport runs once per run, not per step.

Likelihoods (``CalibrationProblem(..., likelihood=...)``):

- ``"charge"``: the run-level likelihood of each sensor's charge summed over the run's
  events. Summed over E events the photoelectron count is Poisson with mean
  M = E (mu_signal + mu_dark) and the summed charge is a sum of that many single-p.e.
  charges, so the per-event charge model (``photonflow.likelihood.charge_logpdf``) with
  mean M is the exact likelihood of the sum (``summed_charge_nll``). Its curvature is
  the expected Fisher information J^T diag(I(M)) J (``information.py``).
- ``"charge+time"``: the per-event likelihood of charge and first-hit time
  (``photonflow.likelihood.dense_sensor_nll``) summed over events and runs. Its
  curvature is the expected Fisher information too: per event and sensor, the charge
  part I(mu) J J^T (the per-event charge model is the summed one with M = mu) plus
  P(hit) E[s s^T] of the first-hit time density, s its score, by quadrature over the
  first-hit quantiles (``information.py``). When only ``time_offset`` and ``tts`` are
  free the charge terms are constant: they are evaluated once and only the time terms
  per step.

Both curvatures are assembled in the per-sensor block structure of ``structured.py``.
-log L is accumulated in float64 on the host from float32 terms (per sensor and event),
so that changes of 1e-3 stay resolved in sums of 10^6 terms.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..geometry.detector import Detector
from ..geometry.sensor_arrays import sensors_for
from ..params import Params, to_unconstrained
from ..transport.optics import TransportConfig
from .independent_rays import (
    JACOBIAN_RAY_STREAM,
    NOISE_RAY_STREAM,
    IndependentRayParts,
    IndependentRays,
    RayNoiseSets,
    ray_noise_score_bias,
    ray_set_keys,
)
from .information import information_table, score_curvature_table
from .layout import FreeLayout
from .run_terms import (
    TIME_FIELDS,
    RunArrays,
    RunStatic,
    charge_jacobian_jit,
    charge_terms_jit,
    event_fisher_jit,
    fisher_jit,
    mean_jit,
    median_jit,
    physical_params,
    run_mirror_paths,
    sensor_light_jit,
    summed_charge_nll,
    terms_jit,
    total_in_float64,
    value_and_grad_jit,
)
from .runs import RunData
from .structured import StructuredMatrix

__all__ = [
    "CalibrationProblem",
    "IndependentRayParts",
    "RayNoiseSets",
    "ray_noise_score_bias",
    "ray_set_keys",
    "summed_charge_nll",
]


class CalibrationProblem(IndependentRays):
    """-log L of a set of runs as a function of the free parameters (unconstrained).

    Args:
        detector: the detector the runs were recorded in.
        runs: the reduced runs (``prepare_runs``).
        init_params: starting parameters; fixed fields stay at these values.
        layout: the free fields (``free_layout``).
        likelihood: "charge" or "charge+time".
        config: transport settings of the expected mode (rays, bounces, window ns).
        key: ``jax.random`` key; run r's rays use ``fold_in(key, r)``.
    """

    def __init__(
        self,
        detector: Detector,
        runs: list[RunData],
        init_params: Params,
        layout: FreeLayout,
        likelihood: str,
        config: TransportConfig,
        key: jax.Array,
    ):
        self.detector = detector
        self.runs = runs
        self.layout = layout
        self.likelihood = likelihood
        self.config = config
        self.base = to_unconstrained(init_params)
        spe_width = float(init_params.spe_width)
        information_table(spe_width)  # built here, outside jit (cached)
        score_curvature_table(spe_width)
        dtype = jnp.result_type(init_params.absorption_length)
        self.sensors = sensors_for(detector, dtype)
        per_event = likelihood == "charge+time"
        sources = [jax.tree.map(lambda x: jnp.asarray(x, dtype), run.source) for run in runs]
        self.arrays = [
            RunArrays(
                source=source,
                key=jax.random.fold_in(key, index),
                n_events=jnp.asarray(run.n_events, dtype),
                charge_sum=jnp.asarray(run.charge_sum, dtype),
                hit_any=jnp.asarray(run.hit_any),
                hit=jnp.asarray(run.hit) if per_event else None,
                charge=jnp.asarray(run.charge, dtype) if per_event else None,
                time=jnp.asarray(run.time, dtype) if per_event else None,
                mirror=run_mirror_paths(self.sensors, source, detector.shape, config),
            )
            for index, (run, source) in enumerate(zip(runs, sources, strict=True))
        ]
        #: per run, the keys of its independent ray sets (``independent_ray_curvature``)
        self.jacobian_keys = [
            jax.random.fold_in(data.key, JACOBIAN_RAY_STREAM) for data in self.arrays
        ]
        self.noise_keys = [
            jax.random.fold_in(data.key, NOISE_RAY_STREAM) for data in self.arrays
        ]
        time_only = per_event and set(layout.names) <= TIME_FIELDS
        self.statics = [
            RunStatic(
                layout=layout, likelihood=likelihood, shape=detector.shape, config=config,
                window=tuple(float(run.source.time) + w for w in config.window),
                spe_width=spe_width, terms="time" if time_only else "all",
            )
            for run in runs
        ]
        self.cached = [None] * len(runs)
        if not layout.needs_transport:
            theta = self.initial_theta()
            params = self.params_of(theta)
            self.cached = [
                sensor_light_jit(self.sensors, params, data.source, data.key, data.mirror,
                                  shape=detector.shape, config=config)
                for data in self.arrays
            ]
        # -log L of the terms the free values do not change (the charges when only time
        # fields are free), evaluated once
        self.constant = 0.0
        if time_only:
            theta = self.initial_theta()
            self.constant = sum(
                total_in_float64(terms_jit(theta, self.base, self.sensors, data, cached,
                                  static=dataclasses.replace(static, terms="charge")))
                for data, cached, static in zip(
                    self.arrays, self.cached, self.statics, strict=True
                )
            )

    def initial_theta(self) -> dict:
        """The free fields of the initial parameters, unconstrained."""
        return self.layout.select(self.base)

    def params_of(self, theta: dict) -> Params:
        """Physical ``Params`` of free values ``theta`` (fixed fields from the start)."""
        return physical_params(theta, self.base)

    def _each(self, function, theta):
        for data, cached, static in zip(self.arrays, self.cached, self.statics, strict=True):
            yield function(theta, self.base, self.sensors, data, cached, static=static)

    def value(self, theta: dict) -> float:
        """-log L of all runs at ``theta`` (summed in float64). The charge likelihood
        goes through the expected charges (``mean_jit``), the program that the ray-noise
        sets compile anyway: one compiled transport fewer."""
        if self.likelihood != "charge":
            return self.constant + sum(total_in_float64(t) for t in self._each(terms_jit, theta))
        return self.constant + sum(
            total_in_float64(charge_terms_jit(theta, self.base, data, mean))
            for data, mean in zip(self.arrays, self._each(mean_jit, theta), strict=True)
        )

    def value_and_grad(self, theta: dict) -> tuple[float, dict]:
        """(-log L, its gradient as a ``theta``-shaped dict)."""
        total, gradient = self.constant, None
        for (_, terms), grad in self._each(value_and_grad_jit, theta):
            total += total_in_float64(terms)
            gradient = grad if gradient is None else jax.tree.map(jnp.add, gradient, grad)
        return total, gradient

    def _summed(self, results) -> tuple[float, list[np.ndarray]]:
        """(-log L, the other parts summed over runs in float64) of per-run results
        (terms, *parts)."""
        value, sums = self.constant, None
        for terms, *run in results:
            value += total_in_float64(terms)
            run = [np.asarray(x, dtype=np.float64) for x in run]
            sums = run if sums is None else [s + x for s, x in zip(sums, run, strict=True)]
        return value, sums

    def curvature(self, theta: dict) -> tuple[float, np.ndarray, np.ndarray, StructuredMatrix]:
        """(-log L, gradient dense (P,), gradient per sensor (N, F), curvature): the
        expected Fisher information of the likelihood (charge, or charge and first-hit
        time). Arrays in float64 numpy."""
        if self.likelihood == "charge":
            per_run = (
                fisher_jit(theta, self.base, data, *jacobian, static=static)
                for data, static, jacobian in zip(
                    self.arrays, self.statics, self._each(charge_jacobian_jit, theta),
                    strict=True)
            )
        else:
            per_run = self._each(event_fisher_jit, theta)
        value, (grad_dense, grad_sensor, a, c, b) = self._summed(per_run)
        return value, grad_dense, grad_sensor, StructuredMatrix(a, c, b)

    def check_predictions(self, theta: dict) -> None:
        """Raise a one-line ``ConfigError`` naming the first run whose expected charge at
        ``theta`` is not finite (a run the expected mode cannot predict cannot be
        fitted)."""
        for index, (run, mean) in enumerate(zip(self.runs, self._each(mean_jit, theta),
                                                strict=True)):
            bad = np.flatnonzero(~np.isfinite(np.asarray(mean)))
            if bad.size:
                position = np.round(np.asarray(run.source.position, dtype=float), 4).tolist()
                raise ConfigError(
                    f"runs[{index}] ({run.label or 'events'}): the expected charge of"
                    f" {bad.size} sensors (first: {int(bad[0])}) is not finite for the"
                    f" source at {position} m at the starting parameters; this is a bug in"
                    " the expected mode: please report it with the source and detector"
                )

    def median_time_shift(self, theta: dict) -> np.ndarray:
        """(N,) ns: per sensor, the median over all runs' hits of (recorded first-hit time
        - the predicted median first-hit time at ``theta``); 0 for a sensor never hit.
        The time offset only shifts the first-hit distribution (up to the few dark
        hits), so adding this to the offsets is a consistent starting estimate.
        Needs the charge+time likelihood (per-event times)."""
        residuals = []
        for run, median in zip(self.runs, self._each(median_jit, theta), strict=True):
            median = np.asarray(median, np.float64)
            residuals.append(np.where(run.hit, run.time - median[None, :], np.nan))
        residuals = np.concatenate(residuals, axis=0)
        hit = np.any(np.isfinite(residuals), axis=0)
        shift = np.zeros(residuals.shape[1])
        shift[hit] = np.nanmedian(residuals[:, hit], axis=0)
        return shift
