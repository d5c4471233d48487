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
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..geometry.detector import Detector
from ..geometry.sensor_arrays import sensors_for
from ..likelihood import (
    charge_logpdf,
    dark_expectation,
    dense_sensor_nll,
    first_hit_logpdf,
    log1mexp,
)
from ..numerics import where
from ..params import Params, from_unconstrained, to_unconstrained
from ..prediction import Prediction
from ..response.expected import SensorLight, expected_response
from ..transport.expected import sensor_light
from ..transport.mirror import MirrorPaths, mirror_paths
from ..transport.optics import TransportConfig
from .information import (
    charge_information,
    expected_score_curvature,
    first_hit_quantiles,
    first_hit_scores_information,
    information_table,
    score_curvature_table,
    time_nodes,
)
from .layout import FreeLayout
from .runs import RunData
from .structured import SandwichCovariance, StructuredMatrix


def summed_charge_nll(charge_sum, hit_any, mean, spe_width) -> jax.Array:
    """Per-sensor -log P of a run's summed charge (p.e.) given its mean number of
    photoelectrons M (p.e., signal + dark): M where nothing was recorded, else
    -log[(1 - e^-M) p(Q | M, n >= 1)]."""
    hit_term = log1mexp(mean) + charge_logpdf(charge_sum, mean, spe_width)
    return -where(hit_any, hit_term, -mean)


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
    mirror: MirrorPaths | None = None


jax.tree_util.register_dataclass(
    _RunArrays,
    data_fields=[
        "source", "key", "n_events", "charge_sum", "hit_any", "hit", "charge", "time",
        "mirror",
    ],
    meta_fields=[],
)


#: Free fields that change only the first-hit time density, not the expected charge:
#: when nothing else is free, the charge terms of "charge+time" are constant.
TIME_FIELDS = frozenset({"time_offset", "tts"})

#: ``fold_in`` tag of a run's independent ray set (its derivatives J of the expected
#: charges, ``CalibrationProblem.independent_ray_curvature``).
JACOBIAN_RAY_STREAM = 0x4A4143

#: ``fold_in`` tag of a run's further ray sets: their expected charges estimate the ray
#: noise of the run's own (``CalibrationProblem.ray_noise_covariance``).
NOISE_RAY_STREAM = 0x4E4F49

#: ``fold_in`` tag of the further ray sets over which the expected charges M_a, their
#: derivatives J_a (``independent_ray_curvature(charge_sets=K)``) and the independent
#: derivatives J_b (``independent_jacobians``) are averaged: the root with K sets of
#: each has 1/K of the ray-noise bias of the root with one (``fit._independent_ray_steps``
#: extrapolates the two).
EXTRA_RAY_STREAM = 0x434852

#: Ray sets besides the run's own from which ``CalibrationProblem.ray_noise_covariance``
#: estimates the ray noise of the expected charges: the estimate has this many degrees
#: of freedom per run.
RAY_NOISE_SETS = 8

#: Events per block when a run's per-event terms are evaluated: bounds the memory of the
#: charge model's photoelectron sum (``N_TERMS`` values per sensor and event).
EVENT_BLOCK = 128


@dataclasses.dataclass(frozen=True)
class IndependentRayParts:
    """The independent-ray estimating equation at one point
    (``CalibrationProblem.independent_ray_curvature``).

    Attributes:
        loss: -log L at the point (with the run's own rays).
        grad_dense: (P,) the score J_b^T [dL/dM_a - bias] of the dense free entries.
        grad_sensor: (N, F) the score of the per-sensor free entries.
        bias_dense: (P,) the part J_b^T bias that was subtracted: the second-order
            (Jensen) bias of dL/dM at ray-sampled charges, 1/2 E[d^3(-log L)/dM^3]
            Var(M_a) (zero without ``RayNoiseSets``).
        bias_sensor: (N, F) the same for the per-sensor free entries.
        newton: the score's expected derivative I J_b J_a^T (not symmetric).
        information: the score's data covariance I J_b J_b^T (symmetric).
        projectors: per run, I J_b (N, T) in float64: a change dM of the run's expected
            charges changes the score by projector^T dM.
        jacobians: per run, J_b (N, T): the derivatives from the independent ray set
            (``CalibrationProblem.independent_ray_score`` reuses them).
    """

    loss: float
    grad_dense: np.ndarray
    grad_sensor: np.ndarray
    bias_dense: np.ndarray
    bias_sensor: np.ndarray
    newton: StructuredMatrix
    information: StructuredMatrix
    projectors: tuple
    jacobians: tuple

    def covariance(self) -> SandwichCovariance:
        """The root's covariance from the data's noise alone (no ray noise)."""
        return SandwichCovariance(self.newton, self.information)


