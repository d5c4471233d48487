"""The sensor response of the expected mode: light at each sensor -> ``Prediction``.

The transport (``photonflow.transport``) delivers ``SensorLight``: per sensor, the
expected photoelectrons of a sensor of relative efficiency 1 (the sensor model's quantum
efficiency and angular acceptance are applied path by path, since the incidence angle
belongs to the path) and the arrival-time mixture of that light, before any property of
the individual sensor. ``expected_response`` applies those, in one place:

- charge x ``efficiency`` (per sensor, relative);
- component means + ``time_offset`` (per sensor, ns);
- component widths sqrt(sigma^2 + ``tts``^2) (transit-time spread, ns; a component's
  exponential delay ``time_tau`` is kept);
- the dark rate (Hz) and single-p.e. width (p.e.) attached for the likelihood.

The mixture weights are the shares of each component in the sensor's light and do not
depend on the response.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..numerics import where
from ..params import Params
from ..prediction import Prediction
from ..pytree import pytree_dataclass, static_field


@pytree_dataclass
class SensorLight:
    """Expected light at each sensor before the sensor response (the expected mode's
    transport output; array fields are JAX leaves, ``window`` is static).

    Attributes:
        charge: (N, K) expected photoelectrons of a sensor of relative efficiency 1,
            per mixture component (component 0 direct light, k the light whose last
            vertex is the k-th), p.e.
        time_mean: (N, K) component mean arrival times without the sensor's time
            offset, ns (the direct time where a component has no light).
        time_variance: (N, K) component variances: the spread of the paths' arrival
            times plus the source's pulse width squared, without the transit-time
            spread, ns^2.
        residual_weight: scalar, expected photons still alive at the bounce cap (light
            not followed).
        window: readout window (t0, t1), ns (static), or None.
        time_tau: (N, K) decay times of exponentially modified components (ns; 0 for a
            Gaussian one: ``Prediction.time_tau``), or None: all Gaussian.
    """

    charge: jax.Array
    time_mean: jax.Array
    time_variance: jax.Array
    residual_weight: jax.Array
    window: tuple[float, float] | None = static_field(default=None)
    time_tau: jax.Array | None = None


def expected_response(light: SensorLight, params: Params) -> Prediction:
    """The ``Prediction`` of sensors with the response of ``params`` receiving ``light``:
    charge (p.e.) = efficiency x the summed light; mixture weights = each component's
    share (component 0 alone where there is no light); means + time offset (ns); widths
    sqrt(variance + tts^2) (ns); dark rate (Hz) and single-p.e. width (p.e.) attached.
    Differentiable in ``light`` and every response field of ``params``."""
    total = jnp.sum(light.charge, axis=1)
    lit = total > 0
    safe_total = where(lit, total, 1.0)
    only_direct = jnp.zeros_like(light.charge).at[:, 0].set(1.0)
    weights = where(lit[:, None], light.charge / safe_total[:, None], only_direct)
    return Prediction(
        charge=total * params.efficiency,
        time_weight=weights,
        time_mean=light.time_mean + params.time_offset[:, None],
        time_sigma=jnp.sqrt(light.time_variance + params.tts * params.tts),
        residual_weight=light.residual_weight,
        dark_rate=params.dark_rate,
        spe_width=params.spe_width,
        window=light.window,
        time_tau=light.time_tau,
    )
