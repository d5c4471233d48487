"""Optical calibration pulls over independent pseudo-experiments (issue 5).

Each pseudo-experiment simulates a central downward laser and two isotropic flashes in
the sampled mode (photon by photon) with known true optics, fits the absorption and
scattering lengths and the wall and sensor reflectivities from a start 25 % away
(Fisher scoring on the expected mode, a fresh ray key per experiment so that the
expected mode's ray noise is part of what the pulls measure), and records the pulls
(fitted - true) / error. Prints per parameter the mean and width of the pulls, the
bias and spread of the fitted values, and the wall time per fit.

    python examples/calibration/optical_pulls.py [--experiments 20] [--detector TOY_CYLINDER]
        [--photons 1e5] [--rays 8192] [--bounces 3] [--out pulls.json]
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

import photonflow as pf
from photonflow.calibration import calibrate
from photonflow.transport.optics import TransportConfig
from photonflow.transport.pseudo_data import sample_events

OPTICS = ("absorption_length", "scattering_length", "wall_reflectivity", "sensor_reflectivity")
#: True optics of the study (m, m, probability, probability): short enough lengths for
#: the toy cylinder (2 m radius) to measure them.
TRUTH = {"absorption_length": 30.0, "scattering_length": 40.0,
         "wall_reflectivity": 0.2, "sensor_reflectivity": 0.3}
#: Start of every fit relative to the truth (lengths 25 % long / short, reflectivities
#: 25 % low / high).
START_FACTORS = {"absorption_length": 1.25, "scattering_length": 0.75,
                 "wall_reflectivity": 0.75, "sensor_reflectivity": 1.25}


def study_sources(detector, photons: float) -> list:
    """A laser at 80 % of the half height pointing down, a flash at the centre and one
    off-centre low (positions m; a sphere's half height is its radius)."""
    radius = float(detector.shape.radius)
    half = 0.5 * float(getattr(detector.shape, "height", 2.0 * radius))
    return [
        pf.LaserSource(position=[0.0, 0.0, 0.8 * half], direction=[0.0, 0.0, -1.0],
                       opening_angle=0.1, n_photons=photons),
        pf.IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=photons),
        pf.IsotropicSource(position=[0.5 * radius, 0.0, -0.5 * half], n_photons=photons),
    ]


def pull_summary(pulls: np.ndarray) -> tuple[float, float]:
    """(mean, sample standard deviation) of a set of pulls."""
    return float(np.mean(pulls)), float(np.std(pulls, ddof=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiments", type=int, default=20)
    parser.add_argument("--detector", default="TOY_CYLINDER")
    parser.add_argument("--photons", type=float, default=1e5, help="photons per flash")
    parser.add_argument("--flashes", type=int, default=1, help="flashes per run")
    parser.add_argument("--rays", type=int, default=8192, help="expected-mode rays per run")
    parser.add_argument("--bounces", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0, help="first experiment's seed")
    parser.add_argument("--free", default=",".join(OPTICS),
                        help="the optical parameters to fit (the others stay at the truth)")
    parser.add_argument("--out", help="write the per-experiment results to this JSON file")
    args = parser.parse_args()

    free = tuple(args.free.split(","))
    unknown = sorted(set(free) - set(OPTICS))
    if unknown:
        parser.error(f"--free: {', '.join(unknown)}: not one of {', '.join(OPTICS)}")
    detector = pf.load_detector(args.detector)
    truth = pf.default_params(detector).replace(**TRUTH)
    start = truth.replace(**{k: TRUTH[k] * START_FACTORS[k] for k in free})
    config = TransportConfig(n_bounces=args.bounces, n_rays=args.rays)
    sources = study_sources(detector, args.photons)
    rows = []
    for experiment in range(args.seed, args.seed + args.experiments):
        runs = [
            (source, list(sample_events(detector, truth, source, 1000 * experiment + k,
                                        args.flashes, config=config)))
            for k, source in enumerate(sources)
        ]
        began = time.perf_counter()
        result = calibrate(detector, runs, start, list(free), config=config, truth=truth,
                           key=jax.random.key(10_000 + experiment))
        elapsed = time.perf_counter() - began
        pulls = result.pulls()
        row = {
            "experiment": experiment, "converged": result.converged,
            "iterations": len(result.history) - 1, "wall_time_s": elapsed,
            "fitted": {k: float(getattr(result.params, k)) for k in free},
            "error": {k: float(getattr(result.errors, k)) for k in free},
            "pull": {k: float(pulls[k]) for k in free},
        }
        rows.append(row)
        shown = "  ".join(f"{k.split('_')[0]} {row['pull'][k]:+.2f}" for k in free)
        print(f"experiment {experiment}: {row['iterations']} iterations, {elapsed:.1f} s;"
              f" pulls {shown}", flush=True)

    print(f"\n{len(rows)} pseudo-experiments, {args.detector}, {len(sources)} runs of"
          f" {args.flashes} x {args.photons:.0e} photons, {args.rays} rays,"
          f" {args.bounces} bounces")
    print(f"{'parameter':22s} {'true':>8s} {'bias':>9s} {'spread':>9s} {'mean err':>9s}"
          f" {'pull mean':>9s} {'pull width':>10s}")
    for name in free:
        fitted = np.array([row["fitted"][name] for row in rows])
        errors = np.array([row["error"][name] for row in rows])
        # a fit at the edge of the range has an infinite error and no meaningful pull
        finite = np.isfinite(errors)
        mean, width = pull_summary(np.array([row["pull"][name] for row in rows])[finite])
        print(f"{name:22s} {TRUTH[name]:8.4g} {np.mean(fitted) - TRUTH[name]:+9.3g}"
              f" {np.std(fitted, ddof=1):9.3g} {np.mean(errors[finite]):9.3g} {mean:+9.2f}"
              f" {width:10.2f}" + (f"  ({np.sum(~finite)} at the edge of the range,"
                                   " left out)" if not finite.all() else ""))
    pooled = np.array([row["pull"][k] for row in rows for k in free
                       if np.isfinite(row["error"][k])])
    mean, width = pull_summary(pooled)
    times = [row["wall_time_s"] for row in rows]
    print(f"all pulls pooled: mean {mean:+.2f}, width {width:.2f} ({pooled.size} pulls);"
          f" converged {sum(row['converged'] for row in rows)}/{len(rows)};"
          f" median wall time per fit {np.median(times):.1f} s (first, with compilation,"
          f" {times[0]:.1f} s)")
    if args.out:
        with open(args.out, "w") as handle:
            json.dump({"settings": vars(args), "truth": TRUTH, "experiments": rows}, handle,
                      indent=1)


if __name__ == "__main__":
    main()
