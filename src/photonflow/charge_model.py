"""The charge of a hit sensor: how many photoelectrons (Poisson, or negative-binomial of
variance mu + r mu^2 with ``overdispersion`` r: a Poisson count of a gamma-distributed
mean; ``photonflow.likelihood`` says why) and the sum of their single-p.e. charges.

For a mean of mu p.e., ``charge_logpdf`` is ``log P(q | n >= 1)`` with
``P(q | n >= 1) = sum_{n>=1} P(n; mu) K_n(q) / (1 - P(0; mu))``: K_1 the exact
single-p.e. density (Normal(1, w) truncated at 0, ``photonflow.response.spe``), K_n for
n >= 2 a normal of n times its mean and variance. The sum runs over ``N_TERMS``
consecutive n and is blended (a mixture of densities, so the normalisation is kept) into
a continuous model of the charge's mean and variance above a switch: a normal for
Poisson counts, a Gamma density for overdispersed ones (skewed like the
negative-binomial). ``photonflow.likelihood`` builds the event likelihood on it.
Charges in p.e.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax.scipy.special import gammainc, gammaln, log_ndtr, ndtr

from .errors import ConfigError
from .numerics import clip, where
from .response.spe import single_pe_moments

#: Number of consecutive photoelectron counts n summed in the exact charge model.
N_TERMS = 128
#: Centre of the blend from the exact Poisson sum to the Gaussian charge model, p.e.
MU_SWITCH = 80.0
#: Half-width of that blend, p.e.
MU_BLEND = 20.0
#: With overdispersion: centre and half-width (p.e.) of the blend from the exact
#: negative-binomial sum into the Gamma charge model (the sum's window of ``N_TERMS``
#: counts then reaches 11 standard deviations above the mean at 13 p.e. for r = 0.5).
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
    log_unhit = log_no_photoelectron(mu, r)
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


def log_no_photoelectron(mu: jax.Array, overdispersion: float) -> jax.Array:
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
        overdispersion: r in [0, ``MAX_OVERDISPERSION``] (static, dimensionless): the
            count's variance is mu + r mu^2; 0 is Poisson.
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
