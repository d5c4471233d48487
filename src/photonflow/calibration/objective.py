"""The calibration objective: -log L of every run, its gradient and its curvature.

Per run r with source s_r and E_r events, the expected-mode prediction is computed with
the sensor response taken out (efficiency 1, time offset 0, transit-time spread 0) and
put back afterwards (``with_response``): a sensor's charge is multiplied by its
efficiency, its times shifted by its offset, its time widths widened by the spread in
quadrature. This is exact (the expected mode applies them the same way) and means that
when only response fields are free the light transport runs once per run, not per step.

Likelihoods (``CalibrationProblem(..., likelihood=...)``):

- ``"charge"``: the run-level likelihood of each sensor's charge summed over the run's
  events. Summed over E events the photoelectron count is Poisson with mean
  M = E (mu_signal + mu_dark) and the summed charge is a sum of that many single-p.e.
  charges, so the per-event charge model (``photonflow.likelihood.charge_logpdf``) with
  mean M is the exact likelihood of the sum (``summed_charge_nll``). Its curvature is
  the expected Fisher information J^T diag(I(M)) J (``information.py``).
- ``"charge+time"``: the per-event likelihood of charge and first-hit time
  (``photonflow.likelihood.dense_sensor_nll``) summed over events and runs; its
  curvature is the observed information (Hessian of -log L) from autodiff.

Both curvatures are assembled in the per-sensor block structure of ``structured.py``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.detector import Detector
from ..likelihood import charge_logpdf, dark_expectation, dense_sensor_nll, log1mexp
from ..params import Params, from_unconstrained, to_unconstrained
from ..prediction import Prediction
from ..transport.expected import expected_function
from ..transport.optics import TransportConfig
from .information import charge_information, information_table
from .layout import FreeLayout
from .runs import RunData
from .structured import StructuredMatrix


def without_response(params: Params) -> Params:
    """``params`` with efficiency 1, time offset 0 and transit-time spread 0 (the light
    transport's own parameters only)."""
    return dataclasses.replace(
        params,
        efficiency=jnp.ones_like(params.efficiency),
        time_offset=jnp.zeros_like(params.time_offset),
        tts=jnp.zeros_like(params.tts),
    )


def with_response(transport: Prediction, params: Params) -> Prediction:
    """Apply the sensor response of ``params`` to a prediction made with
    ``without_response(params)``: charge x efficiency (p.e.), times + time offset (ns),
    widths sqrt(sigma^2 + tts^2) (ns); dark rate (Hz) and single-p.e. width attached."""
    return dataclasses.replace(
        transport,
        charge=transport.charge * params.efficiency,
        time_mean=transport.time_mean + params.time_offset[:, None],
        time_sigma=jnp.sqrt(transport.time_sigma**2 + params.tts**2),
        dark_rate=params.dark_rate,
        spe_width=params.spe_width,
    )


def summed_charge_nll(charge_sum, hit_any, mean, spe_width) -> jax.Array:
    """Per-sensor -log P of a run's summed charge (p.e.) given its mean number of
    photoelectrons M (p.e., signal + dark): M where nothing was recorded, else
    -log[(1 - e^-M) p(Q | M, n >= 1)]."""
    hit_term = log1mexp(mean) + charge_logpdf(charge_sum, mean, spe_width)
    return -jnp.where(hit_any, hit_term, -mean)


@dataclasses.dataclass(frozen=True)
class _RunArrays:
    """A run's data as JAX arrays (a pytree of leaves, passed to jitted functions)."""

    source: object
    key: jax.Array
    charge_sum: jax.Array
    hit_any: jax.Array
    hit: jax.Array | None
    charge: jax.Array | None
    time: jax.Array | None


jax.tree_util.register_dataclass(
    _RunArrays,
    data_fields=["source", "key", "charge_sum", "hit_any", "hit", "charge", "time"],
    meta_fields=[],
)


class CalibrationProblem:
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
        self.spe_width = float(init_params.spe_width)
        if likelihood == "charge":
            information_table(self.spe_width)  # built here, outside jit (cached)
        dtype = jnp.result_type(init_params.absorption_length)
        self.predict = expected_function(detector, dtype, config=config)
        per_event = likelihood == "charge+time"
        self.arrays = [
            _RunArrays(
                source=run.source,
                key=jax.random.fold_in(key, index),
                charge_sum=jnp.asarray(run.charge_sum, dtype),
                hit_any=jnp.asarray(run.hit_any),
                hit=jnp.asarray(run.hit) if per_event else None,
                charge=jnp.asarray(run.charge, dtype) if per_event else None,
                time=jnp.asarray(run.time, dtype) if per_event else None,
            )
            for index, run in enumerate(runs)
        ]
        self.windows = [
            tuple(float(run.source.time) + w for w in config.window) for run in runs
        ]
        if layout.needs_transport:
            self.cached = [None] * len(runs)
        else:
            transport = without_response(init_params)
            self.cached = [
                jax.block_until_ready(self.predict(transport, data.source, data.key))
                for data in self.arrays
            ]
        self._value_and_grad = jax.jit(
            jax.value_and_grad(self._run_nll), static_argnames=("window", "n_events")
        )
        self._run_nll_jit = jax.jit(self._run_nll, static_argnames=("window", "n_events"))
        self._fisher_parts = jax.jit(self._fisher_run, static_argnames=("window", "n_events"))
        self._hessian_parts = jax.jit(self._hessian_run, static_argnames=("window", "n_events"))

    # -- parameters ---------------------------------------------------------------

    def initial_theta(self) -> dict:
        """The free fields of the initial parameters, unconstrained."""
        return self.layout.select(self.base)

    def params_of(self, theta: dict) -> Params:
        """Physical ``Params`` of free values ``theta`` (fixed fields from the start)."""
        return from_unconstrained(dataclasses.replace(self.base, **theta))

    # -- one run --------------------------------------------------------------------

    def _prediction(self, theta, data, cached) -> Prediction:
        params = self.params_of(theta)
        transport = (
            cached if cached is not None
            else self.predict(without_response(params), data.source, data.key)
        )
        return with_response(transport, params)

    def _mean(self, theta, data, cached, window, n_events):
        """(N,) expected photoelectrons of the run, summed over its events, p.e."""
        prediction = self._prediction(theta, data, cached)
        dark = dark_expectation(self.params_of(theta), window)
        return n_events * (prediction.charge + dark)

    def _run_nll(self, theta, data, cached, window, n_events):
        if self.likelihood == "charge":
            mean = self._mean(theta, data, cached, window, n_events)
            spe_width = self.params_of(theta).spe_width
            return jnp.sum(summed_charge_nll(data.charge_sum, data.hit_any, mean, spe_width))
        prediction = self._prediction(theta, data, cached)

        def event_nll(hit, charge, time):
            return jnp.sum(
                dense_sensor_nll(
                    prediction, hit, charge, time, prediction.dark_rate,
                    prediction.spe_width, window,
                )
            )

        return jnp.sum(jax.vmap(event_nll)(data.hit, data.charge, data.time))

    def _tangents(self):
        """Tangent directions: one-hot per dense entry, then all-ones per per-sensor
        field (a sensor's terms depend on its own per-sensor values only, so the
        all-ones direction yields each sensor's own derivative)."""
        n_dense, n_columns = self.layout.n_dense, len(self.layout.sensor_fields)
        n = self.layout.n_sensors
        dense = np.zeros((n_dense + n_columns, n_dense))
        sensor = np.zeros((n_dense + n_columns, n, n_columns))
        dense[np.arange(n_dense), np.arange(n_dense)] = 1.0
        for column in range(n_columns):
            sensor[n_dense + column, :, column] = 1.0
        return dense, sensor

    def _fisher_run(self, theta, data, cached, window, n_events):
        """(value, gradient (P,), (N, F), Fisher parts A, C, B) of one run, charge
        likelihood: J from forward-mode derivatives of M, I(M) from ``information``."""
        layout = self.layout
        dense0, sensor0 = layout.split(theta)

        def mean_of(dense, sensor):
            return self._mean(layout.join(dense, sensor), data, cached, window, n_events)

        tangent_dense, tangent_sensor = self._tangents()
        dtype = dense0.dtype if dense0.size else sensor0.dtype
        mean, jac = jax.vmap(
            lambda td, ts: jax.jvp(mean_of, (dense0, sensor0), (td, ts)), out_axes=(None, 0)
        )(jnp.asarray(tangent_dense, dtype), jnp.asarray(tangent_sensor, dtype))
        spe_width = self.params_of(theta).spe_width

        def total(m):
            return jnp.sum(summed_charge_nll(data.charge_sum, data.hit_any, m, spe_width))

        value, score = jax.value_and_grad(total)(mean)
        weight = charge_information(mean, self.spe_width)
        n_dense = layout.n_dense
        jac_dense = jac[:n_dense].T  # (N, P)
        jac_sensor = jac[n_dense:].T  # (N, F)
        grad_dense = jac_dense.T @ score
        grad_sensor = jac_sensor * score[:, None]
        a = jac_dense.T @ (weight[:, None] * jac_dense)
        c = (weight[:, None] * jac_sensor)[:, :, None] * jac_dense[:, None, :]
        b = (weight[:, None] * jac_sensor)[:, :, None] * jac_sensor[:, None, :]
        return value, grad_dense, grad_sensor, a, c, b

    def _hessian_run(self, theta, data, cached, window, n_events):
        """(value, gradient, observed-information parts A, C, B) of one run from
        Hessian-vector products along the tangents of ``_tangents``."""
        layout = self.layout
        dense0, sensor0 = layout.split(theta)

        def nll_of(dense, sensor):
            return self._run_nll(layout.join(dense, sensor), data, cached, window, n_events)

        value, (grad_dense, grad_sensor) = jax.value_and_grad(nll_of, argnums=(0, 1))(
            dense0, sensor0
        )
        tangent_dense, tangent_sensor = self._tangents()
        dtype = dense0.dtype if dense0.size else sensor0.dtype
        gradient = jax.grad(nll_of, argnums=(0, 1))

        def hvp(td, ts):
            return jax.jvp(gradient, (dense0, sensor0), (td, ts))[1]

        h_dense, h_sensor = jax.lax.map(
            lambda pair: hvp(*pair),
            (jnp.asarray(tangent_dense, dtype), jnp.asarray(tangent_sensor, dtype)),
        )
        n_dense = layout.n_dense
        a = h_dense[:n_dense]  # (P, P)
        c = jnp.moveaxis(h_sensor[:n_dense], 0, -1)  # (N, F, P)
        b = jnp.moveaxis(h_sensor[n_dense:], 0, -1)  # (N, F, F)
        return value, grad_dense, grad_sensor, a, c, b

    # -- all runs -----------------------------------------------------------------------

    def _each_run(self):
        for data, cached, window, run in zip(
            self.arrays, self.cached, self.windows, self.runs, strict=True
        ):
            yield data, cached, window, run.n_events

    def value(self, theta: dict) -> float:
        """-log L of all runs at ``theta``."""
        return float(
            sum(
                self._run_nll_jit(theta, data, cached, window=window, n_events=n)
                for data, cached, window, n in self._each_run()
            )
        )

    def value_and_grad(self, theta: dict) -> tuple[float, dict]:
        """(-log L, its gradient as a ``theta``-shaped dict)."""
        total, gradient = 0.0, None
        for data, cached, window, n in self._each_run():
            value, grad = self._value_and_grad(theta, data, cached, window=window, n_events=n)
            total += float(value)
            gradient = grad if gradient is None else jax.tree.map(jnp.add, gradient, grad)
        return total, gradient

    def curvature(self, theta: dict) -> tuple[float, np.ndarray, np.ndarray, StructuredMatrix]:
        """(-log L, gradient dense (P,), gradient per sensor (N, F), curvature): the
        expected Fisher information for the charge likelihood, the observed information
        for charge+time. Arrays in float64 numpy."""
        parts = self._fisher_parts if self.likelihood == "charge" else self._hessian_parts
        sums = None
        for data, cached, window, n in self._each_run():
            run = parts(theta, data, cached, window=window, n_events=n)
            run = [np.asarray(x, dtype=np.float64) for x in run]
            sums = run if sums is None else [s + x for s, x in zip(sums, run, strict=True)]
        value, grad_dense, grad_sensor, a, c, b = sums
        return float(value), grad_dense, grad_sensor, StructuredMatrix(a, c, b)