@dataclasses.dataclass(frozen=True)
class RayNoiseSets:
    """The ray noise of every run's expected charges M_a, sampled
    (``CalibrationProblem.ray_noise_sets``).

    Attributes:
        charges: per run, (N,) p.e.: the mean expected charges over the K ray sets.
        deviations: per run, (K, N) p.e.: the expected charges of K independent ray sets
            (the run's own and K - 1 further ones) minus that mean.
    """

    charges: tuple
    deviations: tuple

    def relative_variances(self) -> list[np.ndarray]:
        """Per run, (N,) dimensionless: the sample variance (K - 1 degrees of freedom)
        of a sensor's expected charges over the ray sets over their mean squared. The
        relative variance of M_a is what carries over to other parameters: a sensor's
        efficiency scales its charge and its ray noise alike."""
        return [
            np.sum(d**2, axis=0) / (d.shape[0] - 1) / np.maximum(m, 1e-30) ** 2
            for m, d in zip(self.charges, self.deviations, strict=True)
        ]


@dataclasses.dataclass(frozen=True)
class _Static:
    """What a compiled run function depends on statically (hashable): the free layout,
    the likelihood, the detector's shape, the transport config, the run's readout
    window (ns), the single-p.e. width (p.e.) of the Fisher information and which terms
    of "charge+time" are evaluated ("all", "time" or "charge"). Problems that share it
    share compiled code."""

    layout: FreeLayout
    likelihood: str
    shape: object
    config: TransportConfig
    window: tuple[float, float]
    spe_width: float
    terms: str = "all"


def _params_of(theta: dict, base: Params) -> Params:
    return from_unconstrained(dataclasses.replace(base, **theta))


def _prediction(theta, base, sensors, data, cached, static: _Static) -> Prediction:
    params = _params_of(theta, base)
    if cached is None:
        cached = sensor_light(sensors, params, data.source, data.key, data.mirror,
                              shape=static.shape, config=static.config)
    return expected_response(cached, params)


def _mean(theta, base, sensors, data, cached, static: _Static):
    """(N,) expected photoelectrons of the run, summed over its events, p.e."""
    prediction = _prediction(theta, base, sensors, data, cached, static)
    dark = dark_expectation(_params_of(theta, base), static.window)
    return data.n_events * (prediction.charge + dark)


def _run_terms(theta, base, sensors, data, cached, static: _Static):
    """-log L terms of one run: (N,) per sensor (charge), or (E, N) per event and sensor
    (charge+time: all terms, or only the first-hit time or only the charge terms as
    ``static.terms`` says)."""
    if static.likelihood == "charge":
        return _charge_terms(theta, base, data, _mean(theta, base, sensors, data, cached, static))
    prediction = _prediction(theta, base, sensors, data, cached, static)
    mu_dark = dark_expectation(_params_of(theta, base), static.window)

    def event_terms(event):
        hit, charge, time = event
        if static.terms == "time":
            log_p = first_hit_logpdf(prediction, time, mu_dark, static.window)
            return -where(hit, log_p, 0.0)
        return dense_sensor_nll(
            prediction, hit, charge, time, prediction.dark_rate, prediction.spe_width,
            static.window, use_time=static.terms == "all",
        )

    return jax.lax.map(event_terms, (data.hit, data.charge, data.time), batch_size=EVENT_BLOCK)


