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
import warnings
import zlib

import jax
import jax.numpy as jnp
import numpy as np

from ..generator.track import Track
from ..likelihood import dense_sensor_nll, hit_arrays
from ..threads import host_cores
from ..transport.pseudo_data import sample_together
from .coordinates import fit_frame, local_from_track, track_from_local
from .minimisers import cast_track, staged_data
from .settings import MIN_VARIABILITY_EVENTS


def score_function(predict, window, charge_threshold, overdispersion: float):
    """Jitted ``scores(point, frame, data, hit, charge, time) -> (n, 7)``: the gradients
    of the full likelihood (dark noise, first-hit times) in ``LOCAL`` coordinates (per m,
    per ns, per rad, per unit of ln E) at
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

        return jax.vmap(score)(hit, charge, time)

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
                   n_events: int, seed: int, config, threads: int | None = None) -> np.ndarray:
    """(n_events, 7) scores (gradients of -log L in ``LOCAL`` coordinates: per m, per ns,
    per rad, per unit of ln E; float64) at
    ``track`` of events simulated at ``track`` by the generator (all together:
    ``pseudo_data.sample_together``) and the sampled mode with
    ``params`` and ``config`` (the readout of the fit's likelihood), read with the fit's
    ``data`` (its emission model and held indirect light at ``track``) about ``frame``
    (``coordinates.fit_frame`` at the track's direction); the events simulated on
    ``threads`` threads (None: one per core; the same events)."""
    dtype = data.charge.dtype
    threads = host_cores() if threads is None else threads
    with jax.enable_x64(False):  # the sampled mode's own precision, as for any event
        events = sample_together(detector, params, [track] * n_events, seed, config=config,
                                 threads=threads)
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
    """``result`` (a fit, converged or not; not a failure) with ``fisher_covariance`` its
    H^-1 and, where ``settings.variability_events`` > 0 and H^-1 is finite, its
    covariance the sandwich H^-1 J H^-1 and ``bias`` the first-order bias -H^-1 E[g]
    (``LOCAL``), J and E[g] from that many events simulated at the fitted track
    (``sampled_scores``; seeds from ``event_seed`` of ``event``).

    With ``settings.bias_correction``, a converged fit is reported less ``correction``:
    the bias in each coordinate where it exceeds twice the standard error of the mean
    score's (sqrt of the sandwich's variance over the number of events; elsewhere 0),
    where the corrected vertex stays ``settings.margin`` (m) inside the detector and its
    energy (MeV) inside the emission model's range. The covariance then adds the
    correction's own variance. ``data`` is the event's (``fit.event_data``), ``config``
    the fit's ``TransportConfig``. A fit is never lost to this step: where the events
    cannot be simulated (a ``RuntimeWarning`` says why) or fewer than
    ``MIN_VARIABILITY_EVENTS`` give finite scores, H^-1 is reported and ``bias`` stays
    None."""
    covariance = np.asarray(result.covariance, np.float64)
    result = dataclasses.replace(result, fisher_covariance=covariance)
    if not settings.variability_events or not np.all(np.isfinite(covariance)):
        return result
    dtype = data.charge.dtype
    model = functions.emission(result.particle)
    track = cast_track(Track(result.particle, result.position, result.direction,
                             result.energy, result.time), dtype)
    frame = fit_frame(detector.shape, track.direction, model.energy_range, result.particle,
                      0.0, dtype)
    try:
        data = staged_data(functions, dataclasses.replace(data, emission=model), track,
                           settings)
        scores = sampled_scores(functions, detector, params, data, track, frame,
                                n_events=settings.variability_events,
                                seed=event_seed(event, settings.variability_seed),
                                config=config, threads=settings.threads)
    except Exception as error:  # noqa: BLE001 - e.g. a vertex rounded onto the wall
        warnings.warn(f"no simulated events at the fit ({error}); its covariance is"
                      f" H^-1", RuntimeWarning, stacklevel=2)
        return result  # the fit is kept
    scores = scores[np.all(np.isfinite(scores), axis=1)]
    if len(scores) < MIN_VARIABILITY_EVENTS:
        return result
    bias = score_bias(covariance, scores)
    sandwich = sandwich_covariance(covariance, scores)
    result = dataclasses.replace(result, covariance=sandwich, bias=bias,
                                 correction=np.zeros_like(bias))
    if not settings.bias_correction or not result.converged:
        return result
    mean_error = np.sqrt(np.diag(sandwich) / len(scores))
    correction = np.where(np.abs(bias) > 2.0 * mean_error, bias, 0.0)
    if not np.any(correction):
        return result
    local = np.asarray(local_from_track(track, dtype), np.float64) - correction
    corrected = track_from_local(frame, jnp.asarray(local, dtype))
    position = np.asarray(corrected.position, np.float64)
    energy = float(corrected.energy)
    low, high = (float(x) for x in model.energy_range)
    if (float(detector.shape.distance_to_wall(position)) <= settings.margin
            or not low < energy < high):
        return result
    applied = np.diag((correction != 0).astype(np.float64))
    return dataclasses.replace(
        result, position=position, time=float(corrected.time),
        direction=np.asarray(corrected.direction, np.float64), energy=energy,
        covariance=sandwich + applied @ sandwich @ applied / len(scores),
        correction=correction)
