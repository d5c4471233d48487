"""Per-sensor Poisson likelihood of an event given a ``Prediction``.

Model for sensor j (all exact, no soft-min):

* light: a Poisson process in time with intensity
  ``lambda(t) = mu_s f(t) + mu_d / T`` on the readout window ``[t0, t1]`` (``T = t1 - t0``),
  where ``mu_s`` is the predicted signal p.e., ``f`` the predicted arrival-time density
  and ``mu_d = dark_rate * T * 1e-9`` the dark-noise p.e. (uniform in the window; a tiny
  floor ``DARK_FLOOR`` p.e. is added so that everything stays finite with
  ``dark_rate = 0``). The total mean is ``mu = mu_s + mu_d``;
* unhit sensor: ``P = exp(-mu)``;
* hit sensor with charge q and first-hit time t:
  ``P = (1 - exp(-mu)) P(q | n >= 1) p_first(t)`` with
  ``P(q | n >= 1) = sum_{n>=1} Poisson(n; mu) Normal(q; n, sqrt(n) spe_width) / (1 - e^-mu)``
  and ``p_first(t) = lambda(t) exp(-Lambda(t)) / (1 - exp(-mu))``,
  ``Lambda(t) = mu_s F(t) + mu_d clip((t - t0) / T, 0, 1)``;
* optional discriminator threshold ``q_thr``: hits with ``q < q_thr`` are not recorded,
  so an unhit sensor has ``P = exp(-mu) + (1 - exp(-mu)) P(q < q_thr | n >= 1)``.

The charge sum runs over a window of ``n_terms`` consecutive n centred on mu (exact to
~1e-9 for mu up to ``mu_switch + blend``); above ``mu_switch`` it is blended linearly (a
mixture of densities, so normalisation is kept) into the Gaussian approximation
``Normal(q; mu, sqrt(mu (1 + spe_width^2)))`` over ``mu_switch +- blend``.

Overdispersion (optional, ``overdispersion = r > 0``): the sensor's whole intensity is
scaled, event by event, by a factor g ~ Gamma(mean 1, variance r) (the light of a
particle track fluctuates coherently from event to event: the ring moves with the
particle's multiple scattering, knock-on electrons make their own small rings). The
count is then negative-binomial, variance ``mu + r mu^2``, and the arrival process a
Polya process:

* unhit: ``P = (1 + r mu)^(-1/r)``;
* count weights ``NB(n; mu, r)`` in the charge sum (over n = 1 .. n_terms), blended above
  ``OVERDISPERSED_SWITCH`` into a Gamma density of the charge's mean and variance;
* first hit: ``p_first(t) = lambda(t) (1 + r Lambda(t))^(-1/r - 1) / P(hit)``.

r = 0 is the Poisson model above, computed by the same code as without the option.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .charge_model import (  # noqa: F401  (re-exported: the likelihood's charge model)
    MAX_OVERDISPERSION,
    MU_BLEND,
    MU_SWITCH,
    N_TERMS,
    OVERDISPERSED_BLEND,
    OVERDISPERSED_SWITCH,
    charge_logcdf,
    charge_logpdf,
    check_overdispersion,
    log1mexp,
    log_no_photoelectron,
)
from .errors import ConfigError
from .inline_jit import inline_jit
from .io.events import Event
from .numerics import clip, strict_array, where
from .params import Params
from .prediction import Prediction

#: Floor on the dark-noise expectation per sensor and window, p.e.
DARK_FLOOR = 1e-9
def _log_intensity_and_integral(
    prediction: Prediction, t: jax.Array, mu_dark: jax.Array, window: tuple[float, float]
) -> tuple[jax.Array, jax.Array]:
    """log lambda(t) (log 1/ns) and Lambda(t) (p.e.) of signal plus dark noise."""
    t0, t1 = window
    length = t1 - t0
    mu_s = prediction.charge
    dtype = mu_s.dtype
    tiny = jnp.finfo(dtype).tiny
    t = jnp.asarray(t, dtype=dtype)
    inside = (t >= t0) & (t <= t1)
    log_f = prediction.time_logpdf(t)
    log_dark = where(inside, jnp.log(mu_dark / length), -jnp.inf)
    # Shifted sum mu_s e^{log_f} + e^{log_dark}, exact gradients also at mu_s = 0.
    shift = jnp.maximum(log_f + jnp.log(jnp.maximum(mu_s, tiny)), log_dark)
    shift = jax.lax.stop_gradient(shift)
    total = mu_s * jnp.exp(log_f - shift) + jnp.exp(log_dark - shift)
    log_lambda = shift + jnp.log(jnp.maximum(total, tiny))
    fraction = clip((t - t0) / length, 0.0, 1.0)
    big_lambda = mu_s * prediction.time_cdf(t) + mu_dark * fraction
    return log_lambda, big_lambda


def dark_expectation(params: Params, window: tuple[float, float]) -> jax.Array:
    """Dark-noise p.e. per sensor in the readout window, ``dark_rate * T * 1e-9 + DARK_FLOOR``.

    Args:
        params: detector parameters (``dark_rate`` in Hz).
        window: readout window (t0, t1), ns.
    """
    return _dark_mean(params.dark_rate, window)


def _dark_mean(dark_rate, window: tuple[float, float]):
    t0, t1 = window
    return dark_rate * ((t1 - t0) * 1e-9) + DARK_FLOOR


def first_hit_logpdf(
    prediction: Prediction, t: jax.Array, mu_dark: jax.Array, window: tuple[float, float],
    overdispersion: float = 0.0,
) -> jax.Array:
    """Log density of the first-hit time given at least one hit, log(1/ns).

    ``p_first(t) = lambda(t) exp(-Lambda(t)) / (1 - exp(-mu))`` with
    ``lambda(t) = mu_s f(t) + mu_d / T`` inside the window (``mu_s f(t)`` outside),
    ``Lambda(t) = mu_s F(t) + mu_d clip((t - t0) / T, 0, 1)`` and ``mu = mu_s + mu_d``;
    with ``overdispersion`` r > 0 (static), the Polya process's
    ``lambda(t) (1 + r Lambda(t))^(-1/r - 1) / (1 - (1 + r mu)^(-1/r))``.

    Args:
        prediction: signal prediction (``charge`` mu_s in p.e., time mixture in ns).
        t: (N,) first-hit time per sensor, ns.
        mu_dark: dark-noise p.e. per sensor in the window (> 0; scalar or (N,)).
        window: readout window (t0, t1), ns.
        overdispersion: r, dimensionless (module docstring); 0: Poisson.
    """
    log_lambda, big_lambda = _log_intensity_and_integral(prediction, t, mu_dark, window)
    log_hit = log1mexp(-log_no_photoelectron(prediction.charge + mu_dark, overdispersion))
    if overdispersion == 0:
        return log_lambda - big_lambda - log_hit
    r = overdispersion
    return log_lambda - (1.0 / r + 1.0) * jnp.log1p(r * big_lambda) - log_hit


def hit_arrays(event: Event, n: int, dtype) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Scatter sparse hits to (N,) arrays: hit mask, summed charge (p.e.) and earliest
    time (ns; 0 where not hit). A concrete event is scattered with numpy (no
    compilation per hit count); traced hits with JAX."""
    fields = (event.sensor_ids, event.charge, event.time)
    if not any(isinstance(x, jax.core.Tracer) for x in fields):
        ids = np.asarray(event.sensor_ids, dtype=np.int64)
        hit = np.zeros(n, dtype=bool)
        hit[ids] = True
        q = np.zeros(n)
        np.add.at(q, ids, np.asarray(event.charge, dtype=np.float64))
        t = np.full(n, np.inf)
        np.minimum.at(t, ids, np.asarray(event.time, dtype=np.float64))
        return (jax.device_put(hit), strict_array(q, dtype),
                strict_array(np.where(hit, t, 0.0), dtype))
    ids = jnp.asarray(event.sensor_ids, dtype=jnp.int32)
    charge = jnp.asarray(event.charge).astype(dtype)
    time = jnp.asarray(event.time).astype(dtype)
    hit = jnp.zeros(n, dtype=bool).at[ids].set(True)
    q = jnp.zeros(n, dtype=dtype).at[ids].add(charge)
    t = jnp.full(n, jnp.inf, dtype=dtype).at[ids].min(time)
    return hit, q, where(hit, t, 0.0)


