"""First-hit times of sampled track events against the expected first-hit distribution
(studies/track-light-validation.md):

    python studies/tracks/first_hit_pit.py [--detector SK] [--particle mu-]
        [--energy 1000] [--events 200] [--start 0,0,0] [--direction 1,0,0] [--keys 1]
        [--overdispersion 0.3] [--hits hits.npz]

Events from the generator + sampled transport, each detected photon's time smeared by the
transit-time spread and shifted by its sensor's time offset; for every sensor j that
detected n_j >= 1 photons, the probability-integral transform of its first-hit time t
given n_j,

    PIT = 1 - (1 - F_j(t))^n_j,

with F_j the expected mode's arrival-time distribution (averaged over ``--keys`` ray
keys): flat if the predicted shape of the arrival times is right. Printed: the histogram
(20 bins), its chi2 against flat, the same for sensors of expected charge < 1, 1-10 and
> 10 p.e., and, for comparison, the PIT given the expected charge mu_j instead of n_j,
(1 - exp(-mu_j F_j(t))) / (1 - exp(-mu_j)) (the likelihood's first-hit term), which also
feels any overdispersion of the counts, and that of the overdispersed likelihood
(``--overdispersion`` r > 0: a Polya process),
(1 - (1 + r mu_j F_j(t))^(-1/r)) / (1 - (1 + r mu_j)^(-1/r)).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import photonflow as pf
from photonflow.progress import with_progress
from photonflow.transport.pseudo_data import sample_track_tally
from photonflow.transport.tracks import track_light

BINS = 20


def _vector(text: str) -> np.ndarray:
    return np.array([float(x) for x in text.split(",")])


def print_bands(pit, charges) -> None:
    """Print the PIT's flatness by the sensors' expected charge (< 1, 1-10, > 10 p.e.),
    for bands of at least 10 hits per bin."""
    for low, high in ((0.0, 1.0), (1.0, 10.0), (10.0, np.inf)):
        chosen = (charges >= low) & (charges < high)
        if chosen.sum() >= 10 * BINS:
            counts, chi2 = flatness(pit[chosen])
            print(f"  mu {low:g}-{high:g} p.e.: {chosen.sum()} hits, chi2/ndf {chi2:.2f};"
                  f" first/last bins {counts[:3].tolist()} ... {counts[-3:].tolist()}")


def first_hits(detector, params, track, index, light, rng):
    """(first-hit time per sensor, ns, inf where none; photons per sensor) of event
    ``index``: generator + sampled transport, each photon's time + tts x N(0, 1) + its
    sensor's time offset."""
    tally = sample_track_tally(detector, params, track, jax.random.key(index), 7, index, light)
    sensor = np.asarray(tally.photon_sensor)
    time = np.asarray(tally.photon_time, np.float64) \
        + float(params.tts) * rng.standard_normal(sensor.size) \
        + np.asarray(params.time_offset, np.float64)[sensor]
    first = np.full(detector.n_sensors, np.inf)
    np.minimum.at(first, sensor, time)
    return first, np.asarray(tally.n_pe)


def _describe(detector, track) -> str:
    """The detector and track a hits file holds events of (its ``sampled`` entry)."""
    return (f"{detector.name} {track.particle} {float(track.energy):g} MeV from "
            f"{np.round(np.asarray(track.position, float), 6).tolist()} along "
            f"{np.round(np.asarray(track.direction, float), 6).tolist()}")


def sampled_hits(detector, params, track, events, path=None):
    """The (first times, counts) of ``events`` sampled events, from the npz file ``path``
    if it exists and holds at least as many events of this detector and track (an
    error otherwise), written there otherwise."""
    if path is not None and Path(path).exists():
        with np.load(path) as saved:
            held = str(saved["sampled"]) if "sampled" in saved else "an unrecorded track"
            if held != _describe(detector, track) or saved["first"].shape[0] < events:
                raise SystemExit(f"error: {path} holds {saved['first'].shape[0]} events of "
                                 f"{held}, not {events} of {_describe(detector, track)}")
            return list(zip(saved["first"][:events], saved["count"][:events], strict=True))
    light = track_light(detector)
    rng = np.random.default_rng(3)
    hits = [first_hits(detector, params, track, i, light, rng)
            for i in with_progress(range(events), "sampled events", show=True)]
    if path is not None:
        np.savez_compressed(path, first=np.stack([h[0] for h in hits]),
                            count=np.stack([h[1] for h in hits]),
                            sampled=_describe(detector, track))
    return hits


