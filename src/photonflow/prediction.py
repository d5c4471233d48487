"""``Prediction``: expected light per sensor, the input of the likelihood.

For each of N sensors it holds the expected number of signal photoelectrons and the
arrival-time density of that light as a K-component mixture (the sensor's transit-time
spread and time offset already folded in by whoever builds it) of Gaussians or, where a
component has a decay time tau > 0 (scintillation light), exponentially modified
Gaussians: a Gaussian (mean mu, width sigma) convolved with an exponential delay of mean
tau, density

    f(t) = exp(sigma^2 / (2 tau^2) - (t - mu) / tau) Phi((t - mu) / sigma - sigma / tau) / tau,

cumulative Phi((t - mu) / sigma) - tau f(t). Dark noise is not included; the likelihood
adds it.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax.scipy.special import log_ndtr, ndtr

from .numerics import where
from .pytree import pytree_dataclass, static_field

#: Time-mixture components lighter than this share of a sensor's light are left out of
#: its log density: the second derivative of log w, -1 / w^2, overflows float32 below
#: w ~ 1e-19 (a quadrature panel far from the Cherenkov peak holds ~1e-21 of the light,
#: and the Hessian of the SK likelihood was NaN); such a component changes the density
#: by less than 1e-15 of itself, and the dark noise outweighs it anyway.
WEIGHT_FLOOR = 1e-15

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


@pytree_dataclass
class Prediction:
    """Expected signal per sensor (array fields are JAX leaves; ``window`` is static).

    Attributes:
        charge: (N,) expected number of signal photoelectrons per sensor, p.e.
            (no dark noise).
        time_weight: (N, K) mixture weights of the arrival-time density (rows sum to 1).
        time_mean: (N, K) component means, ns.
        time_sigma: (N, K) component standard deviations (> 0), ns.
        residual_weight: scalar, expected number of photons (not p.e.) still alive when
            the transport stopped at its bounce cap, i.e. light that was not followed
            (0 for a prediction without truncated transport).
        dark_rate: dark-noise rate per sensor, Hz, and ``spe_width`` the single-p.e.
            width, p.e.: the sensor-response parameters the prediction was made with
            (``expected`` fills them from ``Params``), so that ``nll(prediction, event)``
            needs nothing else; None when not known.
        window: readout window (t0, t1), ns (static), or None.
        time_tau: (N, K) decay times of exponentially modified components, ns (0: a
            Gaussian component), or None: all components Gaussian.
    """

    charge: jax.Array
    time_weight: jax.Array
    time_mean: jax.Array
    time_sigma: jax.Array
    residual_weight: jax.Array = 0.0
    dark_rate: jax.Array | None = None
    spe_width: jax.Array | None = None
    window: tuple[float, float] | None = static_field(default=None)
    time_tau: jax.Array | None = None

    @property
    def n_sensors(self) -> int:
        """Number of sensors N."""
        return int(self.charge.shape[0])

    @classmethod
    def from_components(cls, charge, weights, means, sigmas, residual_weight=0.0) -> Prediction:
        """Build from array-likes, broadcasting the mixture to shape (N, K).

        Args:
            charge: (N,) expected signal p.e. per sensor.
            weights: (N, K) or (K,) non-negative mixture weights; each row is divided by
                its sum (so they need not be normalised).
            means: (N, K) or (K,) component means, ns.
            sigmas: (N, K) or (K,) component standard deviations, ns.
            residual_weight: expected photons left untracked at the bounce cap (scalar).
        """
        charge = jnp.asarray(charge)
        n = charge.shape[0]
        floating = jnp.issubdtype(charge.dtype, jnp.floating)
        dtype = charge.dtype if floating else jnp.zeros(()).dtype
        charge = charge.astype(dtype)
        weights, means, sigmas = (jnp.asarray(x, dtype=dtype) for x in (weights, means, sigmas))
        k = max(jnp.shape(x)[-1] for x in (weights, means, sigmas))
        weights, means, sigmas = (jnp.broadcast_to(x, (n, k)) for x in (weights, means, sigmas))
        weights = weights / jnp.sum(weights, axis=1, keepdims=True)
        return cls(
            charge=charge,
            time_weight=weights,
            time_mean=means,
            time_sigma=sigmas,
            residual_weight=jnp.asarray(residual_weight, dtype=dtype),
        )

    def _z(self, t: jax.Array) -> jax.Array:
        t = jnp.asarray(t, dtype=self.time_mean.dtype)
        return (t[:, None] - self.time_mean) / self.time_sigma

    def time_logpdf(self, t: jax.Array) -> jax.Array:
        """Log of the arrival-time density at one time per sensor.

        Args:
            t: (N,) times, ns.

        Returns:
            (N,) log f_j(t_j), log(1/ns). Finite (a large negative number) far in the
            tails; computed as a log-sum-exp over the components of positive weight,
            shifted by the largest term, so no term overflows or vanishes whatever the
            time (components of weight below ``WEIGHT_FLOOR`` contribute nothing, to the
            value or to the derivatives of any order).
        """
        log_component = self._log_components(t)
        w = self.time_weight
        used = w > WEIGHT_FLOOR
        terms = where(used, jnp.log(where(used, w, 1.0)) + log_component, -jnp.inf)
        shift = jax.lax.stop_gradient(jnp.max(terms, axis=1, keepdims=True))
        shift = where(jnp.isfinite(shift), shift, 0.0)
        total = jnp.sum(where(used, jnp.exp(terms - shift), 0.0), axis=1)
        return shift[:, 0] + jnp.log(total)

    def time_pdf(self, t: jax.Array) -> jax.Array:
        """Arrival-time density f_j(t_j), 1/ns, for t of shape (N,) in ns."""
        return jnp.exp(self.time_logpdf(t))

    def time_cdf(self, t: jax.Array) -> jax.Array:
        """Cumulative arrival-time distribution F_j(t_j) in [0, 1], for t of shape (N,) ns."""
        gaussian = ndtr(self._z(t))
        if self.time_tau is None:
            return jnp.sum(self.time_weight * gaussian, axis=1)
        delayed = self.time_tau > 0
        tau = where(delayed, self.time_tau, 1.0)
        # Phi(z) - tau f(t), tau f(t) written from its logarithm
        tail = jnp.exp(jnp.log(tau) + self._log_components(t))
        return jnp.sum(self.time_weight * jnp.clip(where(delayed, gaussian - tail, gaussian),
                                                   0.0, 1.0), axis=1)

    def _log_components(self, t: jax.Array) -> jax.Array:
        """(N, K) log densities of the components at one time per sensor, log(1/ns)."""
        z = self._z(t)
        gaussian = -0.5 * z * z - jnp.log(self.time_sigma) - _HALF_LOG_2PI
        if self.time_tau is None:
            return gaussian
        delayed = self.time_tau > 0
        tau = where(delayed, self.time_tau, 1.0)
        ratio = self.time_sigma / tau
        modified = 0.5 * ratio * ratio - z * ratio + log_ndtr(z - ratio) - jnp.log(tau)
        return where(delayed, modified, gaussian)
