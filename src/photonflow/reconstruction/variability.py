"""How much a fit's estimate scatters when the data fluctuate more than the likelihood
says: the sandwich covariance H^-1 J H^-1, its variability matrix J sampled from the
generator.

The likelihood treats each sensor's count as Poisson about the expected response of one
smooth track; a real (and a sampled) track's light also fluctuates coherently across
sensors (multiple scattering moves the ring's edges, knock-on electrons add light in
bursts; ``docs/reconstruction.md``). The inverse Fisher information H^-1 then
understates the scatter of the fitted track. To first order about the fit, an event's
estimate moves by -H^-1 g from the fit to data whose score (the gradient of -log L at the
fitted track) is g, so the estimate's covariance is H^-1 J H^-1 with J the covariance of
the score over events of that track (the Godambe information's inverse; it is H^-1 where
the model describes the data, J = H). ``sampled_scores`` estimates J from events that
the stochastic generator and the sampled mode simulate at the fitted track (what the
data would scatter like if the fit were the truth; a parametric bootstrap of the score,
without refitting); their mean score gives the fit's bias to the same order,
-H^-1 E[g]. Coordinates ``coordinates.LOCAL``: x, y, z m, t ns, two angles rad, ln E.
"""

from __future__ import annotations

import dataclasses
import zlib

import jax
import jax.numpy as jnp
import numpy as np

from ..generator.track import Track
from ..likelihood import dense_sensor_nll, hit_arrays
from .coordinates import fit_frame, local_from_track, track_from_local
from .minimisers import cast_track, staged_data


def score_function(predict, window, charge_threshold, overdispersion: float):
    """Jitted ``scores(point, frame, data, hit, charge, time) -> (n, 7)``: the gradients
    of the full likelihood (dark noise, first-hit times) in ``LOCAL`` coordinates at
    ``point`` (7,) about ``frame``'s axis, of n events' dense hits (``hit``, ``charge``
    p.e., ``time`` ns: (n, N) arrays), with the prediction and the rest of the event's
    ``data`` (``fit._EventData``: params, held indirect light) shared. ``predict``,
    ``window`` (ns), ``charge_threshold`` (p.e. or None) and ``overdispersion`` are those
    of the fit's likelihood (``fit.likelihood_functions``).

    The prediction is linearised once (7 tangents through the transport) and each
    event's score is its likelihood's gradient with respect to the prediction contracted
    with them: n events cost about one forward pass with 7 tangents, not n gradients.
    Written here because the fit's gradient program recomputes the prediction for every
    event.
    """

    @jax.jit
    def scores(point, frame, data, hit, charge, time):
        def prediction_at(x):
            return predict(data.params, track_from_local(frame, x), None, None,
                           emission=data.emission, arrays=data.sensors, held=data.held)

        prediction, tangent = jax.linearize(prediction_at, point)
        tangents = jax.vmap(tangent)(jnp.eye(point.shape[0], dtype=point.dtype))

        def score(hit, charge, time):
            def nll(p):
                return jnp.sum(dense_sensor_nll(p, hit, charge, time, data.dark_rate,
                                                data.spe_width, window,
                                                charge_threshold=charge_threshold,
                                                overdispersion=overdispersion))

            slopes = jax.grad(nll)(prediction)
            pairs = zip(jax.tree.leaves(tangents), jax.tree.leaves(slopes), strict=True)
            return sum(jnp.einsum("j...,...->j", t, s) for t, s in pairs)

        # lax.map, not vmap: under jaxlib 0.10's YNNPACK fusions, batched sums of SK's
        # size came back wrong for all events but the first two (the flag of
        # photonflow.xla_settings fixes them; this loop does not depend on it)
        return jax.lax.map(lambda columns: score(*columns), (hit, charge, time))

    return scores


def event_seed(event, seed: int = 0) -> int:
    """A seed (int) of the pseudo-events of ``event``: ``seed`` mixed with a checksum of
    its hits, so that the same event gives the same pseudo-events in any run, order or
    worker."""
    checksum = 0
    for name in ("sensor_ids", "charge", "time"):
        checksum = zlib.crc32(np.ascontiguousarray(getattr(event, name)).tobytes(), checksum)
    return (checksum ^ (int(seed) * 0x9E3779B1)) % (2**31 - 1)


