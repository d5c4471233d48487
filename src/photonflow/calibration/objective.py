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
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.detector import Detector
from ..likelihood import charge_logpdf, dark_expectation, dense_sensor_nll, log1mexp
from ..params import Params, from_unconstrained, to_unconstrained
from ..prediction import Prediction
from ..transport.expected import expected_inputs, expected_jit
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
    n_events: jax.Array
    charge_sum: jax.Array
    hit_any: jax.Array
    hit: jax.Array | None
    charge: jax.Array | None
    time: jax.Array | None


jax.tree_util.register_dataclass(
    _RunArrays,
    data_fields=[
        "source", "key", "n_events", "charge_sum", "hit_any", "hit", "charge", "time"
    ],
    meta_fields=[],
)


@dataclasses.dataclass(frozen=True)
class _Static:
    """What a compiled run function depends on statically (hashable): the free layout,
    the likelihood, the detector's shape, the transport config, the run's readout
    window (ns) and the single-p.e. width (p.e.) of the Fisher information. Problems
    that share it share compiled code."""

    layout: FreeLayout
    likelihood: str
    shape: object
    config: TransportConfig
    window: tuple[float, float]
    spe_width: float


def _params_of(theta: dict, base: Params) -> Params:
    return from_unconstrained(dataclasses.replace(base, **theta))


def _prediction(theta, base, sensors, data, cached, static: _Static) -> Prediction:
    params = _params_of(theta, base)
    if cached is None:
        cached = _transport_jit(sensors, without_response(params), data.source, data.key,
                                shape=static.shape, config=static.config)
    return with_response(cached, params)


def _mean(theta, base, sensors, data, cached, static: _Static):
    """(N,) expected photoelectrons of the run, summed over its events, p.e."""
    prediction = _prediction(theta, base, sensors, data, cached, static)
    dark = dark_expectation(_params_of(theta, base), static.window)
    return data.n_events * (prediction.charge + dark)


def _run_nll(theta, base, sensors, data, cached, static: _Static):
    """-log L of one run."""
    if static.likelihood == "charge":
        mean = _mean(theta, base, sensors, data, cached, static)
        spe_width = _params_of(theta, base).spe_width
        return jnp.sum(summed_charge_nll(data.charge_sum, data.hit_any, mean, spe_width))
    prediction = _prediction(theta, base, sensors, data, cached, static)

    def event_nll(hit, charge, time):
        return jnp.sum(
            dense_sensor_nll(
                prediction, hit, charge, time, prediction.dark_rate,
                prediction.spe_width, static.window,
            )
        )

    return jnp.sum(jax.vmap(event_nll)(data.hit, data.charge, data.time))


def _tangents(layout: FreeLayout, dtype):
    """Tangent directions: one-hot per dense entry, then all-ones per per-sensor field
    (a sensor's terms depend on its own per-sensor values only, so the all-ones
    direction yields each sensor's own derivative)."""
    n_dense, n_columns, n = layout.n_dense, len(layout.sensor_fields), layout.n_sensors
    dense = np.zeros((n_dense + n_columns, n_dense))
    sensor = np.zeros((n_dense + n_columns, n, n_columns))
    dense[np.arange(n_dense), np.arange(n_dense)] = 1.0
    for column in range(n_columns):
        sensor[n_dense + column, :, column] = 1.0
    return jnp.asarray(dense, dtype), jnp.asarray(sensor, dtype)


def _fisher_run(theta, base, sensors, data, cached, static: _Static):
    """(value, gradient (P,), (N, F), Fisher parts A, C, B) of one run, charge
    likelihood: J from forward-mode derivatives of M, I(M) from ``information``."""
    layout = static.layout
    dense0, sensor0 = layout.split(theta)

    def mean_of(dense, sensor):
        return _mean(layout.join(dense, sensor), base, sensors, data, cached, static)

    tangent_dense, tangent_sensor = _tangents(layout, data.charge_sum.dtype)
    mean, jac = jax.vmap(
        lambda td, ts: jax.jvp(mean_of, (dense0, sensor0), (td, ts)), out_axes=(None, 0)
    )(tangent_dense, tangent_sensor)
    spe_width = _params_of(theta, base).spe_width

    def total(m):
        return jnp.sum(summed_charge_nll(data.charge_sum, data.hit_any, m, spe_width))

    value, score = jax.value_and_grad(total)(mean)
    weight = charge_information(mean, static.spe_width)
    jac_dense = jac[: layout.n_dense].T  # (N, P)
    jac_sensor = jac[layout.n_dense:].T  # (N, F)
    grad_dense = jac_dense.T @ score
    grad_sensor = jac_sensor * score[:, None]
    a = jac_dense.T @ (weight[:, None] * jac_dense)
    c = (weight[:, None] * jac_sensor)[:, :, None] * jac_dense[:, None, :]
    b = (weight[:, None] * jac_sensor)[:, :, None] * jac_sensor[:, None, :]
    return value, grad_dense, grad_sensor, a, c, b