def _run_nll(theta, base, sensors, data, cached, static: _Static):
    """(-log L of one run (float32), its terms (``_run_terms``))."""
    terms = _run_terms(theta, base, sensors, data, cached, static)
    return jnp.sum(terms), terms


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


def _blocks(layout: FreeLayout, information):
    """Per-sensor information matrices (N, T, T) over the tangents of ``_tangents`` ->
    the blocks A (P, P), C (N, F, P), B (N, F, F) of ``StructuredMatrix``: sensors'
    terms are independent, so A is the sum over sensors."""
    n_dense = layout.n_dense
    a = jnp.sum(information[:, :n_dense, :n_dense], axis=0)
    return a, information[:, n_dense:, :n_dense], information[:, n_dense:, n_dense:]


def _charge_jacobian(theta, base, sensors, data, cached, static: _Static):
    """(M (N,) p.e., J (N, T)): the run's expected charges and their forward-mode
    derivatives along the tangents of ``_tangents``."""
    layout = static.layout
    dense0, sensor0 = layout.split(theta)

    def mean_of(dense, sensor):
        return _mean(layout.join(dense, sensor), base, sensors, data, cached, static)

    tangent_dense, tangent_sensor = _tangents(layout, data.charge_sum.dtype)
    mean, jac = jax.vmap(
        lambda td, ts: jax.jvp(mean_of, (dense0, sensor0), (td, ts)), out_axes=(None, 0)
    )(tangent_dense, tangent_sensor)
    return mean, jac.T


def _charge_terms(theta, base, data, mean):
    """(N,) -log L terms of the summed-charge likelihood at expected charges M (p.e.)."""
    return summed_charge_nll(data.charge_sum, data.hit_any, mean,
                             _params_of(theta, base).spe_width)


def _charge_score(theta, base, data, mean):
    """(-log L terms (N,), dL/dM (N,)) of the summed-charge likelihood at charges M."""

    def total(m):
        terms = _charge_terms(theta, base, data, m)
        return jnp.sum(terms), terms

    (_, terms), score = jax.value_and_grad(total, has_aux=True)(mean)
    return terms, score


def ray_noise_score_bias(mean, variance, spe_width: float) -> jax.Array:
    """(N,) the second-order bias of a run's summed-charge score dL/dM (1/p.e.) when the
    expected charges are ray-sampled, M_a = M + e with zero-mean ray noise e of variance
    ``variance`` (p.e.^2): E[dL/dM(M + e)] - E[dL/dM(M)] = 1/2 E[d^3(-log L)/dM^3] Var(e)
    to second order (Jensen), the expectation over the data at ``mean`` (p.e.;
    ``expected_score_curvature``). ``spe_width`` in p.e., a Python float."""
    return 0.5 * expected_score_curvature(mean, spe_width) * variance


def _fisher_run(theta, base, data, mean, jac, static: _Static):
    """(terms (N,), gradient (P,), (N, F), Fisher parts A, C, B) of one run, charge
    likelihood, from its expected charges M (N,) p.e. and their derivatives J (N, T)
    (``_charge_jacobian``); I(M) from ``information``."""
    layout = static.layout
    terms, score = _charge_score(theta, base, data, mean)
    weight = charge_information(mean, static.spe_width)
    grad = jac * score[:, None]
    information = weight[:, None, None] * jac[:, :, None] * jac[:, None, :]
    a, c, b = _blocks(layout, information)
    return terms, jnp.sum(grad[:, : layout.n_dense], axis=0), grad[:, layout.n_dense:], a, c, b