def sampled_scores(functions, detector, params, data, track: Track, frame, *,
                   n_events: int, seed: int, config) -> np.ndarray:
    """(n_events, 7) scores (gradients of -log L in ``LOCAL`` coordinates, float64) at
    ``track`` of events simulated at ``track`` by the generator and the sampled mode with
    ``params`` and ``config`` (the readout of the fit's likelihood), read with the fit's
    ``data`` (its emission model and held indirect light at ``track``) about ``frame``
    (``coordinates.fit_frame`` at the track's direction)."""
    from ..transport.pseudo_data import sample_events

    dtype = data.charge.dtype
    with jax.enable_x64(False):  # the sampled mode's own precision, as for any event
        events = list(sample_events(detector, params, track, seed, n_events,
                                    config=config))
    dense = [hit_arrays(event, detector.n_sensors, dtype) for event in events]
    hit, charge, time = (jnp.stack(column) for column in zip(*dense, strict=True))
    point = local_from_track(track, dtype)
    return np.asarray(functions.scores(point, frame, data, hit, charge, time), np.float64)


def sandwich_covariance(covariance, scores) -> np.ndarray:
    """(7, 7) H^-1 J H^-1: ``covariance`` (7, 7) the inverse Fisher information H^-1,
    J the covariance of ``scores`` (n, 7) (n > 7 rows); units of ``LOCAL`` squared. NaN
    where ``covariance`` is."""
    covariance = np.asarray(covariance, np.float64)
    variability = np.cov(np.asarray(scores, np.float64), rowvar=False)
    return covariance @ variability @ covariance


def score_bias(covariance, scores) -> np.ndarray:
    """(7,) the fit's bias to first order, -H^-1 E[g], in ``LOCAL`` coordinates:
    ``covariance`` the inverse Fisher information, ``scores`` (n, 7) of events simulated
    at the fitted track."""
    return -np.asarray(covariance, np.float64) @ np.mean(np.asarray(scores), axis=0)


def with_variability(functions, detector, params, data, event, result, *, config,
                     settings):
    """``result`` (a converged or unconverged fit, not a failure) with its covariance the
    sandwich H^-1 J H^-1 (``fisher_covariance`` keeps H^-1) and ``bias`` the first-order
    bias -H^-1 E[g] (``LOCAL``), J and E[g] from ``settings.variability_events`` events
    simulated at the fitted track (``sampled_scores``; seeds from ``event_seed`` of
    ``event``); with ``settings.bias_correction`` the reported track is the fit less the
    bias (where that track lies inside the detector and the emission model's energy
    range; otherwise the fit as it is). ``data`` is the event's (``fit.event_data``),
    ``config`` the fit's ``TransportConfig``. Unchanged where H^-1 is not finite."""
    covariance = np.asarray(result.covariance, np.float64)
    if not np.all(np.isfinite(covariance)):
        return dataclasses.replace(result, fisher_covariance=covariance)
    dtype = data.charge.dtype
    model = functions.emission(result.particle)
    track = cast_track(Track(result.particle, result.position, result.direction,
                             result.energy, result.time), dtype)
    data = staged_data(functions, dataclasses.replace(data, emission=model), track,
                       settings)
    frame = fit_frame(detector.shape, track.direction, model.energy_range, result.particle,
                      0.0, dtype)
    scores = sampled_scores(functions, detector, params, data, track, frame,
                            n_events=settings.variability_events,
                            seed=event_seed(event, settings.variability_seed),
                            config=config)
    bias = score_bias(covariance, scores)
    result = dataclasses.replace(result, covariance=sandwich_covariance(covariance, scores),
                                 fisher_covariance=covariance, bias=bias)
    if not settings.bias_correction or not np.all(np.isfinite(bias)):
        return result
    local = np.asarray(local_from_track(track, dtype), np.float64) - bias
    corrected = track_from_local(frame, jnp.asarray(local, dtype))
    position = np.asarray(corrected.position, np.float64)
    energy = float(corrected.energy)
    low, high = (float(x) for x in model.energy_range)
    if float(detector.shape.distance_to_wall(position)) <= 0 or not low < energy < high:
        return result
    return dataclasses.replace(result, position=position, time=float(corrected.time),
                               direction=np.asarray(corrected.direction, np.float64),
                               energy=energy)
