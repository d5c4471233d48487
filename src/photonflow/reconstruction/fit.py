"""Event reconstruction: the track that maximises the likelihood of an event's hits.

``reconstruct`` seeds the fit from the hits alone (``seeding``), places a few starts
behind the point-source vertex along the seeded direction and its opposite (the particle
outruns its light) and along directions spread over the sphere, evaluates the charge-
only likelihood at each and fits the best ``RecoSettings.fits`` of them, and the next
likeliest (at most ``restarts``) while none has converged; the best converged minimum is
kept. The likelihood is the full charge + first-hit-time likelihood with dark noise
(``likelihood.dense_sensor_nll``) of the expected response of the track
(``expected_function``), in the free coordinates of ``coordinates`` (the vertex stays
inside the detector by the map). Two minimisers (``minimisers``):

- ``method="gradient"``: L-BFGS (``photonflow.lbfgs``: an Armijo line search driven from
  the host over one jitted value-and-gradient program) on exact gradients, its initial
  inverse Hessian the inverse of the sensors' summed score outer products;
- ``method="minuit"``: MIGRAD (iminuit) with numerical derivatives, errors by HESSE:
  the conventional fit of the same likelihood from the same starts.

The indirect light's rays are fixed by a reference track (``expected``'s
``reference``): each fit starts with its start as the reference, and when the fitted
track has moved from it by more than ``RecoSettings.refresh_distance`` (m) or
``refresh_angle`` (degrees), the reference and the direction axis of the coordinates
move to the fitted track and the fit continues; its stages hold the indirect light
frozen at their reference (``minimisers.fit_stages``). H^-1,
the inverse of the Hessian of the negative log-likelihood (the observed Fisher
information) at the fitted track in ``coordinates.LOCAL``, comes from central
differences of exact gradients (``minimisers.local_hessian``) for the gradient fit and
from HESSE (transformed to the same coordinates) for MINUIT. The reported covariance is
the sandwich H^-1 J H^-1 with J from events simulated at the best fit, and the reported
track that fit less its first-order bias (``variability``; ``RecoSettings``). Lengths m,
times ns, energies MeV.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import time as clock
from weakref import WeakKeyDictionary

import jax
import jax.numpy as jnp
import numpy as np

from ..constants import SPEED_OF_LIGHT
from ..emission import emission_model
from ..errors import ConfigError
from ..generator.track import Track
from ..geometry.sensor_arrays import sensors_for
from ..likelihood import dark_expectation, dense_sensor_nll, hit_arrays
from ..numerics import default_float_dtype
from ..threads import parallel_map
from ..transport.expected import expected_function, held_indirect_function
from ..transport.optics import TransportConfig
from ..transport.tracks import detector_medium
from .coordinates import (
    fit_frame,
    free_from_track,
    free_from_vertex,
    track_from_free,
    track_from_local,
    vertex_from_free,
)
from .minimisers import cast_track, minimise_gradient, minimise_minuit, staged_data
from .result import RecoResult
from .seeding import energy_from_charge, padded_hits, point_source_seed
from .settings import RecoSettings
from .variability import score_function, with_variability

#: Particle hypotheses a fit takes; "auto" fits both and keeps the likelier.
PARTICLES = ("mu-", "e-", "auto")
METHODS = ("gradient", "minuit")
#: Distances behind the point-source vertex along the seeded direction (and along the
#: opposite direction, for an event whose seeded direction is reversed) of the starts,
#: in units of the light's extent at the seeded energy (the particle outruns its light:
#: the point-source vertex of a 1 GeV muon in SK lies 2-4 m ahead of its start).
START_SHARES = (0.0, 0.35, 0.7)
#: ... of the starts in the ``RecoSettings.scan_directions`` directions spread over the
#: sphere from the point-source vertex (the seeded direction can be far off: a muon
#: heading at a near wall puts the point-source vertex at the wall, its track's end) ...
SCAN_SHARES = (0.35, 0.7, 1.0)
#: ... and from the detector's centre (the point-source vertex of a small detector can
#: fall near the wall, among the hits); also where the seed's energy is predicted.
SCAN_SHARE = 0.35
#: The start whose held indirect light all starts are ranked with: along the seeded
#: direction, ``START_SHARES[1]`` behind the point-source vertex.
RANKING_START = 1
#: Energy (MeV) of the first prediction that seeds the energy from the total charge.
REFERENCE_ENERGY = {"mu-": 1000.0, "e-": 500.0}
#: Predictions of the seed's total charge, each at the last energy estimate.
ENERGY_PASSES = 3


def sphere_directions(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    k = np.arange(count) + 0.5
    cos = 1.0 - 2.0 * k / max(count, 1)
    azimuth = np.pi * (1.0 + 5.0**0.5) * k
    sine = np.sqrt(1.0 - cos * cos)
    return np.stack([sine * np.cos(azimuth), sine * np.sin(azimuth), cos], axis=-1)


def reconstruct(detector, params, event, particle: str = "mu-", method: str = "gradient",
                *, config: TransportConfig | None = None,
                settings: RecoSettings | None = None,
                start: Track | None = None) -> RecoResult:
    """Reconstruct one event (module docstring): the maximum-likelihood track of
    ``particle`` ("mu-", "e-" or "auto": both, the likelier kept, with their
    log-likelihood ratio) by ``method`` ("gradient" or "minuit").

    Args:
        detector: the ``Detector``; params: its ``Params``; event: an ``Event``.
        config: transport settings of the prediction (default ``TransportConfig()``;
            its window and charge threshold are the event's readout's).
        settings: ``RecoSettings`` (default ``RecoSettings()``).
        start: None (seed from the hits), or the one ``Track`` to start the fit from
            (a refit, or a comparison of minimisers from one point); its particle is
            the fit's.

    Returns:
        A ``RecoResult``; an event that cannot be fitted (no hits, non-finite hits,
        sensor ids out of range, a likelihood that is not finite) gives a result with
        ``failure`` set, not an exception.

    Raises:
        ConfigError: an unknown ``particle`` or ``method`` (one line).
    """
    began = clock.perf_counter()
    if particle not in PARTICLES:
        raise ConfigError(f"particle = {particle!r}: must be one of {', '.join(PARTICLES)}")
    if method not in METHODS:
        raise ConfigError(f"method = {method!r}: must be one of {', '.join(METHODS)}")
    if start is not None:
        particle = start.particle
    settings = RecoSettings() if settings is None else settings
    config = TransportConfig() if config is None else config
    problem = event_problem(event, detector.n_sensors)
    if problem is not None:
        return RecoResult.failed(problem, particle, method, clock.perf_counter() - began)
    precision = "float64" if method == "minuit" else None
    with jax.enable_x64(True) if method == "minuit" else contextlib.nullcontext():
        dtype = jnp.dtype(settings.dtype or precision or default_float_dtype())
        functions = likelihood_functions(detector, dtype, config, settings.overdispersion)
        data = event_data(detector, params, event, dtype, functions)
        seed = _seed(detector, params, event, dtype) if start is None else start
        hypotheses = ("mu-", "e-") if particle == "auto" else (particle,)
        results = {}
        for hypothesis in hypotheses:
            results[hypothesis] = _fit_particle(functions, detector, params, data, seed,
                                                hypothesis, method, settings)
        fitted = [r for r in results.values() if r.failure is None]
        best = min(fitted, key=lambda r: r.nll) if fitted else results[hypotheses[0]]
        if best.failure is None:
            best = with_variability(functions, detector, params, data, event, best,
                                    config=config, settings=settings)
    ratio = None
    if particle == "auto" and len(fitted) == 2:
        ratio = results["mu-"].nll - results["e-"].nll
    return dataclasses.replace(best, seconds=clock.perf_counter() - began,
                               log_likelihood_ratio=ratio,
                               iterations=sum(r.iterations for r in results.values()),
                               evaluations=sum(r.evaluations for r in results.values()))


def event_problem(event, n_sensors: int) -> str | None:
    """Why ``event`` cannot be reconstructed (one line), or None."""
    ids = np.asarray(event.sensor_ids)
    if ids.size == 0:
        return "no hits"
    if ids.min() < 0 or ids.max() >= n_sensors:
        bad = int(ids[(ids < 0) | (ids >= n_sensors)][0])
        return f"sensor id {bad} out of range (the detector has {n_sensors} sensors)"
    for name in ("charge", "time"):
        values = np.asarray(getattr(event, name), np.float64)
        if not np.all(np.isfinite(values)):
            return f"non-finite hit {name}"
    if np.unique(ids).size < 2:
        return "all hits in one sensor"
    return None


@dataclasses.dataclass(frozen=True)
class _Functions:
    """The jitted pieces of one (detector, dtype, config): the likelihood of a track in
    free coordinates, ``value(free, frame, reference, data)``, and its value and gradient
    in free or ``LOCAL`` coordinates, ``value_and_grad(x, local, frame, reference, data,
    time_weight)`` (``local``: a bool array, traced: one program for both), each with
    the indirect light by rays from ``reference`` or held (``data.held``); the (7, 7)
    sum over sensors of the outer products of their terms' gradients in free
    coordinates, ``score_information(free, frame, reference, data, time_weight)``
    (units of -log L squared per unit of the coordinates squared); the held indirect
    light of a track, ``hold(track, data, slopes=True)``; the scores of many events at
    one point, ``scores`` (``variability.score_function``)."""

    value: object
    value_and_grad: object
    score_information: object
    scores: object
    hold: object
    total_charge: object
    window: tuple[float, float]
    emission: object
    sensors: object


@dataclasses.dataclass(frozen=True)
class _EventData:
    """The event as dense per-sensor arrays and the response it is read with, and the
    large arrays of the prediction (the emission model of the hypothesis fitted, the
    detector's ``Sensors``): arguments of the jitted functions, not constants of their
    programs (``expected_function``); ``held``: None (the indirect light by rays from
    the reference track), or the indirect light held at the reference
    (``held_indirect_function``; the prediction then costs the direct light's alone)."""

    hit: jax.Array
    charge: jax.Array
    time: jax.Array
    params: object
    dark_rate: jax.Array
    spe_width: jax.Array
    sensors: object
    emission: object = None
    held: object = None


jax.tree_util.register_dataclass(
    _EventData, data_fields=["hit", "charge", "time", "params", "dark_rate", "spe_width",
                             "sensors", "emission", "held"],
    meta_fields=[])

#: Jitted functions per detector object, keyed by (dtype, config, overdispersion).
_FUNCTIONS: WeakKeyDictionary = WeakKeyDictionary()


def likelihood_functions(detector, dtype, config: TransportConfig,
                         overdispersion: float = 0.0) -> _Functions:
    """The cached ``_Functions`` (the fit's jitted likelihood pieces) of ``detector`` for
    a float ``dtype``, a ``TransportConfig`` and the likelihood's ``overdispersion``."""
    cached = _FUNCTIONS.setdefault(detector, {})
    key = (jnp.dtype(dtype).name, config, overdispersion)
    if key not in cached:
        cached[key] = _build_functions(detector, dtype, config, overdispersion)
    return cached[key]


def _build_functions(detector, dtype, config: TransportConfig,
                     overdispersion: float = 0.0) -> _Functions:
    predict = expected_function(detector, dtype, config=config)
    window = tuple(float(x) for x in config.window)
    threshold = config.charge_threshold if config.charge_threshold > 0 else None

    def sensor_terms(track, reference, data, time_weight=1.0):
        prediction = predict(data.params, track, None, reference, emission=data.emission,
                             arrays=data.sensors, held=data.held)
        weight = jnp.asarray(time_weight, data.charge.dtype)
        return dense_sensor_nll(prediction, data.hit, data.charge, data.time,
                                data.dark_rate, data.spe_width, window,
                                charge_threshold=threshold, time_weight=weight,
                                overdispersion=overdispersion)

    def track_nll(track, reference, data, time_weight=1.0):
        return jnp.sum(sensor_terms(track, reference, data, time_weight))

    def free_nll(free, frame, reference, data, time_weight=1.0):
        return track_nll(track_from_free(frame, free), reference, data, time_weight)

    def coordinate_nll(x, local, frame, reference, data, time_weight):
        # one program for the fit (free coordinates) and the Hessian (LOCAL ones): the
        # cheap coordinate maps are the two branches, the likelihood is shared
        track = jax.lax.cond(local, track_from_local, track_from_free, frame, x)
        return track_nll(track, reference, data, time_weight)

    @jax.jit
    def score_information(x, frame, reference, data, time_weight):
        # sum over sensors of the outer products of their terms' gradients in free
        # coordinates (forward mode: 7 tangents through the prediction)
        def terms(x):
            return sensor_terms(track_from_free(frame, x), reference, data, time_weight)

        scores = jax.jacfwd(terms)(x)
        return scores.T @ scores

    @jax.jit
    def total_charge(track, data):
        return jnp.sum(predict(data.params, track, emission=data.emission,
                               arrays=data.sensors).charge)

    hold_light = held_indirect_function(detector, dtype, config=config)

    @functools.partial(jax.jit, static_argnames="slopes")
    def hold(track, data, slopes=True):
        return hold_light(data.params, track, emission=data.emission, arrays=data.sensors,
                          slopes=slopes)

    medium = detector_medium(detector)
    return _Functions(value=jax.jit(free_nll),
                      value_and_grad=jax.jit(jax.value_and_grad(coordinate_nll)),
                      score_information=score_information,
                      scores=score_function(predict, window, threshold, overdispersion),
                      hold=lambda track, data, slopes=True: hold(
                          track, dataclasses.replace(data, held=None), slopes),
                      total_charge=total_charge, window=window,
                      emission=lambda particle: emission_model(particle, medium, dtype,
                                                               config.emission_model),
                      sensors=sensors_for(detector, dtype))


def event_data(detector, params, event, dtype, functions) -> _EventData:
    """``event``'s hits as the dense per-sensor arrays of ``_EventData`` (``dtype``), with
    ``params`` and the detector's sensors from ``functions`` (``likelihood_functions``);
    its emission model is set per hypothesis."""
    cast = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    hit, charge, time = hit_arrays(event, detector.n_sensors, dtype)
    return _EventData(hit=hit, charge=charge, time=time, params=jax.tree.map(cast, params),
                      dark_rate=cast(params.dark_rate), spe_width=cast(params.spe_width),
                      sensors=functions.sensors)


def _seed(detector, params, event, dtype):
    """The point-source pre-fit of the event's hit sensors (``seeding``)."""
    hit, charge, time = (np.asarray(x) for x in hit_arrays(event, detector.n_sensors,
                                                           np.float64))
    index = np.flatnonzero(hit)
    positions = np.asarray(detector.sensor_positions, np.float64)[index]
    lows, highs = positions.min(axis=0), positions.max(axis=0)
    group_index = float(np.asarray(params.group_index))
    cast = lambda x: np.asarray(x, dtype)  # noqa: E731  (no compilation per shape)
    hits = padded_hits(positions, time[index], charge[index])
    return point_source_seed(*(cast(x) for x in hits), cast(lows), cast(highs),
                             cast(group_index))


def _fit_particle(functions, detector, params, data, seed, particle, method,
                  settings) -> RecoResult:
    """The best fit of ``particle`` over the starts (``seed``: a ``seeding.Seed``, or a
    ``Track``: the only start)."""
    began = clock.perf_counter()
    model = functions.emission(particle)  # the configured model (spline or SIREN)
    data = dataclasses.replace(data, emission=model)
    minimise = minimise_gradient if method == "gradient" else minimise_minuit

    def fit_from(start):
        fit = minimise(functions, detector, model, data, start, settings)
        # a fit at an end of the model's energy range found no minimum there
        return dataclasses.replace(fit, converged=fit.converged and not at_energy_edge(
            fit.energy, model.energy_range))

    if isinstance(seed, Track):
        return dataclasses.replace(fit_from(seed), seconds=clock.perf_counter() - began)
    dtype = data.charge.dtype
    direction = np.asarray(seed.direction, np.float64)
    vertex = np.asarray(seed.vertex, np.float64)
    frame = fit_frame(detector.shape, direction, model.energy_range, particle,
                      settings.margin, dtype)
    energy = seed_energy(functions, detector, data, frame, seed, particle)
    extent = float(model.at(energy).extent)
    candidates = [(axis, share) for axis in (direction, -direction) for share in START_SHARES]
    candidates = [(vertex, axis, share) for axis, share in candidates]
    scan = sphere_directions(settings.scan_directions)
    candidates += [(vertex, axis, share) for axis in scan for share in SCAN_SHARES]
    candidates += [(np.zeros(3), axis, SCAN_SHARE) for axis in scan]
    tracks = []
    for origin, axis, share in candidates:
        offset = share * extent
        tracks.append(Track(particle, frame_inside(frame, origin - offset * axis), axis,
                            energy, float(seed.time) - offset / SPEED_OF_LIGHT))
    # every start sees the indirect light held at the seeded direction's middle start (a
    # smooth background of the right size: the same likeliest start as each start's own
    # rays in the benchmark's events, at a quarter of the cost)
    ranking = staged_data(functions, data, cast_track(tracks[RANKING_START], dtype),
                          settings, slopes=False)

    def start_value(start):
        cast = cast_track(start, dtype)
        turned = fit_frame(detector.shape, start.direction, model.energy_range, particle,
                           settings.margin, dtype)
        # ranked by the charge-only likelihood, as the fit's first stage: the seed's time
        # is off for a start far from the point-source vertex
        return float(functions.value(_free_from_track(turned, cast), turned, cast, ranking,
                                     jnp.zeros((), dtype)))

    starts = list(zip(parallel_map(start_value, tracks, settings.threads), tracks,
                      strict=True))
    starts.sort(key=lambda item: item[0] if math.isfinite(item[0]) else math.inf)
    fits = []
    for rank, (_, start) in enumerate(starts):
        if rank >= settings.fits and (rank >= settings.fits + settings.restarts
                                      or any(f.converged for f in fits)):
            break
        fits.append(fit_from(start))
    good = [f for f in fits if f.failure is None]
    # a converged fit before any that stopped short of a minimum, then the likeliest
    best = min(good, key=lambda f: (not f.converged, f.nll)) if good else fits[0]
    return dataclasses.replace(best, seconds=clock.perf_counter() - began,
                               iterations=sum(f.iterations for f in fits),
                               evaluations=sum(f.evaluations for f in fits) + len(starts) + 1)


#: A fit whose energy ends within this fraction of an end of the emission model's
#: energy range has not found a minimum (a track leaving the detector, whose light
#: bounds its energy from below only, runs to the model's highest energy).
ENERGY_EDGE = 0.01


def at_energy_edge(energy: float, energy_range) -> bool:
    """Whether ``energy`` (MeV) lies within ``ENERGY_EDGE`` (relative) of an end of
    ``energy_range`` (MeV, lowest and highest), beyond it, or is NaN."""
    low, high = (float(x) for x in energy_range)
    return not low * (1.0 + ENERGY_EDGE) < float(energy) < high * (1.0 - ENERGY_EDGE)


def seed_energy(functions, detector, data, frame, seed, particle: str) -> float:
    """Kinetic energy (MeV) of ``particle`` seeded from the event's total charge less the
    dark noise's (``data``, with its emission model): ``energy_from_charge`` from a
    prediction at ``REFERENCE_ENERGY``, then ``ENERGY_PASSES - 1`` times from one at the
    last estimate (the charge of a track that leaves the detector grows slower than its
    yield), each of a track along the seeded direction from the middle start behind
    the point-source vertex (``SCAN_SHARE``; ``frame`` keeps it inside)."""
    model, dtype = data.emission, data.charge.dtype
    direction = np.asarray(seed.direction, np.float64)
    vertex = np.asarray(seed.vertex, np.float64)
    observed = float(jnp.sum(data.charge)) - _dark_total(detector, data, functions)
    energy = REFERENCE_ENERGY[particle]
    for _ in range(ENERGY_PASSES):
        behind = SCAN_SHARE * float(model.at(energy).extent)
        probe = Track(particle, frame_inside(frame, vertex - behind * direction), direction,
                      energy, float(seed.time) - behind / SPEED_OF_LIGHT)
        predicted = float(functions.total_charge(cast_track(probe, dtype), data))
        energy = energy_from_charge(model, observed, predicted, energy)
    return energy


def frame_inside(frame, vertex) -> np.ndarray:
    """``vertex`` (m) moved onto the fit's inner volume if it lies outside it."""
    vertex = np.asarray(vertex, frame.inner.dtype)
    return np.asarray(_onto_inner(frame, vertex), np.float64)


# compiled once: the starts call these ~60 times per event (eagerly, ~5 ms each)
_onto_inner = jax.jit(lambda frame, vertex: vertex_from_free(frame,
                                                             free_from_vertex(frame, vertex)))
_free_from_track = jax.jit(free_from_track)


def _dark_total(detector, data, functions) -> float:
    """Expected dark-noise charge of the whole detector in the readout window, p.e."""
    return float(detector.n_sensors * dark_expectation(data.params, functions.window))
