"""Pseudo-data: Monte Carlo events of calibration sources and particle tracks.

Photon transport (``sampled.py``; a track's photons from ``tracks.py``) followed by the
sensor response (``response.photoelectrons_to_event``). Event i of a seed uses the key
``fold_in(PRNGKey(seed), i)``, so the same seed gives the same events in the same order.
Positions m, times ns, charges p.e.
"""

from __future__ import annotations

import itertools

import jax
import numpy as np

from ..cluster import check_count
from ..errors import ConfigError, format_value
from ..generator import GeneratorSettings, Track
from ..geometry.detector import Detector
from ..io.events import Event, Truth
from ..params import Params, validate_params
from ..progress import with_progress
from ..response.hits import photoelectrons_to_event
from ..sources import DiffuserSource, IsotropicSource, LaserSource, check_source
from ..threads import ordered_map
from .optics import DEFAULT_CONFIG, TransportConfig, check_config
from .sampled import (
    check_seed,
    grid_for,
    photon_count,
    sample_photon_bundle,
    sample_photons,
)
from .tracks import (
    check_track,
    spectral_params,
    track_light,
    track_photons,
    track_photons_together,
    track_truth,
)

_SOURCE_KINDS = {IsotropicSource: "isotropic", LaserSource: "laser", DiffuserSource: "diffuser"}


def source_truth(source, seed: int) -> Truth:
    """The ``Truth`` of a calibration-source event: kind, position (m), direction (unit;
    NaN for the isotropic source), time (ns) and the seed."""
    direction = getattr(source, "direction", None)
    return Truth(
        source_kind=_SOURCE_KINDS.get(type(source), type(source).__name__),
        position=np.asarray(source.position, dtype=np.float64),
        direction=(
            np.full(3, np.nan) if direction is None else np.asarray(direction, dtype=np.float64)
        ),
        time=float(np.asarray(source.time)),
        seed=int(seed),
    )


def event_keys(seed: int, index: int) -> tuple[jax.Array, jax.Array]:
    """(transport key, response key) of event ``index`` of the run ``seed``: the two
    halves of ``jax.random.split(jax.random.fold_in(jax.random.PRNGKey(seed), index))``,
    computed in one compiled program (eagerly, each of those steps compiles its own)."""
    if jax.config.jax_enable_x64:
        seed_argument = np.uint64(seed)
    else:
        seed_argument = np.uint32(seed % 2**32)  # what PRNGKey keeps of it in 32-bit mode
    return _event_keys(seed_argument, np.uint32(index))


@jax.jit
def _event_keys(seed, index):
    """``event_keys`` on unsigned integer arrays."""
    keys = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(seed), index))
    return keys[0], keys[1]


def sample_track_tally(detector: Detector, params: Params, track: Track, key, seed: int,
                       index: int, light, *, config: TransportConfig = DEFAULT_CONFIG,
                       grid=None):
    """The photoelectrons of event ``index`` of ``seed`` of a particle ``track``: its
    photons from the generator (``tracks.track_photons``) followed through the detector
    with ``key`` (``bundle_tally``; ``light``: ``tracks.track_light`` of the detector).
    Returns the ``PhotonTally`` (p.e. per sensor, photon times ns, before the charge
    response)."""
    return bundle_tally(detector, params, track, track_photons(detector, track, seed, index, light),
                        key, light, config=config, grid=grid)


def bundle_tally(detector: Detector, params: Params, track: Track, bundle, key, light, *,
                 config: TransportConfig = DEFAULT_CONFIG, grid=None):
    """The photoelectrons of a track's generated photons ``bundle`` (a ``PhotonBundle``
    of ``tracks.track_photons``), followed through the detector with ``key``
    (``sampled.sample_photon_bundle``, the QE raised by ``tracks.spectral_params``).
    Returns the ``PhotonTally``."""
    return sample_photon_bundle(detector, spectral_params(params, light), bundle, key,
                                source_time=track.time, config=config, grid=grid)


def _event(detector, params, source, seed, index, config, grid, light) -> Event:
    """Event ``index`` of ``seed``: transport and response keys split from
    ``fold_in(PRNGKey(seed), index)``; a track's photons from ``track_photons``."""
    if isinstance(source, Track):
        bundle = track_photons(detector, source, seed, index, light)
        return _track_event(detector, params, source, bundle, seed, index, config, grid, light)
    transport_key, response_key = event_keys(seed, index)
    tally = sample_photons(detector, params, source, transport_key, config=config, grid=grid)
    return photoelectrons_to_event(tally, params, response_key, config=config,
                                   truth=source_truth(source, seed))


def _track_event(detector, params, track, bundle, seed, index, config, grid, light) -> Event:
    """Event ``index`` of ``seed`` of ``track`` from its generated photons ``bundle``:
    the keys of ``_event``."""
    transport_key, response_key = event_keys(seed, index)
    tally = bundle_tally(detector, params, track, bundle, transport_key, light, config=config,
                         grid=grid)
    return photoelectrons_to_event(tally, params, response_key, config=config,
                                   truth=track_truth(track, seed))


def _check_any_source(source, detector: Detector) -> None:
    """``check_track`` for a track, ``check_source`` and ``photon_count`` otherwise."""
    if isinstance(source, Track):
        check_track(source, detector)
    else:
        check_source(source, detector)
        photon_count(source)