def _independent_ray_score(theta, base, data, mean, jac_b, relative_variance,
                           static: _Static):
    """The independent-ray score of one run (charge likelihood) at expected charges M_a
    (N,) p.e., with derivatives J_b (N, T) from an independent ray set and
    ``relative_variance`` (N,) the variance of M_a's ray noise over M_a^2 (zeros: no
    bias correction). Returns (terms (N,); the score J_b^T [dL/dM_a - bias] as (P,) and
    (N, F), bias from ``ray_noise_score_bias``; the subtracted J_b^T bias as (P,) and
    (N, F))."""
    n_dense = static.layout.n_dense
    terms, score = _charge_score(theta, base, data, mean)
    variance = relative_variance * mean * mean
    bias = jac_b * ray_noise_score_bias(mean, variance, static.spe_width)[:, None]
    grad = jac_b * score[:, None] - bias
    return (terms, jnp.sum(grad[:, :n_dense], axis=0), grad[:, n_dense:],
            jnp.sum(bias[:, :n_dense], axis=0), bias[:, n_dense:])


def _independent_ray_run(theta, base, data, mean, jac_a, jac_b, relative_variance,
                         static: _Static):
    """The independent-ray parts of one run (charge likelihood) from its expected charges
    M_a (N,) p.e. and their derivatives J_a (N, T) (``_charge_jacobian`` with the run's
    own rays, or averaged over several ray sets) and the derivatives J_b (N, T) from an
    independent ray set. Returns (``_independent_ray_score``'s five parts; the score's
    expected derivative I J_b J_a^T as blocks A, C, B, C_upper (not symmetric: rows are
    the score's components, columns the free values); I J_b J_b^T as blocks A, C, B
    (the score's data covariance); and the projector I J_b (N, T): a change dM of the
    expected charges changes the score by projector^T dM)."""
    layout = static.layout
    n_dense = layout.n_dense
    score = _independent_ray_score(theta, base, data, mean, jac_b, relative_variance, static)
    fisher = charge_information(mean, static.spe_width)
    weight = fisher[:, None, None]
    derivative = weight * jac_b[:, :, None] * jac_a[:, None, :]
    c_upper = jnp.swapaxes(derivative[:, :n_dense, n_dense:], 1, 2)
    information = _blocks(layout, weight * jac_b[:, :, None] * jac_b[:, None, :])
    return (*score, *_blocks(layout, derivative), c_upper, *information,
            jac_b * fisher[:, None])


def _event_fisher_run(theta, base, sensors, data, cached, static: _Static):
    """(terms (E, N), gradient (P,), (N, F), Fisher parts A, C, B) of one run,
    charge+time likelihood. Per event and sensor the expected information is
    I(mu) J J^T (charge: J = d mu / d theta, mu = signal + dark p.e. of one event) plus
    P(hit) E[s s^T | hit] (first-hit time: s = d log p(t) / d theta at the quadrature
    nodes of ``information.time_nodes``); times E events. The gradient is the data's."""
    layout = static.layout
    dense0, sensor0 = layout.split(theta)
    dtype = data.charge_sum.dtype
    x, weights = time_nodes()
    prediction = _prediction(theta, base, sensors, data, cached, static)
    mu_dark = dark_expectation(_params_of(theta, base), static.window)
    nodes = first_hit_quantiles(prediction, mu_dark, static.window, x)  # (N, G) ns

    def at_nodes(dense, sensor):
        point = layout.join(dense, sensor)
        prediction = _prediction(point, base, sensors, data, cached, static)
        mu_dark = dark_expectation(_params_of(point, base), static.window)
        log_p = jax.vmap(
            lambda t: first_hit_logpdf(prediction, t, mu_dark, static.window),
            in_axes=1, out_axes=1,
        )(nodes)
        return prediction.charge + mu_dark, log_p

    tangent_dense, tangent_sensor = _tangents(layout, dtype)
    (mean, _), (jac, scores) = jax.vmap(
        lambda td, ts: jax.jvp(at_nodes, (dense0, sensor0), (td, ts)), out_axes=(None, 0)
    )(tangent_dense, tangent_sensor)
    jac = jac.T  # (N, T)
    charge_part = charge_information(mean, static.spe_width)[:, None, None] * (
        jac[:, :, None] * jac[:, None, :]
    )
    time_part = first_hit_scores_information(scores, jnp.asarray(weights, dtype))
    hit_probability = -jnp.expm1(-mean)[:, None, None]
    information = data.n_events * (charge_part + hit_probability * time_part)
    a, c, b = _blocks(layout, information)

    def nll_of(dense, sensor):
        return _run_nll(layout.join(dense, sensor), base, sensors, data, cached, static)

    (_, terms), (grad_dense, grad_sensor) = jax.value_and_grad(
        nll_of, argnums=(0, 1), has_aux=True
    )(dense0, sensor0)
    return terms, grad_dense, grad_sensor, a, c, b