def pit_values(prediction, hits, overdispersion=0.0):
    """(PIT given the true count, PIT given the expected charge, expected charge) of every
    hit sensor over the events ``hits`` ((first times, counts) pairs); the second with
    counts of variance mu + r mu^2 for ``overdispersion`` r > 0."""
    given_count, given_mean, charges = [], [], []
    charge = np.asarray(prediction.charge, np.float64)
    for first, count in hits:
        hit = count > 0
        cdf = np.asarray(prediction.time_cdf(jnp.asarray(np.where(hit, first, 0.0))),
                         np.float64)[hit]
        cdf = np.clip(cdf, 0.0, 1.0)
        given_count.append(-np.expm1(count[hit] * np.log1p(-np.minimum(cdf, 1 - 1e-16))))
        mu = charge[hit]
        if overdispersion > 0:
            r = overdispersion
            given_mean.append(-np.expm1(-np.log1p(r * mu * cdf) / r)
                              / -np.expm1(-np.log1p(r * mu) / r))
        else:
            given_mean.append(-np.expm1(-mu * cdf) / -np.expm1(-mu))
        charges.append(mu)
    return tuple(np.concatenate(x) for x in (given_count, given_mean, charges))


def flatness(values) -> tuple[np.ndarray, float]:
    """(histogram in ``BINS`` bins of [0, 1], chi2 / ndf against a flat one)."""
    counts = np.histogram(values, bins=BINS, range=(0.0, 1.0))[0]
    expected = values.size / BINS
    return counts, float(np.sum((counts - expected) ** 2) / expected / (BINS - 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--detector", default="SK")
    parser.add_argument("--particle", default="mu-")
    parser.add_argument("--energy", type=float, default=1000.0)
    parser.add_argument("--events", type=int, default=200)
    parser.add_argument("--start", type=_vector, default=_vector("0,0,0"))
    parser.add_argument("--direction", type=_vector, default=_vector("1,0,0"))
    parser.add_argument("--keys", type=int, default=1)
    parser.add_argument("--overdispersion", type=float, default=0.0)
    parser.add_argument("--hits", default=None,
                        help="npz file of the sampled first hits: read if it exists "
                             "(refused if of another detector or track), else written")
    args = parser.parse_args()
    detector = pf.load_detector(args.detector)
    base = pf.default_params(detector)
    params = base.replace(dark_rate=base.dark_rate * 0)
    config = pf.TransportConfig(n_rays=4096)
    track = pf.Track(args.particle, args.start, args.direction / np.linalg.norm(args.direction),
                     args.energy, 0.0)
    predictions = [pf.expected(detector, params, track, config=config, key=jax.random.key(k))
                   for k in range(args.keys)]
    prediction = predictions[0]
    if args.keys > 1:  # the mixture of the keys' predictions
        charge = sum(p.charge for p in predictions) / args.keys
        weights = jnp.concatenate([p.time_weight * p.charge[:, None] for p in predictions], 1)
        prediction = pf.Prediction.from_components(
            charge, weights / args.keys, jnp.concatenate([p.time_mean for p in predictions], 1),
            jnp.concatenate([p.time_sigma for p in predictions], 1))
        if predictions[0].time_tau is not None:
            prediction = dataclasses.replace(
                prediction, time_tau=jnp.concatenate([p.time_tau for p in predictions], 1))
    hits = sampled_hits(detector, params, track, args.events, args.hits)
    given_count, given_mean, charges = pit_values(prediction, hits)
    counts, chi2 = flatness(given_count)
    print(f"{args.detector} {args.particle} {args.energy:g} MeV: {given_count.size} first"
          f" hits, PIT given the count chi2/ndf {chi2:.2f} (ndf {BINS - 1})")
    print("histogram:", " ".join(str(c) for c in counts))
    print_bands(given_count, charges)
    rs = (0.0,) if args.overdispersion == 0 else (0.0, args.overdispersion)
    for r in rs:
        if r > 0:
            given_mean = pit_values(prediction, hits, r)[1]
        counts, chi2 = flatness(given_mean)
        print(f"PIT given the expected charge, overdispersion {r:g}: chi2/ndf {chi2:.2f};"
              f" histogram {' '.join(str(c) for c in counts)}")
        print_bands(given_mean, charges)


if __name__ == "__main__":
    main()