def _prepare(detector, params, sources, seed, config, medium, generator):
    """Validate everything once; (seed, sensor grid of a walled detector, TrackLight)."""
    seed = check_seed(seed)
    check_config(config)
    validate_params(params, detector.n_sensors)
    for source in sources:
        _check_any_source(source, detector)
    light = track_light(detector, medium, generator)
    return seed, grid_for(detector, None), light


def sample(
    detector: Detector,
    params: Params,
    source,
    seed: int,
    *,
    config: TransportConfig = DEFAULT_CONFIG,
    medium: str | None = None,
    generator: GeneratorSettings | None = None,
) -> Event:
    """One Monte Carlo event (pseudo-data) of a calibration source or a particle track.

    A calibration source emits from its point (``sample_photons``); a ``Track`` is
    generated (``photonflow.generate`` in ``medium``, default the detector preset's,
    with ``generator`` settings) and its photons transported (``track_photons``,
    ``sample_photon_bundle``; docs/transport.md, "Particle tracks in sampled mode").
    Then the sensor response (``photoelectrons_to_event``: transit-time spread,
    single-p.e. charges, dark noise, readout window from the source or track time,
    threshold). Positions m, times ns, charges p.e. The same seed gives the same event;
    ``sample(..., seed)`` equals the first event of ``sample_events(..., seed, n)``.

    Raises:
        ConfigError: source or track start outside the detector, n_photons < 1 after
            rounding, NaN or out-of-domain parameters, bad config, medium or seed (one
            line).
    """
    seed, grid, light = _prepare(detector, params, [source], seed, config, medium, generator)
    return _event(detector, params, source, seed, 0, config, grid, light)


def sample_events(
    detector: Detector,
    params: Params,
    source,
    seed: int,
    n_events: int,
    *,
    config: TransportConfig = DEFAULT_CONFIG,
    medium: str | None = None,
    generator: GeneratorSettings | None = None,
    progress: bool = False,
    first_event: int = 0,
    threads: int = 1,
):
    """Yield ``n_events`` independent Monte Carlo events, of indices ``first_event`` to
    ``first_event + n_events - 1``.

    ``source`` is one calibration source or ``Track`` for every event, or a sequence of
    ``n_events`` of them, the k-th for event ``first_event + k`` (e.g. a slice of
    ``random_tracks``); ``medium`` and ``generator`` as in ``sample``. Event i uses the
    key ``fold_in(PRNGKey(seed), i)`` (and for a track the generator seeds of
    ``event_seeds(seed, i)``), so the same seed gives the same events in the same
    order, and a run split into blocks by ``first_event`` (parallel production,
    resuming) gives the same events as one run. ``progress=True`` shows a rich
    progress bar. ``threads`` > 1 computes that many events at once
    (``threads.ordered_map``: a track's generator, in Python, overlaps another event's
    compiled transport), the same events in the same order. Input is validated before
    the first event (``ConfigError``, one line).
    """
    for name, value, lowest in (("n_events", n_events, 0), ("first_event", first_event, 0),
                                ("threads", threads, 1)):
        check_count(name, value, lowest)
    per_event = isinstance(source, list | tuple)
    distinct = list(source) if per_event else [source]
    if per_event and len(distinct) != n_events:
        raise ConfigError(f"{len(distinct)} sources for n_events = {n_events}: need one per event")
    seed, grid, light = _prepare(detector, params, distinct, seed, config, medium, generator)
    sources = distinct if per_event else itertools.repeat(distinct[0], int(n_events))
    events = ordered_map(
        lambda pair: _event(detector, params, pair[1], seed, pair[0], config, grid, light),
        enumerate(sources, start=int(first_event)), threads)
    yield from with_progress(events, "sampling events", total=int(n_events), show=progress)


def sample_together(
    detector: Detector,
    params: Params,
    tracks,
    seed: int,
    *,
    config: TransportConfig = DEFAULT_CONFIG,
    medium: str | None = None,
    generator: GeneratorSettings | None = None,
    threads: int = 1,
) -> list[Event]:
    """Monte Carlo events of several particle ``tracks``, one event each, whose particles
    the generator transports together (``generator.generate_together``: 16 muons of 1 GeV
    in about a third of the time they take one at a time), each event's photons then
    followed and read out as in ``sample_events``.

    Event k uses the transport and response keys of event k of ``seed``. The events are
    independent and distributed as ``sample_events``' but are not the same events (the
    generator's random numbers are shared by the list): the same tracks and seed give the
    same events. ``medium``, ``generator`` and ``threads`` as in ``sample_events``;
    input is validated first (``ConfigError``, one line). Positions m, times ns, charges
    p.e.
    """
    tracks = list(tracks)
    for k, track in enumerate(tracks):
        if not isinstance(track, Track):
            raise ConfigError(f"tracks[{k}] = {format_value(track)}: must be a photonflow.Track")
    check_count("threads", threads, 1)
    seed, grid, light = _prepare(detector, params, tracks, seed, config, medium, generator)
    bundles = track_photons_together(detector, tracks, seed, light)
    return list(ordered_map(
        lambda k: _track_event(detector, params, tracks[k], bundles[k], seed, k, config, grid,
                               light),
        range(len(tracks)), threads))
