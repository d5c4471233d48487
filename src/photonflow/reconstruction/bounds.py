"""The Cramér-Rao bound of a reconstruction: the covariance that the likelihood's
curvature at the **true** track allows, against which a fit's resolution is judged.

``cramer_rao_covariance`` is the inverse of the observed Fisher information (the
Hessian of the event's negative log-likelihood) at a known track, computed as the fit
computes its own covariance at its minimum (``minimisers.local_hessian``: differences of
exact gradients over one sigma, the indirect light held at the track), in the
coordinates ``coordinates.LOCAL``. Averaged over events it estimates the inverse of the
expected Fisher information; where the model describes the data, an unbiased fit's
errors scatter as this covariance says. Lengths m, times ns, energies MeV.
"""

from __future__ import annotations

import contextlib
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..generator.track import Track
from ..numerics import default_float_dtype
from ..transport.optics import TransportConfig
from .fit import event_data, event_problem, likelihood_functions
from .minimisers import cast_track, covariance_from_hessian, hessian_at, staged_data
from .settings import RecoSettings


def cramer_rao_covariance(detector, params, event, track: Track, *,
                          config: TransportConfig | None = None,
                          settings: RecoSettings | None = None) -> np.ndarray:
    """(7, 7) inverse of the Hessian of the negative log-likelihood of ``event``'s hits
    at ``track`` (its particle the hypothesis), in ``LOCAL`` coordinates (x, y, z m, t
    ns, two angles about the track's direction rad, ln E); ``covariance_errors`` gives
    its 1-sigma errors. All NaN where the Hessian is not positive definite (the
    likelihood does not curve upwards about the track in every direction), or where the
    event cannot be fitted (``fit.event_problem``). ``config`` and ``settings`` as
    ``reconstruct``'s (their dtype, overdispersion, held indirect light and threads)."""
    settings = RecoSettings() if settings is None else settings
    config = TransportConfig() if config is None else config
    if event_problem(event, detector.n_sensors) is not None:
        return np.full((7, 7), np.nan)
    with jax.enable_x64(True) if settings.dtype == "float64" else contextlib.nullcontext():
        dtype = jnp.dtype(settings.dtype or default_float_dtype())
        functions = likelihood_functions(detector, dtype, config, settings.overdispersion)
        model = functions.emission(track.particle)
        data = dataclasses.replace(event_data(detector, params, event, dtype, functions),
                                   emission=model)
        data = staged_data(functions, data, cast_track(track, dtype), settings)
        hessian, _, _ = hessian_at(functions, detector, model, data, track, settings.threads)
    return covariance_from_hessian(hessian)