def _first_hit_median(theta, base, sensors, data, cached, static: _Static):
    """(N,) predicted median of every sensor's first-hit time, ns."""
    prediction = _prediction(theta, base, sensors, data, cached, static)
    mu_dark = dark_expectation(_params_of(theta, base), static.window)
    zero = jnp.zeros(1, prediction.charge.dtype)
    return first_hit_quantiles(prediction, mu_dark, static.window, zero)[:, 0]


_terms_jit = jax.jit(_run_terms, static_argnames=("static",))
_value_and_grad_jit = jax.jit(
    jax.value_and_grad(_run_nll, has_aux=True), static_argnames=("static",)
)
_fisher_jit = jax.jit(_fisher_run, static_argnames=("static",))
_independent_ray_jit = jax.jit(_independent_ray_run, static_argnames=("static",))
_independent_ray_score_jit = jax.jit(_independent_ray_score, static_argnames=("static",))
_charge_jacobian_jit = jax.jit(_charge_jacobian, static_argnames=("static",))
_mean_jit = jax.jit(_mean, static_argnames=("static",))
_charge_terms_jit = jax.jit(_charge_terms)
_event_fisher_jit = jax.jit(_event_fisher_run, static_argnames=("static",))
_median_jit = jax.jit(_first_hit_median, static_argnames=("static",))


