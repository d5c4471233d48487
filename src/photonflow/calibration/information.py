"""Fisher information of the run-level charge likelihood about the expected charge.

A sensor that collects n ~ Poisson(M) photoelectrons over a run records the summed
charge Q of n single-p.e. charges (``photonflow.spe``; Q = 0 exactly when n = 0). The
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

from ..likelihood import MU_BLEND, MU_SWITCH, charge_logpdf, log1mexp
from ..spe import single_pe_moments

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


@functools.lru_cache(maxsize=16)
def information_table(spe_width: float) -> tuple[np.ndarray, np.ndarray]:
    """(log M, M I(M)) on ``N_MU`` points over ``LOG10_MU_RANGE``, for one
    single-p.e. width (p.e.); M I(M) is dimensionless (1 for pure counting)."""
    log_mu = np.log(np.logspace(*LOG10_MU_RANGE, N_MU))
    mu = np.exp(log_mu)
    mean_one = 1.0 + spe_width  # generous upper reach per photoelectron
    upper = mu * mean_one + 12.0 * np.sqrt(mu * (1.0 + spe_width**2)) + 12.0 * spe_width + 2.0
    fraction = (np.arange(1, N_CHARGE + 1) - 0.5) / N_CHARGE  # midpoints: Q > 0
    charges = upper[:, None] * fraction[None, :]
    step = upper / N_CHARGE

    width = jnp.float32(spe_width)
    log_p, d_log_p = _scores(jnp.asarray(charges, jnp.float32), jnp.asarray(mu, jnp.float32), width)
    log_p, d_log_p = np.asarray(log_p, np.float64), np.asarray(d_log_p, np.float64)
    information = np.exp(-mu) + step * np.sum(np.exp(log_p) * d_log_p**2, axis=1)
    return log_mu, mu * information


def charge_information(mu: jax.Array, spe_width: float) -> jax.Array:
    """Fisher information I(M) about the expected charge M (p.e.) of the summed charge of
    one sensor, 1/p.e.^2 (see the module docstring); ``spe_width`` in p.e., a Python
    float. Shape of ``mu``."""
    log_mu, scaled = information_table(float(spe_width))
    mu = jnp.asarray(mu)
    clipped = jnp.clip(jnp.log(mu), log_mu[0], log_mu[-1])
    table = jnp.interp(clipped, jnp.asarray(log_mu, mu.dtype), jnp.asarray(scaled, mu.dtype)) / mu
    return jnp.where(mu > math.exp(log_mu[-1]), gaussian_limit(mu, spe_width), table)


def gaussian_limit(mu, spe_width: float):
    """I(M) of the Gaussian charge model Normal(M m1, M (m1^2 + v1)), 1/p.e.^2, for M in
    p.e. (array or float) and the single-p.e. width in p.e."""
    with jax.ensure_compile_time_eval():  # constants, also when called under jit
        mean_one, var_one = (float(x) for x in single_pe_moments(spe_width))
    second = mean_one**2 + var_one
    return mean_one**2 / (mu * second) + 1.0 / (2.0 * mu * mu)