def _hessian_run(theta, base, sensors, data, cached, static: _Static):
    """(value, gradient, observed-information parts A, C, B) of one run from
    Hessian-vector products along the tangents of ``_tangents``."""
    layout = static.layout
    dense0, sensor0 = layout.split(theta)

    def nll_of(dense, sensor):
        return _run_nll(layout.join(dense, sensor), base, sensors, data, cached, static)

    gradient = jax.grad(nll_of, argnums=(0, 1))
    value, (grad_dense, grad_sensor) = jax.value_and_grad(nll_of, argnums=(0, 1))(
        dense0, sensor0
    )
    tangent_dense, tangent_sensor = _tangents(layout, data.charge_sum.dtype)
    h_dense, h_sensor = jax.lax.map(
        lambda pair: jax.jvp(gradient, (dense0, sensor0), pair)[1],
        (tangent_dense, tangent_sensor),
    )
    n_dense = layout.n_dense
    a = h_dense[:n_dense]  # (P, P)
    c = jnp.moveaxis(h_sensor[:n_dense], 0, -1)  # (N, F, P)
    b = jnp.moveaxis(h_sensor[n_dense:], 0, -1)  # (N, F, F)
    return value, grad_dense, grad_sensor, a, c, b


_run_nll_jit = jax.jit(_run_nll, static_argnames=("static",))
_value_and_grad_jit = jax.jit(jax.value_and_grad(_run_nll), static_argnames=("static",))
_fisher_jit = jax.jit(_fisher_run, static_argnames=("static",))
_hessian_jit = jax.jit(_hessian_run, static_argnames=("static",))


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
        spe_width = float(init_params.spe_width)
        if likelihood == "charge":
            information_table(spe_width)  # built here, outside jit (cached)
        dtype = jnp.result_type(init_params.absorption_length)
        self.sensors = expected_inputs(detector, dtype)
        per_event = likelihood == "charge+time"
        self.arrays = [
            _RunArrays(
                source=jax.tree.map(lambda x: jnp.asarray(x, dtype), run.source),
                key=jax.random.fold_in(key, index),
                n_events=jnp.asarray(run.n_events, dtype),
                charge_sum=jnp.asarray(run.charge_sum, dtype),
                hit_any=jnp.asarray(run.hit_any),
                hit=jnp.asarray(run.hit) if per_event else None,
                charge=jnp.asarray(run.charge, dtype) if per_event else None,
                time=jnp.asarray(run.time, dtype) if per_event else None,
            )
            for index, run in enumerate(runs)
        ]
        self.statics = [
            _Static(
                layout=layout, likelihood=likelihood, shape=detector.shape, config=config,
                window=tuple(float(run.source.time) + w for w in config.window),
                spe_width=spe_width,
            )
            for run in runs
        ]
        self.cached = [None] * len(runs)
        if not layout.needs_transport:
            theta = self.initial_theta()
            transport = without_response(self.params_of(theta))
            self.cached = [
                _transport_jit(self.sensors, transport, data.source, data.key,
                               shape=detector.shape, config=config)
                for data in self.arrays
            ]

    def initial_theta(self) -> dict:
        """The free fields of the initial parameters, unconstrained."""
        return self.layout.select(self.base)

    def params_of(self, theta: dict) -> Params:
        """Physical ``Params`` of free values ``theta`` (fixed fields from the start)."""
        return _params_of(theta, self.base)

    def _each(self, function, theta):
        for data, cached, static in zip(self.arrays, self.cached, self.statics, strict=True):
            yield function(theta, self.base, self.sensors, data, cached, static=static)

    def value(self, theta: dict) -> float:
        """-log L of all runs at ``theta``."""
        return float(sum(float(v) for v in self._each(_run_nll_jit, theta)))

    def value_and_grad(self, theta: dict) -> tuple[float, dict]:
        """(-log L, its gradient as a ``theta``-shaped dict)."""
        total, gradient = 0.0, None
        for value, grad in self._each(_value_and_grad_jit, theta):
            total += float(value)
            gradient = grad if gradient is None else jax.tree.map(jnp.add, gradient, grad)
        return total, gradient

    def curvature(self, theta: dict) -> tuple[float, np.ndarray, np.ndarray, StructuredMatrix]:
        """(-log L, gradient dense (P,), gradient per sensor (N, F), curvature): the
        expected Fisher information for the charge likelihood, the observed information
        for charge+time. Arrays in float64 numpy."""
        parts = _fisher_jit if self.likelihood == "charge" else _hessian_jit
        sums = None
        for run in self._each(parts, theta):
            run = [np.asarray(x, dtype=np.float64) for x in run]
            sums = run if sums is None else [s + x for s, x in zip(sums, run, strict=True)]
        value, grad_dense, grad_sensor, a, c, b = sums
        return float(value), grad_dense, grad_sensor, StructuredMatrix(a, c, b)


@functools.partial(jax.jit, static_argnames=("shape", "config"))
def _transport_jit(sensors, params, source, key, *, shape, config) -> Prediction:
    positions, normals, radius, grid, near_grid = sensors
    return expected_jit(
        positions, normals, radius, grid, params, source, key, near_grid,
        shape=shape, config=config,
    )
