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
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaln, log_ndtr, ndtr

from .errors import ConfigError
from .io.events import Event
from .numerics import clip, strict_array, where
from .params import Params
from .prediction import Prediction
from .response.spe import single_pe_moments

#: Floor on the dark-noise expectation per sensor and window, p.e.
DARK_FLOOR = 1e-9
#: Number of consecutive photoelectron counts n summed in the exact charge model.
N_TERMS = 128
#: Centre of the blend from the exact Poisson sum to the Gaussian charge model, p.e.
MU_SWITCH = 80.0
#: Half-width of that blend, p.e.
MU_BLEND = 20.0

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
_LOG2 = math.log(2.0)


def log1mexp(mu: jax.Array) -> jax.Array:
    """``log(1 - exp(-mu))`` for mu > 0, computed stably (-inf at mu = 0)."""
    small = mu < _LOG2
    safe_small = where(small, mu, _LOG2)
    safe_large = where(small, 1.0, mu)
    return where(small, jnp.log(-jnp.expm1(-safe_small)), jnp.log1p(-jnp.exp(-safe_large)))


def _charge_mixture(
    q: jax.Array,
    mu: jax.Array,
    spe_width: jax.Array,
    one_photoelectron: Callable[[jax.Array, jax.Array], jax.Array],
    normal: Callable[[jax.Array, jax.Array, jax.Array], jax.Array],
    n_terms: int,
    mu_switch: float,
    blend: float,
) -> jax.Array:
    """Log of E[kernel(q | n) | n >= 1] for n ~ Poisson(mu), blended into a Gaussian.

    The kernel of one photoelectron is ``one_photoelectron(q, w)`` (the exact truncated
    normal of ``photonflow.response.spe``); for n >= 2 and in the Gaussian branch it is
    ``normal(q, mean, sd)`` with the n-fold mean and variance. Both return log values
    (densities for ``charge_logpdf``, cumulatives for ``charge_logcdf``).
    """
    q, mu = jnp.broadcast_arrays(jnp.asarray(q), jnp.asarray(mu))
    spe_width = jnp.broadcast_to(jnp.asarray(spe_width, dtype=mu.dtype), mu.shape)
    q = q.astype(mu.dtype)

    def poisson_kernel(n, mean_n, sigma_n):
        one = one_photoelectron(q[..., None], spe_width[..., None])
        return where(n == 1, one, normal(q[..., None], mean_n, sigma_n))

    def gauss_kernel(mean, sd):
        return normal(q, mean, sd)

    tiny = jnp.finfo(mu.dtype).tiny
    lo, hi = mu_switch - blend, mu_switch + blend
    s = clip((mu - lo) / (hi - lo), 0.0, 1.0)
    s = s * s * (3.0 - 2.0 * s)  # smoothstep: C1 blend
    poisson_only = mu <= lo
    gauss_only = mu >= hi

    # n photoelectrons give a charge of mean n m1 and variance n v1 (``spe``).
    mean_one, var_one = single_pe_moments(spe_width)

    # Exact Poisson sum over n_lo .. n_lo + n_terms - 1 (double-where: safe mu).
    mu_p = where(gauss_only, mu_switch, jnp.maximum(mu, tiny))
    n_lo = jnp.maximum(1.0, jnp.floor(mu_p) - (n_terms // 2 - 1))
    n = n_lo[..., None] + jnp.arange(n_terms, dtype=mu.dtype)
    sigma_n = jnp.sqrt(n * var_one[..., None])
    log_weight = (n - 1.0) * jnp.log(mu_p)[..., None] - gammaln(n + 1.0)
    log_norm = jnp.log(mu_p) - mu_p - log1mexp(mu_p)  # log(mu e^-mu / (1 - e^-mu))
    log_poisson = (
        jax.nn.logsumexp(log_weight + poisson_kernel(n, n * mean_one[..., None], sigma_n), axis=-1)
        + log_norm
    )

    # Gaussian approximation (double-where: safe mu).
    mu_g = where(poisson_only, mu_switch, mu)
    log_gauss = gauss_kernel(mu_g * mean_one, jnp.sqrt(mu_g * (var_one + mean_one * mean_one)))

    s_mid = where(poisson_only | gauss_only, 0.5, s)
    mixed = jnp.logaddexp(jnp.log1p(-s_mid) + log_poisson, jnp.log(s_mid) + log_gauss)
    return where(poisson_only, log_poisson, where(gauss_only, log_gauss, mixed))


def _normal_logcdf(x: jax.Array, mean: jax.Array, sd: jax.Array) -> jax.Array:
    return log_ndtr((x - mean) / sd)


def _normal_logpdf(x: jax.Array, mean: jax.Array, sd: jax.Array) -> jax.Array:
    z = (x - mean) / sd
    return -0.5 * z * z - jnp.log(sd) - _HALF_LOG_2PI


#: Log value standing in for log 0 (a charge below zero from one photoelectron).
_LOG_ZERO = -1e30


def _truncated_logpdf(q: jax.Array, width: jax.Array) -> jax.Array:
    """log density (1/p.e.) of one photoelectron's charge, Normal(1, w) truncated at 0."""
    value = _normal_logpdf(q, 1.0, width) - log_ndtr(1.0 / width)
    return where(q >= 0, value, _LOG_ZERO)


def _truncated_logcdf(q: jax.Array, width: jax.Array) -> jax.Array:
    """log P(charge < q) of one photoelectron (Normal(1, w) truncated at 0)."""
    floor = ndtr(-1.0 / width)
    above = jnp.maximum(ndtr((q - 1.0) / width) - floor, jnp.finfo(q.dtype).tiny)
    value = jnp.log(above) - log_ndtr(1.0 / width)
    return where(q > 0, value, _LOG_ZERO)


def charge_logpdf(
    q: jax.Array,
    mu: jax.Array,
    spe_width: jax.Array,
    *,
    n_terms: int = N_TERMS,
    mu_switch: float = MU_SWITCH,
    blend: float = MU_BLEND,
) -> jax.Array:
    """Log density of the charge of a hit sensor, ``log P(q | mu, n >= 1)``, log(1/p.e.).

    Args:
        q: charge, p.e. (any shape broadcasting with ``mu``).
        mu: expected number of photoelectrons (> 0), p.e.
        spe_width: width w of the single-p.e. charge Normal(1, w) truncated at 0 (see
            ``photonflow.response.spe``), p.e. (scalar or broadcastable).
        n_terms: number of consecutive n summed in the exact branch (static).
        mu_switch: centre of the blend into the Gaussian approximation, p.e. (static).
        blend: half-width of the blend, p.e. (static).
    """
    return _charge_mixture(
        q, mu, spe_width, _truncated_logpdf, _normal_logpdf, n_terms, mu_switch, blend
    )


def charge_logcdf(
    q: jax.Array,
    mu: jax.Array,
    spe_width: jax.Array,
    *,
    n_terms: int = N_TERMS,
    mu_switch: float = MU_SWITCH,
    blend: float = MU_BLEND,
) -> jax.Array:
    """``log P(charge < q | mu, n >= 1)`` (the cumulative of ``charge_logpdf``).

    Args:
        q: charge, p.e.; mu: expected p.e. (> 0); spe_width: width w of the
            single-p.e. charge Normal(1, w) truncated at 0, p.e.
        n_terms, mu_switch, blend: as in ``charge_logpdf`` (static).
    """
    return _charge_mixture(
        q, mu, spe_width, _truncated_logcdf, _normal_logcdf, n_terms, mu_switch, blend
    )


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
    prediction: Prediction, t: jax.Array, mu_dark: jax.Array, window: tuple[float, float]
) -> jax.Array:
    """Log density of the first-hit time given at least one hit, log(1/ns).

    ``p_first(t) = lambda(t) exp(-Lambda(t)) / (1 - exp(-mu))`` with
    ``lambda(t) = mu_s f(t) + mu_d / T`` inside the window (``mu_s f(t)`` outside),
    ``Lambda(t) = mu_s F(t) + mu_d clip((t - t0) / T, 0, 1)`` and ``mu = mu_s + mu_d``.

    Args:
        prediction: signal prediction (``charge`` mu_s in p.e., time mixture in ns).
        t: (N,) first-hit time per sensor, ns.
        mu_dark: dark-noise p.e. per sensor in the window (> 0; scalar or (N,)).
        window: readout window (t0, t1), ns.
    """
    log_lambda, big_lambda = _log_intensity_and_integral(prediction, t, mu_dark, window)
    return log_lambda - big_lambda - log1mexp(prediction.charge + mu_dark)


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

    Returns:
        (N,) ``-log P`` per sensor (dimensionless for unhit sensors; densities in
        1/p.e. and, with ``use_time``, 1/ns for hit sensors). Differentiable in every
        field of ``prediction`` and ``params``; works under ``jit``.
    """
    return dense_sensor_nll(
        *_dense_arguments(prediction, event, params, window),
        charge_threshold=charge_threshold, use_time=use_time,
    )


def _dense_arguments(prediction: Prediction, event: Event, params, window) -> tuple:
    """The positional arguments of ``dense_sensor_nll`` for ``sensor_nll``'s inputs."""
    n = prediction.charge.shape[0]
    hit, q, t = hit_arrays(event, n, prediction.charge.dtype)
    dark_rate, spe_width, window = _response(prediction, params, window)
    return prediction, hit, q, t, dark_rate, spe_width, window


@functools.partial(jax.jit, static_argnames=("window", "charge_threshold", "use_time"))
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

    log_hit = log1mexp(mu)
    log_hit = log_hit + charge_logpdf(q, mu, width)
    if use_time:
        time_term = first_hit_logpdf(prediction, t, mu_dark, window)
        if time_weight is not None:
            time_term = jnp.asarray(time_weight, dtype=dtype) * time_term
        log_hit = log_hit + time_term
    if charge_threshold is None:
        log_unhit = -mu
    else:
        below = charge_logcdf(jnp.full(n, charge_threshold, dtype=dtype), mu, width)
        log_unhit = jnp.logaddexp(-mu, log1mexp(mu) + below)
    return -where(hit, log_hit, log_unhit)


def nll(
    prediction: Prediction,
    event: Event,
    params: Params | None = None,
    *,
    window: tuple[float, float] | None = None,
    charge_threshold: float | None = None,
    use_time: bool = True,
) -> jax.Array:
    """Total negative log-likelihood of an event: the sum of ``sensor_nll`` (scalar).

    Arguments as in ``sensor_nll`` (window in ns, threshold in p.e.).
    """
    return dense_nll(
        *_dense_arguments(prediction, event, params, window),
        charge_threshold=charge_threshold, use_time=use_time,
    )


def _summed_sensor_nll(*arguments, **options) -> jax.Array:
    """``dense_sensor_nll`` summed over sensors (scalar)."""
    return jnp.sum(dense_sensor_nll(*arguments, **options))


#: ``dense_sensor_nll`` summed over sensors (scalar) in one jitted program, with no eager
#: reduction after it; arguments and units as for ``dense_sensor_nll`` (the window, the
#: seventh, static).
dense_nll = jax.jit(
    _summed_sensor_nll, static_argnums=(6,), static_argnames=("charge_threshold", "use_time")
)
