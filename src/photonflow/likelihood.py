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

import dataclasses
import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammainc, gammaln, log_ndtr, ndtr

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
#: With overdispersion: centre and half-width (p.e.) of the blend from the exact
#: negative-binomial sum into the Gamma charge model (the sum's window of ``N_TERMS``
#: counts then reaches the mean + 9 standard deviations for r = 0.5).
OVERDISPERSED_SWITCH = 10.0
OVERDISPERSED_BLEND = 3.0
#: Largest overdispersion r accepted (the negative-binomial window's reach).
MAX_OVERDISPERSION = 0.5

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
    kernels: _ChargeKernels,
    n_terms: int,
    mu_switch: float,
    blend: float,
    overdispersion: float = 0.0,
) -> jax.Array:
    """Log of E[kernel(q | n) | n >= 1] for n ~ Poisson(mu) (or negative-binomial with
    variance mu + r mu^2 for ``overdispersion`` r > 0), blended into a continuous model.

    The kernel of one photoelectron is ``kernels.one(q, w)`` (the exact truncated normal
    of ``photonflow.response.spe``); for n >= 2 it is ``kernels.normal(q, mean, sd)``
    with the n-fold mean and variance; the continuous branch is ``kernels.normal`` of
    the charge's mean and variance (r = 0) or ``kernels.gamma(q, shape, scale)``
    (r > 0). All return log values (densities for ``charge_logpdf``, cumulatives for
    ``charge_logcdf``).
    """
    q, mu = jnp.broadcast_arrays(jnp.asarray(q), jnp.asarray(mu))
    spe_width = jnp.broadcast_to(jnp.asarray(spe_width, dtype=mu.dtype), mu.shape)
    q = q.astype(mu.dtype)

    def count_kernel(n, mean_n, sigma_n):
        one = kernels.one(q[..., None], spe_width[..., None])
        return where(n == 1, one, kernels.normal(q[..., None], mean_n, sigma_n))

    tiny = jnp.finfo(mu.dtype).tiny
    lo, hi = mu_switch - blend, mu_switch + blend
    s = clip((mu - lo) / (hi - lo), 0.0, 1.0)
    s = s * s * (3.0 - 2.0 * s)  # smoothstep: C1 blend
    exact_only = mu <= lo
    continuous_only = mu >= hi

    # n photoelectrons give a charge of mean n m1 and variance n v1 (``spe``).
    mean_one, var_one = single_pe_moments(spe_width)

    # Exact sum over n_lo .. n_lo + n_terms - 1 (double-where: safe mu).
    mu_p = where(continuous_only, mu_switch, jnp.maximum(mu, tiny))
    n_lo = jnp.maximum(1.0, jnp.floor(mu_p) - (n_terms // 2 - 1))
    n = n_lo[..., None] + jnp.arange(n_terms, dtype=mu.dtype)
    sigma_n = jnp.sqrt(n * var_one[..., None])
    log_weight, log_norm = _hit_count_logpmf(n, mu_p, overdispersion)
    log_exact = (
        jax.nn.logsumexp(log_weight + count_kernel(n, n * mean_one[..., None], sigma_n),
                         axis=-1)
        + log_norm
    )

    # Continuous approximation of the charge (double-where: safe mu).
    mu_c = where(exact_only, mu_switch, mu)
    mean_q = mu_c * mean_one
    if overdispersion > 0:
        variance_q = (mu_c * var_one
                      + (mu_c + overdispersion * mu_c * mu_c) * mean_one * mean_one)
        log_continuous = kernels.gamma(q, mean_q * mean_q / variance_q, variance_q / mean_q)
    else:
        log_continuous = kernels.normal(q, mean_q,
                                        jnp.sqrt(mu_c * (var_one + mean_one * mean_one)))

    s_mid = where(exact_only | continuous_only, 0.5, s)
    mixed = jnp.logaddexp(jnp.log1p(-s_mid) + log_exact, jnp.log(s_mid) + log_continuous)
    return where(exact_only, log_exact, where(continuous_only, log_continuous, mixed))


def _hit_count_logpmf(n: jax.Array, mu: jax.Array, overdispersion: float):
    """log P(n | n >= 1) of the photoelectron count n >= 1 (mean mu > 0 p.e.; n has one
    more axis), as (a term per n, a term per mu) to be added: Poisson, or
    negative-binomial with variance mu + r mu^2 for ``overdispersion`` r > 0."""
    if overdispersion == 0:
        # log(mu^n e^-mu / n! / (1 - e^-mu)), written so that mu -> 0 stays finite.
        log_weight = (n - 1.0) * jnp.log(mu)[..., None] - gammaln(n + 1.0)
        return log_weight, jnp.log(mu) - mu - log1mexp(mu)
    r = overdispersion
    log_unhit = _log_unhit(mu, r)
    log_weight = (n * (jnp.log(mu) - jnp.log1p(r * mu))[..., None]
                  + _log_rising_product(n, r) - gammaln(n + 1.0))
    return log_weight, log_unhit - log1mexp(-log_unhit)


def _log_rising_product(n: jax.Array, r: float) -> jax.Array:
    """sum_{j < n} log(1 + r j) for r > 0 (static): log Gamma(n + 1/r) - log Gamma(1/r)
    + n log r, from ``gammaln`` for r >= 0.1 and from Stirling's series otherwise
    (where the two log-gammas of ~1/r would cancel to float32 noise; series error
    < 1e-8 there)."""
    if r >= 0.1:
        return gammaln(n + 1.0 / r) - math.lgamma(1.0 / r) + n * math.log(r)
    grown = jnp.log1p(n * r)
    ratio = 1.0 / (1.0 + n * r)
    return ((1.0 / r - 0.5 + n) * grown - n + r * (ratio - 1.0) / 12.0
            - r**3 * (ratio**3 - 1.0) / 360.0)


def _log_unhit(mu: jax.Array, overdispersion: float) -> jax.Array:
    """log P(no photoelectron) for mean mu (p.e.): -mu, or -log(1 + r mu) / r."""
    if overdispersion == 0:
        return -mu
    return -jnp.log1p(overdispersion * mu) / overdispersion


def _switch(overdispersion: float, mu_switch, blend) -> tuple[float, float]:
    """The blend's centre and half-width (p.e.): the given ones, else the defaults of
    the Poisson or the overdispersed model."""
    if overdispersion > 0:
        defaults = (OVERDISPERSED_SWITCH, OVERDISPERSED_BLEND)
    else:
        defaults = (MU_SWITCH, MU_BLEND)
    return (defaults[0] if mu_switch is None else mu_switch,
            defaults[1] if blend is None else blend)


def check_overdispersion(overdispersion: float) -> float:
    """``overdispersion`` as a float in [0, ``MAX_OVERDISPERSION``]; a one-line
    ``ConfigError`` otherwise."""
    if not isinstance(overdispersion, int | float) or not (
            0.0 <= overdispersion <= MAX_OVERDISPERSION):
        raise ConfigError(f"overdispersion = {overdispersion!r}: must be a number in"
                          f" [0, {MAX_OVERDISPERSION}]")
    return float(overdispersion)


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


def _gamma_logpdf(q: jax.Array, shape: jax.Array, scale: jax.Array) -> jax.Array:
    safe_q = jnp.maximum(q, jnp.finfo(q.dtype).tiny)
    value = ((shape - 1.0) * jnp.log(safe_q) - safe_q / scale - gammaln(shape)
             - shape * jnp.log(scale))
    return where(q > 0, value, _LOG_ZERO)


def _gamma_logcdf(q: jax.Array, shape: jax.Array, scale: jax.Array) -> jax.Array:
    safe_q = jnp.maximum(q, jnp.finfo(q.dtype).tiny)
    above = jnp.maximum(gammainc(shape, safe_q / scale), jnp.finfo(q.dtype).tiny)
    return where(q > 0, jnp.log(above), _LOG_ZERO)


@dataclasses.dataclass(frozen=True)
class _ChargeKernels:
    """Log kernels of the charge model: one photoelectron (q, w), a normal (q, mean, sd)
    and a Gamma (q, shape, scale); densities or cumulatives."""

    one: Callable
    normal: Callable
    gamma: Callable


_DENSITIES = _ChargeKernels(_truncated_logpdf, _normal_logpdf, _gamma_logpdf)
_CUMULATIVES = _ChargeKernels(_truncated_logcdf, _normal_logcdf, _gamma_logcdf)


def charge_logpdf(
    q: jax.Array,
    mu: jax.Array,
    spe_width: jax.Array,
    *,
    n_terms: int = N_TERMS,
    mu_switch: float | None = None,
    blend: float | None = None,
    overdispersion: float = 0.0,
) -> jax.Array:
    """Log density of the charge of a hit sensor, ``log P(q | mu, n >= 1)``, log(1/p.e.).

    Args:
        q: charge, p.e. (any shape broadcasting with ``mu``).
        mu: expected number of photoelectrons (> 0), p.e.
        spe_width: width w of the single-p.e. charge Normal(1, w) truncated at 0 (see
            ``photonflow.response.spe``), p.e. (scalar or broadcastable).
        n_terms: number of consecutive n summed in the exact branch (static).
        mu_switch: centre of the blend into the continuous approximation, p.e. (static;
            None: ``MU_SWITCH``, or ``OVERDISPERSED_SWITCH`` with overdispersion).
        blend: half-width of the blend, p.e. (static; None: the default of the model).
        overdispersion: r (static, dimensionless): the count's variance is
            mu + r mu^2 (module docstring); 0 is Poisson.
    """
    mu_switch, blend = _switch(overdispersion, mu_switch, blend)
    return _charge_mixture(q, mu, spe_width, _DENSITIES, n_terms, mu_switch, blend,
                           overdispersion)


def charge_logcdf(
    q: jax.Array,
    mu: jax.Array,
    spe_width: jax.Array,
    *,
    n_terms: int = N_TERMS,
    mu_switch: float | None = None,
    blend: float | None = None,
    overdispersion: float = 0.0,
) -> jax.Array:
    """``log P(charge < q | mu, n >= 1)`` (the cumulative of ``charge_logpdf``).

    Args:
        q: charge, p.e.; mu: expected p.e. (> 0); spe_width: width w of the
            single-p.e. charge Normal(1, w) truncated at 0, p.e.
        n_terms, mu_switch, blend, overdispersion: as in ``charge_logpdf`` (static).
    """
    mu_switch, blend = _switch(overdispersion, mu_switch, blend)
    return _charge_mixture(q, mu, spe_width, _CUMULATIVES, n_terms, mu_switch, blend,
                           overdispersion)


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
    mu = prediction.charge + mu_dark
    if overdispersion == 0:
        return log_lambda - big_lambda - log1mexp(mu)
    r = overdispersion
    return (log_lambda - (1.0 / r + 1.0) * jnp.log1p(r * big_lambda)
            - log1mexp(-_log_unhit(mu, r)))


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


@functools.partial(jax.jit, static_argnames=("window", "charge_threshold", "use_time",
                                             "overdispersion"))
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
    log_none = _log_unhit(mu, r)
    log_hit = log1mexp(mu) if r == 0 else log1mexp(-log_none)
    log_hit = log_hit + charge_logpdf(q, mu, width, overdispersion=r)
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
        log_unhit = jnp.logaddexp(log_none, (log1mexp(mu) if r == 0 else log1mexp(-log_none))
                                  + below)
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
dense_nll = jax.jit(
    _summed_sensor_nll, static_argnums=(6,),
    static_argnames=("charge_threshold", "use_time", "overdispersion"),
)
