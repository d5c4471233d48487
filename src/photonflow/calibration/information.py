"""Fisher information of the calibration likelihoods: the charge about its expectation,
and the first-hit time about the parameters (second half of this module).

A sensor that collects n ~ Poisson(M) photoelectrons over a run records the summed
charge Q of n single-p.e. charges (``photonflow.response.spe``; Q = 0 exactly when n = 0). The
information about M carried by Q,

    I(M) = E[(d log P(Q | M) / dM)^2]
         = e^-M + integral over Q > 0 of p(Q) (d log p(Q) / dM)^2 dQ,

lies between the Gaussian limit m1^2 / (M (m1^2 + v1)) at large M (m1, v1 the mean and
variance of one photoelectron's charge) and the Poisson value 1 / M of counting alone
at small M, where a hit is almost surely one photoelectron. It is computed once per
single-p.e. width by quadrature of the very density the likelihood uses
(``photonflow.likelihood.charge_logpdf``), tabulated as M I(M) against log M, and
interpolated. The Fisher matrix of the calibration parameters is J^T diag(I) J, with J
the Jacobian of the expected charges: its inverse is the Cramer-Rao bound.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import log_ndtr, ndtr

from ..likelihood import MU_BLEND, MU_SWITCH, charge_logpdf, log1mexp
from ..numerics import clip, where
from ..response.spe import single_pe_moments

#: log10 of the smallest and largest tabulated M, p.e. Below, M I(M) is constant (pure
#: counting); above, the likelihood is its Gaussian branch and I(M) is ``gaussian_limit``.
LOG10_MU_RANGE = (-4.0, math.log10(MU_SWITCH + MU_BLEND))
#: Number of tabulated M values and of quadrature nodes in Q per value.
N_MU = 61
N_CHARGE = 1501


def _log_density(q, mu, width):
    """log of P(n >= 1) x density of Q given n >= 1, i.e. log p(Q), for Q > 0."""
    return log1mexp(mu) + charge_logpdf(q, mu, width)


#: log p(Q) and d log p(Q) / dM on an (M, Q) grid: (N_MU, N_CHARGE) arrays each.
_scores = jax.jit(
    jax.vmap(
        jax.vmap(jax.value_and_grad(_log_density, argnums=1), (0, None, None)), (0, 0, None)
    )
)


def _third_derivative(q, mu, width):
    """d^3 log p(Q) / dM^3, 1/p.e.^3."""
    first = jax.grad(_log_density, argnums=1)
    second = jax.grad(first, argnums=1)
    return jax.grad(second, argnums=1)(q, mu, width)


#: d^3 log p(Q) / dM^3 on an (M, Q) grid: (N_MU, N_CHARGE).
_third_derivatives = jax.jit(
    jax.vmap(jax.vmap(_third_derivative, (0, None, None)), (0, 0, None))
)


def _charge_grid(spe_width: float):
    """The quadrature of the tables: (log M (N_MU,), M (N_MU,), charges Q > 0
    (N_MU, N_CHARGE) p.e. at the midpoints of N_CHARGE equal steps up to far beyond the
    charge distribution of M, step (N_MU,) p.e.)."""
    log_mu = np.log(np.logspace(*LOG10_MU_RANGE, N_MU))
    mu = np.exp(log_mu)
    mean_one = 1.0 + spe_width  # generous upper reach per photoelectron
    upper = mu * mean_one + 12.0 * np.sqrt(mu * (1.0 + spe_width**2)) + 12.0 * spe_width + 2.0
    fraction = (np.arange(1, N_CHARGE + 1) - 0.5) / N_CHARGE  # midpoints: Q > 0
    charges = upper[:, None] * fraction[None, :]
    return log_mu, mu, charges, upper / N_CHARGE


@functools.lru_cache(maxsize=16)
def information_table(spe_width: float) -> tuple[np.ndarray, np.ndarray]:
    """(log M, M I(M)) on ``N_MU`` points over ``LOG10_MU_RANGE``, for one
    single-p.e. width (p.e.); M I(M) is dimensionless (1 for pure counting)."""
    log_mu, mu, charges, step = _charge_grid(spe_width)
    log_p, d_log_p = _scores(jnp.asarray(charges, jnp.float32), jnp.asarray(mu, jnp.float32),
                             jnp.float32(spe_width))
    log_p, d_log_p = np.asarray(log_p, np.float64), np.asarray(d_log_p, np.float64)
    information = np.exp(-mu) + step * np.sum(np.exp(log_p) * d_log_p**2, axis=1)
    return log_mu, mu * information


@functools.lru_cache(maxsize=16)
def score_curvature_table(spe_width: float) -> tuple[np.ndarray, np.ndarray]:
    """(log M, M^2 E[d^3(-log L)/dM^3]) on the points of ``information_table``, for one
    single-p.e. width (p.e.); dimensionless (-2 for pure counting). No hit contributes
    nothing: there -log L = M."""
    log_mu, mu, charges, step = _charge_grid(spe_width)
    q, m, width = (jnp.asarray(charges, jnp.float32), jnp.asarray(mu, jnp.float32),
                   jnp.float32(spe_width))
    log_p, _ = _scores(q, m, width)
    third = np.asarray(_third_derivatives(q, m, width), np.float64)
    expectation = -step * np.sum(np.exp(np.asarray(log_p, np.float64)) * third, axis=1)
    return log_mu, mu**2 * expectation


def expected_score_curvature(mu: jax.Array, spe_width: float) -> jax.Array:
    """E[d^3(-log L)/dM^3] of one sensor's summed charge at expected charge M (p.e.),
    1/p.e.^3, the data drawn at M: the expected second derivative of the score dL/dM,
    which sets the second-order (Jensen) bias of the score at a noisy M. Tabulated by
    quadrature of the likelihood's own density (``score_curvature_table``); -2/M^2 for
    pure counting at small M, and above the table the Gaussian charge model's
    -3 m1^2/(M^2 (m1^2 + v1)) - 2/M^3. ``spe_width`` in p.e., a Python float. Shape of
    ``mu``."""
    log_mu, scaled = score_curvature_table(float(spe_width))
    mu = jnp.asarray(mu)
    clipped = clip(jnp.log(mu), log_mu[0], log_mu[-1])
    table = jnp.interp(clipped, jnp.asarray(log_mu, mu.dtype),
                       jnp.asarray(scaled, mu.dtype)) / (mu * mu)
    with jax.ensure_compile_time_eval():  # constants, also when called under jit
        mean_one, var_one = (float(x) for x in single_pe_moments(spe_width))
    gaussian = -3.0 * mean_one**2 / (mu * mu * (mean_one**2 + var_one)) - 2.0 / mu**3
    return where(mu > math.exp(log_mu[-1]), gaussian, table)


def charge_information(mu: jax.Array, spe_width: float) -> jax.Array:
    """Fisher information I(M) about the expected charge M (p.e.) of the summed charge of
    one sensor, 1/p.e.^2 (see the module docstring); ``spe_width`` in p.e., a Python
    float. Shape of ``mu``."""
    log_mu, scaled = information_table(float(spe_width))
    mu = jnp.asarray(mu)
    clipped = clip(jnp.log(mu), log_mu[0], log_mu[-1])
    table = jnp.interp(clipped, jnp.asarray(log_mu, mu.dtype), jnp.asarray(scaled, mu.dtype)) / mu
    return where(mu > math.exp(log_mu[-1]), gaussian_limit(mu, spe_width), table)


def gaussian_limit(mu, spe_width: float):
    """I(M) of the Gaussian charge model Normal(M m1, M (m1^2 + v1)), 1/p.e.^2, for M in
    p.e. (array or float) and the single-p.e. width in p.e."""
    with jax.ensure_compile_time_eval():  # constants, also when called under jit
        mean_one, var_one = (float(x) for x in single_pe_moments(spe_width))
    second = mean_one**2 + var_one
    return mean_one**2 / (mu * second) + 1.0 / (2.0 * mu * mu)



# --- first-hit time ------------------------------------------------------------------
#
# The time term of the charge-and-time likelihood is the density of a sensor's first-hit
# time given a hit, p(t) = lambda(t) exp(-Lambda(t)) / (1 - exp(-mu))
# (``photonflow.likelihood.first_hit_logpdf``). Its Fisher information about the
# parameters, E[s s^T] with s = d log p(t) / d theta, is an integral over t. With the
# first-hit distribution function G, t = G^-1(Phi(x)) maps a standard normal x onto the
# first-hit time, so E[h(t)] = integral of h(G^-1(Phi(x))) phi(x) dx: a trapezoid rule on
# a uniform grid in x (weights phi(x)) is exact to ~1e-8 for a Gaussian time density and
# for the first-hit time of many photoelectrons, and robust for mixtures.

#: Number of quadrature nodes in x and their range (+- standard deviations; the mass
#: outside, 3e-12, is neglected).
N_TIME_NODES = 48
TIME_NODE_RANGE = 7.0
#: Bisection steps of the first-hit quantiles (the bracket of <= a few 1000 ns shrinks
#: below float32 resolution).
QUANTILE_ITERATIONS = 60


def time_nodes(dtype=np.float32) -> tuple[np.ndarray, np.ndarray]:
    """(x, w): ``N_TIME_NODES`` standard-normal abscissae on [-R, R] and trapezoid
    weights proportional to phi(x), summing to 1 (dimensionless)."""
    x = np.linspace(-TIME_NODE_RANGE, TIME_NODE_RANGE, N_TIME_NODES)
    w = np.exp(-0.5 * x * x)
    return x.astype(dtype), (w / w.sum()).astype(dtype)


def _light_integrals(prediction, t, mu_dark, window):
    """(Lambda(t), mu - Lambda(t)) in p.e. for times t (N, G) ns: the expected number of
    photoelectrons (signal + dark) before and after t, each summed from its own tail so
    that both stay accurate where they are small."""
    t0, t1 = window
    length = t1 - t0
    z = (t[:, :, None] - prediction.time_mean[:, None, :]) / prediction.time_sigma[:, None, :]
    weight = prediction.time_weight[:, None, :]
    before = jnp.sum(weight * ndtr(z), axis=-1)
    after = jnp.sum(weight * ndtr(-z), axis=-1)
    mu_s = prediction.charge[:, None]
    mu_d = jnp.broadcast_to(mu_dark, prediction.charge.shape)[:, None]
    dark_before = mu_d * clip((t - t0) / length, 0.0, 1.0)
    dark_after = mu_d * clip((t1 - t) / length, 0.0, 1.0)
    return mu_s * before + dark_before, mu_s * after + dark_after


def first_hit_log_cdf(prediction, t, mu_dark, window) -> tuple[jax.Array, jax.Array]:
    """(log P(T < t | hit), log P(T > t | hit)) of the first-hit time T of every sensor,
    for times t (N, G) ns; ``mu_dark`` dark p.e. per sensor in ``window`` (t0, t1) ns."""
    before, after = _light_integrals(prediction, t, mu_dark, window)
    log_hit = log1mexp(before + after)
    return log1mexp(before) - log_hit, -before + log1mexp(after) - log_hit


def first_hit_quantiles(prediction, mu_dark, window, x) -> jax.Array:
    """(N, G) first-hit times (ns) t with P(T < t | hit) = Phi(x) for the G standard-normal
    values x, by bisection (the lower tail matched in log P(T < t), the upper one in
    log P(T > t), so both tails are resolved). Not differentiated (stop_gradient)."""
    prediction = jax.lax.stop_gradient(prediction)
    mu_dark = jax.lax.stop_gradient(mu_dark)
    x = jnp.asarray(x, prediction.charge.dtype)
    reach = 12.0 * prediction.time_sigma
    low = jnp.minimum(jnp.min(prediction.time_mean - reach, axis=1), window[0]) - 1.0
    high = jnp.maximum(jnp.max(prediction.time_mean + reach, axis=1), window[1]) + 1.0
    shape = (prediction.charge.shape[0], x.shape[0])
    low, high = jnp.broadcast_to(low[:, None], shape), jnp.broadcast_to(high[:, None], shape)
    lower_tail = x[None, :] < 0
    target_below, target_above = log_ndtr(x)[None, :], log_ndtr(-x)[None, :]

    def bisect(_, bracket):
        low, high = bracket
        middle = 0.5 * (low + high)
        log_below, log_above = first_hit_log_cdf(prediction, middle, mu_dark, window)
        early = where(lower_tail, log_below < target_below, log_above > target_above)
        return where(early, middle, low), where(early, high, middle)

    low, high = jax.lax.fori_loop(0, QUANTILE_ITERATIONS, bisect, (low, high))
    return 0.5 * (low + high)


def first_hit_scores_information(scores: jax.Array, weights: jax.Array) -> jax.Array:
    """E[s s^T | hit] per sensor, (N, T, T), from scores (T, N, G) at the quantile nodes
    (units: 1 / (unit of the parameters)^2) and the node weights (G,)."""
    return jnp.einsum("ang,bng,g->nab", scores, scores, weights)