def _total(terms) -> float:
    """Sum of float32 terms in float64 (host)."""
    return float(np.sum(np.asarray(terms, dtype=np.float64)))


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
        information_table(spe_width)  # built here, outside jit (cached)
        score_curvature_table(spe_width)
        dtype = jnp.result_type(init_params.absorption_length)
        self.sensors = sensors_for(detector, dtype)
        per_event = likelihood == "charge+time"
        sources = [jax.tree.map(lambda x: jnp.asarray(x, dtype), run.source) for run in runs]
        self.arrays = [
            _RunArrays(
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
            _Static(
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
                _sensor_light_jit(self.sensors, params, data.source, data.key, data.mirror,
                                  shape=detector.shape, config=config)
                for data in self.arrays
            ]
        # -log L of the terms the free values do not change (the charges when only time
        # fields are free), evaluated once
        self.constant = 0.0
        if time_only:
            theta = self.initial_theta()
            self.constant = sum(
                _total(_terms_jit(theta, self.base, self.sensors, data, cached,
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
        return _params_of(theta, self.base)

    def _each(self, function, theta):
        for data, cached, static in zip(self.arrays, self.cached, self.statics, strict=True):
            yield function(theta, self.base, self.sensors, data, cached, static=static)

    def value(self, theta: dict) -> float:
        """-log L of all runs at ``theta`` (summed in float64). The charge likelihood
        goes through the expected charges (``_mean_jit``), the program that the ray-noise
        sets compile anyway: one compiled transport fewer."""
        if self.likelihood != "charge":
            return self.constant + sum(_total(t) for t in self._each(_terms_jit, theta))
        return self.constant + sum(
            _total(_charge_terms_jit(theta, self.base, data, mean))
            for data, mean in zip(self.arrays, self._each(_mean_jit, theta), strict=True)
        )

    def value_and_grad(self, theta: dict) -> tuple[float, dict]:
        """(-log L, its gradient as a ``theta``-shaped dict)."""
        total, gradient = self.constant, None
        for (_, terms), grad in self._each(_value_and_grad_jit, theta):
            total += _total(terms)
            gradient = grad if gradient is None else jax.tree.map(jnp.add, gradient, grad)
        return total, gradient

    def _summed(self, results) -> tuple[float, list[np.ndarray]]:
        """(-log L, the other parts summed over runs in float64) of per-run results
        (terms, *parts)."""
        value, sums = self.constant, None
        for terms, *run in results:
            value += _total(terms)
            run = [np.asarray(x, dtype=np.float64) for x in run]
            sums = run if sums is None else [s + x for s, x in zip(sums, run, strict=True)]
        return value, sums

    @property
    def has_independent_rays(self) -> bool:
        """True when ``independent_ray_curvature`` applies: the charge
        likelihood with a free field that changes the light transport, and indirect
        light (rays) in the expected mode."""
        return (self.likelihood == "charge" and self.layout.needs_transport
                and self.config.n_bounces > 0)

    def curvature(self, theta: dict) -> tuple[float, np.ndarray, np.ndarray, StructuredMatrix]:
        """(-log L, gradient dense (P,), gradient per sensor (N, F), curvature): the
        expected Fisher information of the likelihood (charge, or charge and first-hit
        time). Arrays in float64 numpy."""
        if self.likelihood == "charge":
            per_run = (
                _fisher_jit(theta, self.base, data, *jacobian, static=static)
                for data, static, jacobian in zip(
                    self.arrays, self.statics, self._each(_charge_jacobian_jit, theta),
                    strict=True)
            )
        else:
            per_run = self._each(_event_fisher_jit, theta)
        value, (grad_dense, grad_sensor, a, c, b) = self._summed(per_run)
        return value, grad_dense, grad_sensor, StructuredMatrix(a, c, b)

    def independent_ray_curvature(
        self, theta: dict, ray_noise: RayNoiseSets | None = None, charge_sets: int = 1,
        jacobians: tuple | None = None,
    ) -> IndependentRayParts:
        """The independent-ray estimating equation at ``theta`` (``has_independent_rays``
        only): every run's expected charges M_a come from its own rays and the
        derivatives J_b from a second, independent ray set; the score is
        J_b^T [dL/dM_a - bias], the Newton matrix its expected derivative I J_b J_a^T
        (not symmetric), the score's data covariance I J_b^T J_b. With ``ray_noise``
        (``ray_noise_sets``, taken at or near ``theta``) the bias is the second-order
        (Jensen) bias that the ray noise of M_a puts into dL/dM; without it, none. With
        ``charge_sets`` = K > 1, M_a and J_a are the averages over the run's own rays and
        K - 1 further sets (``ray_set_keys``), so their ray noise (and the bias
        correction) has 1/K of the variance. With ``jacobians`` (per run, J_b (N, T), e.g.
        ``independent_jacobians`` of a nearby point) those are the score's weights
        instead of a fresh set: any weights independent of the noise of M_a and of the
        data keep the score unbiased at the truth, and weights with less ray noise make
        the root more efficient. Float64 numpy. The root is free of the bias that the
        correlated ray noise of M and J puts into the minimum of -log L
        (docs/calibration.md, "Ray noise and the independent-ray score")."""
        per_run, used = [], []
        inputs = self._independent_ray_inputs(ray_noise, charge_sets)
        given = [None] * len(inputs) if jacobians is None else jacobians
        for (data, static, jacobian_key, variance, keys), jac_b in zip(
            inputs, given, strict=True
        ):
            sets = [self._jacobian(theta, data, static, key) for key in keys]
            mean = sum(m for m, _ in sets) / len(sets)
            jac_a = sum(j for _, j in sets) / len(sets)
            if jac_b is None:
                _, jac_b = self._jacobian(theta, data, static, jacobian_key)
            used.append(jac_b)
            per_run.append(_independent_ray_jit(theta, self.base, data, mean, jac_a, jac_b,
                                                variance, static=static))
        value, (grad_dense, grad_sensor, bias_dense, bias_sensor, *blocks) = self._summed(
            run[:-1] for run in per_run
        )
        return IndependentRayParts(
            value, grad_dense, grad_sensor, bias_dense, bias_sensor,
            StructuredMatrix(*blocks[:4]), StructuredMatrix(*blocks[4:]),
            tuple(np.asarray(run[-1], np.float64) for run in per_run), tuple(used),
        )

    def independent_ray_score(
        self, theta: dict, jacobians: tuple, ray_noise: RayNoiseSets | None = None,
        charge_sets: int = 1,
    ) -> tuple[float, np.ndarray, np.ndarray]:
        """(-log L, score dense (P,), per sensor (N, F)) of
        ``independent_ray_curvature`` at ``theta`` with the derivatives J_b given (per
        run, ``IndependentRayParts.jacobians`` of a nearby point): only the expected
        charges are computed, a third of the cost of their derivatives. For steps that
        reuse a nearby point's Newton matrix. Float64 numpy."""
        per_run = []
        for (data, static, _, variance, keys), jac_b in zip(
            self._independent_ray_inputs(ray_noise, charge_sets), jacobians, strict=True
        ):
            mean = sum(_mean_jit(theta, self.base, self.sensors,
                                 dataclasses.replace(data, key=key), None, static=static)
                       for key in keys) / len(keys)
            per_run.append(_independent_ray_score_jit(theta, self.base, data, mean, jac_b,
                                                      variance, static=static)[:3])
        value, (grad_dense, grad_sensor) = self._summed(per_run)
        return value, grad_dense, grad_sensor

    def _independent_ray_inputs(self, ray_noise: RayNoiseSets | None, charge_sets: int):
        """Per run (data, static, J_b's key, relative variance of M_a's ray noise over
        ``charge_sets`` sets, the keys of those sets)."""
        if not self.has_independent_rays:
            raise ConfigError(
                "independent rays: need the charge likelihood, a free field that changes"
                " the light transport and n_bounces > 0"
            )
        if int(charge_sets) < 1:
            raise ConfigError(f"charge_sets = {charge_sets}: must be >= 1")
        if ray_noise is None:
            variances = [jnp.zeros_like(data.charge_sum) for data in self.arrays]
        else:
            variances = [jnp.asarray(v / charge_sets, data.charge_sum.dtype) for v, data in zip(
                ray_noise.relative_variances(), self.arrays, strict=True)]
        return [
            (data, static, jacobian_key, variance, ray_set_keys(data.key, charge_sets))
            for data, static, jacobian_key, variance in zip(
                self.arrays, self.statics, self.jacobian_keys, variances, strict=True)
        ]

    def _jacobian(self, theta: dict, data, static: _Static, key):
        """(M (N,), J (N, T)) of a run with the rays of ``key`` (``_charge_jacobian``)."""
        return _charge_jacobian_jit(theta, self.base, self.sensors,
                                    dataclasses.replace(data, key=key), None, static=static)

    def independent_jacobians(self, theta: dict, n_sets: int) -> tuple:
        """Per run, the derivatives J_b (N, T) of the expected charges at ``theta``
        averaged over ``n_sets`` independent ray sets: the run's J_b set and
        ``n_sets`` - 1 further ones (``ray_set_keys``), for ``independent_ray_score``."""
        return tuple(
            sum(self._jacobian(theta, data, static, key)[1]
                for key in ray_set_keys(jacobian_key, n_sets)) / n_sets
            for data, static, jacobian_key in zip(
                self.arrays, self.statics, self.jacobian_keys, strict=True)
        )

    def ray_noise_sets(self, theta: dict, n_sets: int = RAY_NOISE_SETS) -> RayNoiseSets:
        """Every run's expected charges at ``theta`` from its own rays and ``n_sets``
        further independent ray sets (keys ``fold_in(fold_in(run key,
        NOISE_RAY_STREAM), k)``), as deviations from their mean: a sample of the ray
        noise of M_a with ``n_sets`` degrees of freedom per run."""
        means, deviations = [], []
        for data, cached, static, key in zip(
            self.arrays, self.cached, self.statics, self.noise_keys, strict=True
        ):
            keys = [data.key] + [jax.random.fold_in(key, k) for k in range(n_sets)]
            charges = np.stack([
                np.asarray(_mean_jit(theta, self.base, self.sensors,
                                     dataclasses.replace(data, key=k), cached, static=static),
                           np.float64)
                for k in keys
            ])
            means.append(charges.mean(axis=0))
            deviations.append(charges - means[-1])
        return RayNoiseSets(tuple(means), tuple(deviations))

    def ray_noise_covariance(
        self, parts: IndependentRayParts, ray_noise: RayNoiseSets
    ) -> SandwichCovariance:
        """The covariance of the independent-ray root: the sandwich of the score's data
        covariance (``parts.information``) and of its ray-noise covariance, which the
        rays of M_a add: per run the sample covariance of projector^T M over the ray sets
        of ``ray_noise`` (independent of J_b, so their spread is pure ray noise). Both
        at (or within a small step of) the root."""
        n_dense = self.layout.n_dense
        noise_dense, noise_sensor = [], []
        for projector, deviations in zip(parts.projectors, ray_noise.deviations, strict=True):
            # sum of u u^T over the K sets = sample covariance (K - 1 degrees of freedom)
            scaled = deviations / np.sqrt(deviations.shape[0] - 1)
            noise_dense.append(scaled @ projector[:, :n_dense])
            noise_sensor.append(scaled[:, :, None] * projector[None, :, n_dense:])
        return SandwichCovariance(parts.newton, parts.information,
                                  np.concatenate(noise_dense), np.concatenate(noise_sensor))

    def check_predictions(self, theta: dict) -> None:
        """Raise a one-line ``ConfigError`` naming the first run whose expected charge at
        ``theta`` is not finite (a run the expected mode cannot predict cannot be
        fitted)."""
        for index, (run, mean) in enumerate(zip(self.runs, self._each(_mean_jit, theta),
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
        for run, median in zip(self.runs, self._each(_median_jit, theta), strict=True):
            median = np.asarray(median, np.float64)
            residuals.append(np.where(run.hit, run.time - median[None, :], np.nan))
        residuals = np.concatenate(residuals, axis=0)
        hit = np.any(np.isfinite(residuals), axis=0)
        shift = np.zeros(residuals.shape[1])
        shift[hit] = np.nanmedian(residuals[:, hit], axis=0)
        return shift


def ray_set_keys(key, n_sets: int) -> list:
    """``key`` and ``n_sets`` - 1 further independent keys derived from it
    (``fold_in(fold_in(key, EXTRA_RAY_STREAM), k)``): the ray sets whose expected charges
    or derivatives are averaged."""
    stream = jax.random.fold_in(key, EXTRA_RAY_STREAM)
    return [key] + [jax.random.fold_in(stream, k) for k in range(int(n_sets) - 1)]


@functools.partial(jax.jit, static_argnames=("shape", "config"))
def _sensor_light_jit(sensors, params, source, key, mirror, *, shape, config) -> SensorLight:
    return sensor_light(sensors, params, source, key, mirror, shape=shape, config=config)


@functools.partial(jax.jit, static_argnames=("shape",))
def _mirror_paths_jit(sensors, source, *, shape) -> MirrorPaths:
    return mirror_paths(shape, sensors, source)


def run_mirror_paths(sensors, source, shape, config: TransportConfig) -> MirrorPaths | None:
    """A run's first-order mirror paths (``transport.mirror.mirror_paths``), or None where
    the expected mode has none (an open medium, or no bounces). The source of a run stays
    put and the paths do not depend on ``Params``, so they are computed once per run
    rather than in every evaluation of the expected mode (~0.1 s each on SK)."""
    if not (shape.has_walls and config.n_bounces > 0):
        return None
    return _mirror_paths_jit(sensors, source, shape=shape)
