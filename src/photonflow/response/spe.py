"""The single-photoelectron charge model shared by the sensor response and the likelihood.

One photoelectron gives a charge q ~ Normal(1, w) truncated at q >= 0 (p.e.), w the
``spe_width`` parameter. Its mean and variance (below) enter the likelihood, so that
the charge model of the expected mode is the one the sampled mode draws from, even for
wide single-p.e. spectra (w ~ 1, where the truncation raises the mean to ~1.3).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jax.scipy.special import ndtr


def single_pe_moments(spe_width):
    """Mean (p.e.) and variance (p.e.^2) of Normal(1, w) truncated at zero.

    With a = -1 / w and lambda = phi(a) / (1 - Phi(a)): mean = 1 + w lambda,
    variance = w^2 (1 + a lambda - lambda^2). Differentiable in w.
    """
    width = jnp.asarray(spe_width)
    a = -1.0 / width
    inverse_mills = jnp.exp(-0.5 * a * a) / math.sqrt(2.0 * math.pi) / ndtr(-a)
    mean = 1.0 + width * inverse_mills
    variance = width * width * (1.0 + a * inverse_mills - inverse_mills * inverse_mills)
    return mean, variance
