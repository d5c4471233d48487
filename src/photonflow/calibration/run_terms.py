"""The calibration's per-run likelihood terms, jitted: expected charges and times of a run
(the transport's ``SensorLight``, cached when only response fields are free, followed
by the sensor response), -log L per sensor (and event), its gradient, the charges'
forward-mode derivatives and the expected Fisher information. ``objective.py`` sums
them over runs (``CalibrationProblem``). Charges in p.e., times in ns.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..likelihood import (
    charge_logpdf,
    dark_expectation,
    dense_sensor_nll,
    first_hit_logpdf,
    log1mexp,
)
from ..numerics import where
from ..params import Params, from_unconstrained
from ..prediction import Prediction
from ..response.expected import SensorLight, expected_response
from ..transport.expected import sensor_light
from ..transport.mirror import MirrorPaths, mirror_paths
from ..transport.optics import TransportConfig
from .information import (
    charge_information,
    first_hit_quantiles,
    first_hit_scores_information,
    time_nodes,
)
from .layout import FreeLayout


def summed_charge_nll(charge_sum, hit_any, mean, spe_width) -> jax.Array:
    """Per-sensor -log P of a run's summed charge (p.e.) given its mean number of
    photoelectrons M (p.e., signal + dark): M where nothing was recorded, else
    -log[(1 - e^-M) p(Q | M, n >= 1)]."""
    hit_term = log1mexp(mean) + charge_logpdf(charge_sum, mean, spe_width)
    return -where(hit_any, hit_term, -mean)


@dataclasses.dataclass(frozen=True)
class RunArrays:
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
    RunArrays,
    data_fields=[
        "source", "key", "n_events", "charge_sum", "hit_any", "hit", "charge", "time",
        "mirror",
    ],
    meta_fields=[],
)


#: Free fields that change only the first-hit time density, not the expected charge:
#: when nothing else is free, the charge terms of "charge+time" are constant.
TIME_FIELDS = frozenset({"time_offset", "tts"})


#: Events per block when a run's per-event terms are evaluated: bounds the memory of the
#: charge model's photoelectron sum (``N_TERMS`` values per sensor and event).
EVENT_BLOCK = 128


@dataclasses.dataclass(frozen=True)
class RunStatic:
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


def physical_params(theta: dict, base: Params) -> Params:
    """The physical ``Params`` of free values ``theta`` (unconstrained) over ``base``."""
    return from_unconstrained(dataclasses.replace(base, **theta))


def run_prediction(theta, base, sensors, data, cached, static: RunStatic) -> Prediction:
    """The run's ``Prediction`` at ``theta``: the cached ``SensorLight`` (or the transport
    run now) followed by the sensor response."""
    params = physical_params(theta, base)
    if cached is None:
        cached = sensor_light(sensors, params, data.source, data.key, data.mirror,
                              shape=static.shape, config=static.config)
    return expected_response(cached, params)


def run_mean(theta, base, sensors, data, cached, static: RunStatic):
    """(N,) expected photoelectrons of the run, summed over its events, p.e."""
    prediction = run_prediction(theta, base, sensors, data, cached, static)
    dark = dark_expectation(physical_params(theta, base), static.window)
    return data.n_events * (prediction.charge + dark)


def run_terms(theta, base, sensors, data, cached, static: RunStatic):
    """-log L terms of one run: (N,) per sensor (charge), or (E, N) per event and sensor
    (charge+time: all terms, or only the first-hit time or only the charge terms as
    ``static.terms`` says)."""
    if static.likelihood == "charge":
        return charge_terms(theta, base, data, run_mean(theta, base, sensors, data, cached, static))
    prediction = run_prediction(theta, base, sensors, data, cached, static)
    mu_dark = dark_expectation(physical_params(theta, base), static.window)

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


def run_nll(theta, base, sensors, data, cached, static: RunStatic):
    """(-log L of one run (float32), its terms (``run_terms``))."""
    terms = run_terms(theta, base, sensors, data, cached, static)
    return jnp.sum(terms), terms


def tangents(layout: FreeLayout, dtype):
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


def information_blocks(layout: FreeLayout, information):
    """Per-sensor information matrices (N, T, T) over the tangents of ``tangents`` ->
    the blocks A (P, P), C (N, F, P), B (N, F, F) of ``StructuredMatrix``: sensors'
    terms are independent, so A is the sum over sensors."""
    n_dense = layout.n_dense
    a = jnp.sum(information[:, :n_dense, :n_dense], axis=0)
    return a, information[:, n_dense:, :n_dense], information[:, n_dense:, n_dense:]


def charge_jacobian(theta, base, sensors, data, cached, static: RunStatic):
    """(M (N,) p.e., J (N, T)): the run's expected charges and their forward-mode
    derivatives along the tangents of ``tangents``."""
    layout = static.layout
    dense0, sensor0 = layout.split(theta)

    def mean_of(dense, sensor):
        return run_mean(layout.join(dense, sensor), base, sensors, data, cached, static)

    tangent_dense, tangent_sensor = tangents(layout, data.charge_sum.dtype)
    mean, jac = jax.vmap(
        lambda td, ts: jax.jvp(mean_of, (dense0, sensor0), (td, ts)), out_axes=(None, 0)
    )(tangent_dense, tangent_sensor)
    return mean, jac.T


def charge_terms(theta, base, data, mean):
    """(N,) -log L terms of the summed-charge likelihood at expected charges M (p.e.)."""
    return summed_charge_nll(data.charge_sum, data.hit_any, mean,
                             physical_params(theta, base).spe_width)


def charge_score(theta, base, data, mean):
    """(-log L terms (N,), dL/dM (N,)) of the summed-charge likelihood at charges M."""

    def total(m):
        terms = charge_terms(theta, base, data, m)
        return jnp.sum(terms), terms

    (_, terms), score = jax.value_and_grad(total, has_aux=True)(mean)
    return terms, score


def fisher_run(theta, base, data, mean, jac, static: RunStatic):
    """(terms (N,), gradient (P,), (N, F), Fisher parts A, C, B) of one run, charge
    likelihood, from its expected charges M (N,) p.e. and their derivatives J (N, T)
    (``charge_jacobian``); I(M) from ``information``."""
    layout = static.layout
    terms, score = charge_score(theta, base, data, mean)
    weight = charge_information(mean, static.spe_width)
    grad = jac * score[:, None]
    information = weight[:, None, None] * jac[:, :, None] * jac[:, None, :]
    a, c, b = information_blocks(layout, information)
    return terms, jnp.sum(grad[:, : layout.n_dense], axis=0), grad[:, layout.n_dense:], a, c, b


def event_fisher_run(theta, base, sensors, data, cached, static: RunStatic):
    """(terms (E, N), gradient (P,), (N, F), Fisher parts A, C, B) of one run,
    charge+time likelihood. Per event and sensor the expected information is
    I(mu) J J^T (charge: J = d mu / d theta, mu = signal + dark p.e. of one event) plus
    P(hit) E[s s^T | hit] (first-hit time: s = d log p(t) / d theta at the quadrature
    nodes of ``information.time_nodes``); times E events. The gradient is the data's."""
    layout = static.layout
    dense0, sensor0 = layout.split(theta)
    dtype = data.charge_sum.dtype
    x, weights = time_nodes()
    prediction = run_prediction(theta, base, sensors, data, cached, static)
    mu_dark = dark_expectation(physical_params(theta, base), static.window)
    nodes = first_hit_quantiles(prediction, mu_dark, static.window, x)  # (N, G) ns

    def at_nodes(dense, sensor):
        point = layout.join(dense, sensor)
        prediction = run_prediction(point, base, sensors, data, cached, static)
        mu_dark = dark_expectation(physical_params(point, base), static.window)
        log_p = jax.vmap(
            lambda t: first_hit_logpdf(prediction, t, mu_dark, static.window),
            in_axes=1, out_axes=1,
        )(nodes)
        return prediction.charge + mu_dark, log_p

    tangent_dense, tangent_sensor = tangents(layout, dtype)
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
    a, c, b = information_blocks(layout, information)

    def nll_of(dense, sensor):
        return run_nll(layout.join(dense, sensor), base, sensors, data, cached, static)

    (_, terms), (grad_dense, grad_sensor) = jax.value_and_grad(
        nll_of, argnums=(0, 1), has_aux=True
    )(dense0, sensor0)
    return terms, grad_dense, grad_sensor, a, c, b


