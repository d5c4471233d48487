"""Track light, expected against sampled mode (studies/track-light-validation.md):

    python studies/tracks/compare_sampled.py [--detector SK] [--particle mu-]
        [--energy 1000] [--events 60] [--start 0,0,0] [--direction 1,0,0]
        [--absorption-only] [--keys 1] [--plot PATH]
        [--emission-model spline|siren|tables] [--cache SAMPLED.npz]

Per-sensor p.e. of generator + sampled transport (counted before the charge response)
against ``expected`` (4,096 rays, averaged over ``--keys`` ray keys); prints the totals,
the per-sensor chi2/ndf (with and without a 3 % floor) and the light by the sensors'
angle to the track. With two keys or more, a second chi2/ndf adds the expected mode's own
statistical error, its ray noise (the variance of the keys' mean, from their spread), to
the sampled mean's. ``--cache``: the sampled counts are read from this file if it
exists (written there otherwise), so that several emission models meet the same events.
"""

from __future__ import annotations

import argparse
import os

import jax
import numpy as np

import photonflow as pf
from photonflow.transport.pseudo_data import sample_track_tally
from photonflow.transport.tracks import track_light


def _vector(text: str) -> np.ndarray:
    return np.array([float(x) for x in text.split(",")])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--detector", default="SK")
    parser.add_argument("--particle", default="mu-")
    parser.add_argument("--energy", type=float, default=1000.0)
    parser.add_argument("--events", type=int, default=60)
    parser.add_argument("--start", type=_vector, default=_vector("0,0,0"))
    parser.add_argument("--direction", type=_vector, default=_vector("1,0,0"))
    parser.add_argument("--absorption-only", action="store_true")
    parser.add_argument("--keys", type=int, default=1,
                        help="average the expected mode over this many ray keys")
    parser.add_argument("--plot", default=None,
                        help="write the sampled and expected maps and the pulls here")
    parser.add_argument("--emission-model", default="spline",
                        help="TransportConfig.emission_model of the expected mode")
    parser.add_argument("--cache", default=None,
                        help="npz file of the sampled counts (read if it exists)")
    args = parser.parse_args()
    detector = pf.load_detector(args.detector)
    base = pf.default_params(detector)
    params = base.replace(dark_rate=base.dark_rate * 0)
    if args.absorption_only:
        params = params.replace(scattering_length=np.float32(1e6), mie_length=np.float32(1e6),
                                wall_reflectivity=np.float32(0.0),
                                sensor_reflectivity=np.float32(0.0))
    direction = args.direction / np.linalg.norm(args.direction)
    track = pf.Track(args.particle, args.start, direction, args.energy, 0.0)
    config = pf.TransportConfig(n_rays=4096, emission_model=args.emission_model)
    per_key = np.array([np.asarray(pf.expected(detector, params, track, config=config,
                                               key=jax.random.key(k)).charge, float)
                        for k in range(args.keys)])
    expected = per_key.mean(axis=0)
    ray_noise = (per_key.std(axis=0, ddof=1) / np.sqrt(args.keys) if args.keys > 1
                 else np.zeros_like(expected))
    if args.cache and os.path.exists(args.cache):
        counts = np.load(args.cache)["counts"]
    else:
        light = track_light(detector)
        counts = np.zeros((args.events, detector.n_sensors))
        for index in range(args.events):
            tally = sample_track_tally(detector, params, track, jax.random.key(index), 7,
                                       index, light)
            counts[index] = np.asarray(tally.n_pe)
        if args.cache:
            np.savez_compressed(args.cache, counts=counts)
    events = counts.shape[0]
    mean = counts.mean(axis=0)
    error = counts.std(axis=0, ddof=1) / np.sqrt(events)
    total_error = counts.sum(axis=1).std(ddof=1) / np.sqrt(events)
    print(f"total p.e.: expected {expected.sum():.1f}, sampled {mean.sum():.1f} +- "
          f"{total_error:.1f}, ratio {expected.sum() / mean.sum():.4f}")
    lit = (expected > 0.5) | (mean > 0.5)
    for floor in (0.0, 0.03):
        pulls = (mean - expected)[lit] / np.sqrt(error[lit] ** 2 + (floor * expected[lit]) ** 2
                                                 + 1e-12)
        both = (mean - expected)[lit] / np.sqrt(error[lit] ** 2 + ray_noise[lit] ** 2
                                                + (floor * expected[lit]) ** 2 + 1e-12)
        print(f"floor {floor:.0%}: chi2/ndf {np.mean(pulls ** 2):.2f} over {lit.sum()} sensors"
              f" (sampled errors); {np.mean(both ** 2):.2f} with the expected mode's ray"
              f" noise too ({args.keys} keys)")
    pull = np.zeros_like(mean)
    pull[lit] = pulls
    if args.plot:
        _plot(detector, mean, expected, pull, args)
    offset = detector.sensor_positions - args.start
    cosine = offset @ direction / np.linalg.norm(offset, axis=1)
    edges = np.linspace(-1.0, 1.0, 41)
    band = np.digitize(cosine, edges)
    for b in range(1, 41):
        chosen = band == b
        if chosen.any() and mean[chosen].sum() > 0:
            print(f"cos [{edges[b - 1]:+.2f}, {edges[b]:+.2f}]: sampled {mean[chosen].sum():8.1f}"
                  f" expected {expected[chosen].sum():8.1f}  chi2 (3 %) "
                  f"{np.sum(pull[chosen] ** 2):6.1f} / {np.sum(chosen & lit)}")


def _plot(detector, mean, expected, pull, args) -> None:
    """Sampled and expected p.e. on one logarithmic scale and the pulls (3 % floor)."""
    from matplotlib.colors import LogNorm, TwoSlopeNorm
    from matplotlib.figure import Figure

    from photonflow.viz.geometry_plot import draw_wall, save_figure
    from photonflow.viz.projections import sensor_map

    figure = Figure(figsize=(16.0, 5.5), layout="constrained")
    axes = figure.subplots(1, 3)
    projected = sensor_map(detector)
    positive = np.concatenate([mean[mean > 0], expected[expected > 1e-3]])
    norm = LogNorm(vmin=max(positive.min(), 1e-2), vmax=positive.max())
    draw_wall(figure, axes[0], detector, projected, np.where(mean > 0, mean, np.nan),
              f"sampled mean p.e. ({args.events} events)", "viridis", norm)
    draw_wall(figure, axes[1], detector, projected, expected, "expected p.e.", "viridis", norm)
    scale = min(max(float(np.max(np.abs(pull))), 1e-6), 5.0)  # pulls beyond 5 saturate
    draw_wall(figure, axes[2], detector, projected, pull,
              "(sampled - expected) / error (3 % floor)", "RdBu_r",
              TwoSlopeNorm(vcenter=0.0, vmin=-scale, vmax=scale))
    figure.suptitle(f"{args.detector}: {args.energy:g} MeV {args.particle} from"
                    f" {args.start.tolist()} m along {args.direction.tolist()}")
    save_figure(figure, args.plot)


if __name__ == "__main__":
    main()