def _response(prediction: Prediction, params: Params | None, window):
    """(dark_rate Hz, spe_width p.e., window ns) from ``params``/``window`` if given,
    else from the prediction; a one-line ``ConfigError`` if neither has them."""
    source = params if params is not None else prediction
    dark_rate, spe_width = source.dark_rate, source.spe_width
    window = prediction.window if window is None else window
    if dark_rate is None or spe_width is None or window is None:
        missing = "window" if window is None else "params"
        raise ConfigError(
            f"nll: no {missing}; pass params= and window= or a Prediction from expected()"
        )
    return dark_rate, spe_width, tuple(window)


def sensor_nll(
    prediction: Prediction,
    event: Event,
    params: Params | None = None,
    *,
    window: tuple[float, float] | None = None,
    charge_threshold: float | None = None,
    use_time: bool = True,
    overdispersion: float = 0.0,
) -> jax.Array:
    """Per-sensor negative log-likelihood terms of an event (see the module docstring).

    Args:
        prediction: expected signal p.e. per sensor and arrival-time mixture (ns).
        event: recorded hits; several hits on one sensor are merged (charges summed,
            earliest time kept). Sensor ids must lie in [0, N).
        params: detector parameters (``dark_rate`` Hz and ``spe_width`` p.e. are used);
            default: the ones stored in the prediction by ``expected``.
        window: readout window (t0, t1), ns (static Python floats); default: the
            prediction's.
        charge_threshold: discriminator threshold, p.e. (None: every hit is recorded).
            Hits below it are taken as not recorded, which the unhit term accounts for.
        use_time: include the first-hit time density (False: charge only).
        overdispersion: r in [0, ``MAX_OVERDISPERSION``] (static, dimensionless): each
            sensor's count has variance mu + r mu^2 (module docstring); 0: Poisson.

    Returns:
        (N,) ``-log P`` per sensor (dimensionless for unhit sensors; densities in
        1/p.e. and, with ``use_time``, 1/ns for hit sensors). Differentiable in every
        field of ``prediction`` and ``params``; works under ``jit``.
    """
    return dense_sensor_nll(
        *_dense_arguments(prediction, event, params, window),
        charge_threshold=charge_threshold, use_time=use_time,
        overdispersion=check_overdispersion(overdispersion),
    )