def first_hit_median(theta, base, sensors, data, cached, static: RunStatic):
    """(N,) predicted median of every sensor's first-hit time, ns."""
    prediction = run_prediction(theta, base, sensors, data, cached, static)
    mu_dark = dark_expectation(physical_params(theta, base), static.window)
    zero = jnp.zeros(1, prediction.charge.dtype)
    return first_hit_quantiles(prediction, mu_dark, static.window, zero)[:, 0]


terms_jit = jax.jit(run_terms, static_argnames=("static",))


value_and_grad_jit = jax.jit(
    jax.value_and_grad(run_nll, has_aux=True), static_argnames=("static",)
)


fisher_jit = jax.jit(fisher_run, static_argnames=("static",))


charge_jacobian_jit = jax.jit(charge_jacobian, static_argnames=("static",))


mean_jit = jax.jit(run_mean, static_argnames=("static",))


charge_terms_jit = jax.jit(charge_terms)


event_fisher_jit = jax.jit(event_fisher_run, static_argnames=("static",))


median_jit = jax.jit(first_hit_median, static_argnames=("static",))


def total_in_float64(terms) -> float:
    """Sum of float32 terms in float64 (host)."""
    return float(np.sum(np.asarray(terms, dtype=np.float64)))


@functools.partial(jax.jit, static_argnames=("shape", "config"))
def sensor_light_jit(sensors, params, source, key, mirror, *, shape, config) -> SensorLight:
    """``transport.expected.sensor_light``, jitted (a run's light, cached by the problem)."""
    return sensor_light(sensors, params, source, key, mirror, shape=shape, config=config)


@functools.partial(jax.jit, static_argnames=("shape",))
def mirror_paths_jit(sensors, source, *, shape) -> MirrorPaths:
    """``transport.mirror.mirror_paths``, jitted."""
    return mirror_paths(shape, sensors, source)


def run_mirror_paths(sensors, source, shape, config: TransportConfig) -> MirrorPaths | None:
    """A run's first-order mirror paths (``transport.mirror.mirror_paths``), or None where
    the expected mode has none (an open medium, or no bounces). The source of a run stays
    put and the paths do not depend on ``Params``, so they are computed once per run
    rather than in every evaluation of the expected mode (~0.1 s each on SK)."""
    if not (shape.has_walls and config.n_bounces > 0):
        return None
    return mirror_paths_jit(sensors, source, shape=shape)