def _dense_arguments(prediction: Prediction, event: Event, params, window) -> tuple:
    """The positional arguments of ``dense_sensor_nll`` for ``sensor_nll``'s inputs."""
    n = prediction.charge.shape[0]
    hit, q, t = hit_arrays(event, n, prediction.charge.dtype)
    dark_rate, spe_width, window = _response(prediction, params, window)
    return prediction, hit, q, t, dark_rate, spe_width, window


@inline_jit(static_argnames=("window", "charge_threshold", "use_time", "overdispersion"))
def dense_sensor_nll(
    prediction: Prediction,
    hit: jax.Array,
    q: jax.Array,
    t: jax.Array,
    dark_rate: jax.Array,
    spe_width: jax.Array,
    window: tuple[float, float],
    *,
    charge_threshold: float | None = None,
    use_time: bool = True,
    time_weight: jax.Array | None = None,
    overdispersion: float = 0.0,
) -> jax.Array:
    """``sensor_nll`` on dense per-sensor arrays (one event; vmap it over events).

    Args:
        prediction: expected signal p.e. per sensor and arrival-time mixture (ns).
        hit: (N,) bool, sensor recorded a hit; q: (N,) its summed charge, p.e.; t: (N,)
            its first-hit time, ns (any finite value where not hit).
        dark_rate: dark-noise rate per sensor, Hz; spe_width: single-p.e. width, p.e.
        window: readout window (t0, t1), ns (static).
        charge_threshold, use_time: as in ``sensor_nll``.
        time_weight: None, or a factor (dimensionless, not static) on the first-hit time
            term: one compiled program serves a charge-only (0) and a full (1)
            likelihood.
        overdispersion: r (static, dimensionless), as in ``sensor_nll``.

    Returns:
        (N,) ``-log P`` per sensor.
    """
    mu_s = prediction.charge
    n = mu_s.shape[0]
    dtype = mu_s.dtype
    mu_dark = jnp.asarray(_dark_mean(dark_rate, window), dtype=dtype)
    mu = mu_s + mu_dark
    width = jnp.asarray(spe_width, dtype=dtype)
    q = jnp.asarray(q, dtype=dtype)

    r = overdispersion
    log_none = log_no_photoelectron(mu, r)
    log_some = log1mexp(-log_none)  # log P(n >= 1)
    log_hit = log_some + charge_logpdf(q, mu, width, overdispersion=r)
    if use_time:
        time_term = first_hit_logpdf(prediction, t, mu_dark, window, r)
        if time_weight is not None:
            time_term = jnp.asarray(time_weight, dtype=dtype) * time_term
        log_hit = log_hit + time_term
    if charge_threshold is None:
        log_unhit = log_none
    else:
        below = charge_logcdf(jnp.full(n, charge_threshold, dtype=dtype), mu, width,
                              overdispersion=r)
        log_unhit = jnp.logaddexp(log_none, log_some + below)
    return -where(hit, log_hit, log_unhit)


def nll(
    prediction: Prediction,
    event: Event,
    params: Params | None = None,
    *,
    window: tuple[float, float] | None = None,
    charge_threshold: float | None = None,
    use_time: bool = True,
    overdispersion: float = 0.0,
) -> jax.Array:
    """Total negative log-likelihood of an event: the sum of ``sensor_nll`` (scalar).

    Arguments as in ``sensor_nll`` (window in ns, threshold in p.e., overdispersion
    dimensionless).
    """
    return dense_nll(
        *_dense_arguments(prediction, event, params, window),
        charge_threshold=charge_threshold, use_time=use_time,
        overdispersion=check_overdispersion(overdispersion),
    )


def _summed_sensor_nll(*arguments, **options) -> jax.Array:
    """``dense_sensor_nll`` summed over sensors (scalar)."""
    return jnp.sum(dense_sensor_nll(*arguments, **options))


#: ``dense_sensor_nll`` summed over sensors (scalar) in one jitted program, with no eager
#: reduction after it; arguments and units as for ``dense_sensor_nll`` (the window, the
#: seventh, static).
dense_nll = inline_jit(
    _summed_sensor_nll, static_argnums=(6,),
    static_argnames=("charge_threshold", "use_time", "overdispersion"),
)
