"""Joint gradient fit versus the conventional sequential calibration, side by side on the
same pseudo-data (issue 5).

Toy cylinder (r = 2 m, h = 4 m, 200 sensors). Every pseudo-experiment draws per-sensor
efficiencies with a 10 % spread and simulates, in the sampled mode (photon by photon),
a central isotropic flasher (the efficiency run) and four off-centre ones near the caps
and the barrel (the attenuation runs). The same runs are then fitted by

- ``joint``: ``photonflow.calibration.calibrate`` (all free fields at once, Fisher
  scoring on the expected mode's exact charge likelihood);
- ``sequential``: ``sequential_calibration`` as done traditionally (efficiencies from
  the central source corrected by direct-light acceptance, attenuation from the slope
  of log charge versus distance, the other optics by 1-D likelihood scans; iterated);
- ``seq+MC``: the same chain with the indirect light predicted by the expected mode at
  the current values subtracted before the efficiency and slope blocks.

Every fit starts 20-30 % away from the true optics (random sign per parameter) with all
efficiencies at 1. Prints per method and parameter the bias (mean of fitted - true), its
significance, the spread (standard deviation), the mean and width of the pulls (fitted -
true) / quoted error, and the median wall time per fit; also the direct-light attenuation
length (1 / L_abs + 1 / L_scat)^-1 each method implies. ``--json`` keeps every fit.

    python examples/calibration/conventional_vs_joint.py [--experiments 20] [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time

import numpy as np

import photonflow as pf
from photonflow.calibration import calibrate, sequential_calibration
from photonflow.calibration.conventional import attenuation_inverse
from photonflow.transport.optics import TransportConfig
from photonflow.transport.pseudo_data import sample_events

#: True optics of the campaign (m, m, probability); the rest are the toy's defaults.
TRUTH = {"absorption_length": 10.0, "scattering_length": 30.0, "wall_reflectivity": 0.05}

#: Isotropic flasher positions, m: the centre (efficiency run) first.
POSITIONS = ([0.0, 0.0, 0.0], [0.0, 0.0, 1.4], [0.0, 0.0, -1.4], [1.3, 0.3, 0.5],
             [-0.5, -1.3, -0.5])

METHODS = ("joint", "sequential", "seq+MC")


def true_params(detector, rng) -> pf.Params:
    """The campaign's true parameters: ``TRUTH`` optics, efficiencies N(1, 0.1)."""
    nominal = pf.default_params(detector)
    return nominal.replace(**TRUTH, efficiency=rng.normal(1.0, 0.1, detector.n_sensors))


def start_params(truth: pf.Params, optics, rng) -> pf.Params:
    """Each free optical value 20-30 % away from the truth (random sign), efficiencies 1."""
    moved = {
        name: float(getattr(truth, name)) * (1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(0.2, 0.3))
        for name in optics
    }
    return truth.replace(**moved, efficiency=np.ones_like(np.asarray(truth.efficiency)))


def make_runs(detector, truth, config, seed: int, photons: float, flashes: tuple[int, int]):
    """(source, events) pairs: ``flashes[0]`` flashes of the central source and
    ``flashes[1]`` of each off-centre one, ``photons`` photons each (sampled mode)."""
    runs = []
    for k, position in enumerate(POSITIONS):
        source = pf.IsotropicSource(position=position, n_photons=photons)
        n_events = flashes[0] if k == 0 else flashes[1]
        events = list(sample_events(detector, truth, source, 1000 * seed + k, n_events,
                                    config=config))
        runs.append((source, events))
    return runs


def summarise(result, truth, optics) -> dict:
    """Fitted - true, error and pull per optical field; efficiency summaries."""
    row = {"wall_time_s": result.wall_time_s, "converged": bool(result.converged),
           "loss": float(result.loss), "start_loss": float(result.history[0]["loss"])}
    for name in optics:
        fitted, true = float(getattr(result.params, name)), float(getattr(truth, name))
        error = float(getattr(result.errors, name))
        row[name] = {"fitted": fitted, "true": true, "error": error,
                     "pull": (fitted - true) / error if error > 0 else math.nan}
    row["attenuation_length"] = {
        "fitted": 1.0 / attenuation_inverse(result.params),
        "true": 1.0 / attenuation_inverse(truth),
        "error": math.nan,
        "pull": math.nan,
    }
    residual = np.asarray(result.params.efficiency, np.float64) - np.asarray(
        truth.efficiency, np.float64)
    error = np.asarray(result.errors.efficiency, np.float64)
    pulls = residual / np.where(error > 0, error, np.nan)
    row["efficiency"] = {
        "mean_residual": float(np.mean(residual)),
        "rms_residual": float(np.sqrt(np.mean(residual**2))),
        "rms_error": float(np.sqrt(np.mean(error**2))),
        "pull_mean": float(np.nanmean(pulls)),
        "pull_std": float(np.nanstd(pulls)),
    }
    return row


def fit_all(detector, runs, start, truth, optics, config, iterations: int) -> dict:
    """The three fits of one pseudo-experiment: method -> ``summarise`` row."""
    free = [*optics, "efficiency"]
    results = {
        "joint": calibrate(detector, runs, start, free, config=config, truth=truth),
        "sequential": sequential_calibration(detector, runs, start, free, config=config,
                                             n_iterations=iterations, truth=truth),
        "seq+MC": sequential_calibration(detector, runs, start, free, config=config,
                                         n_iterations=iterations, indirect="subtract",
                                         truth=truth),
    }
    return {method: summarise(result, truth, optics) for method, result in results.items()}


def table(rows: list[dict], optics) -> str:
    """The side-by-side table (markdown) over the experiments in ``rows``."""
    n = len(rows)
    lines = [
        f"{n} pseudo-experiments. bias = mean(fitted - true) (its significance: bias /"
        " (spread / sqrt(n))); spread = std of fitted; pulls = (fitted - true) / quoted"
        " error, mean and std.",
        "",
        "| method | parameter | true | bias | bias / s.e. | spread | pull mean | pull std |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for method in METHODS:
        for name in [*optics, "attenuation_length"]:
            fitted = np.array([r[method][name]["fitted"] for r in rows])
            true = rows[0][method][name]["true"]
            pulls = np.array([r[method][name]["pull"] for r in rows])
            bias, spread = float(np.mean(fitted - true)), float(np.std(fitted, ddof=1))
            significance = bias / (spread / math.sqrt(n))
            lines.append(
                f"| {method} | {name} | {true:.4g} | {bias:+.3g} | {significance:+.1f}"
                f" | {spread:.3g} | {np.nanmean(pulls):+.2f} | {np.nanstd(pulls, ddof=1):.2f} |"
            )
        eff = [r[method]["efficiency"] for r in rows]
        mean_residual = np.array([e["mean_residual"] for e in eff])
        lines.append(
            f"| {method} | efficiency (200) | N(1, 0.1) | {np.mean(mean_residual):+.3g}"
            f" | {np.mean(mean_residual) / (np.std(mean_residual, ddof=1) / math.sqrt(n)):+.1f}"
            f" | rms {np.mean([e['rms_residual'] for e in eff]):.3g}"
            f" (quoted {np.mean([e['rms_error'] for e in eff]):.3g})"
            f" | {np.mean([e['pull_mean'] for e in eff]):+.2f}"
            f" | {np.mean([e['pull_std'] for e in eff]):.2f} |"
        )
    lines += [
        "",
        "| method | median wall time per fit, s | converged | -log L rose from the start"
        " | mean -log L above the joint fit's |",
        "|---|---|---|---|---|",
    ]
    for method in METHODS:
        times = [r[method]["wall_time_s"] for r in rows]
        converged = sum(r[method]["converged"] for r in rows)
        rose = sum(r[method]["loss"] > r[method]["start_loss"] for r in rows)
        above = np.mean([r[method]["loss"] - r["joint"]["loss"] for r in rows])
        lines.append(f"| {method} | {np.median(times):.1f} | {converged}/{n} | {rose}/{n}"
                     f" | {above:.1f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiments", type=int, default=20)
    parser.add_argument("--quick", action="store_true",
                        help="2 experiments, 1024 rays, 2 passes: a smoke run, not a result")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rays", type=int, default=4096, help="expected-mode rays per run")
    parser.add_argument("--bounces", type=int, default=3)
    parser.add_argument("--photons", type=float, default=1e5, help="photons per flash")
    parser.add_argument("--flashes", default="10,5",
                        help="flashes of the central run, of each off-centre run")
    parser.add_argument("--iterations", type=int, default=3, help="sequential passes")
    parser.add_argument("--optics", default="absorption_length,wall_reflectivity",
                        help="free optical fields (the others stay at the truth)")
    parser.add_argument("--json", help="write every fit's summary to this file")
    args = parser.parse_args()
    if args.quick:
        args.experiments, args.rays, args.iterations = min(args.experiments, 2), 1024, 2
    optics = [name.strip() for name in args.optics.split(",") if name.strip()]
    flashes = tuple(int(x) for x in args.flashes.split(","))

    detector = pf.load_detector("TOY_CYLINDER")
    config = TransportConfig(n_bounces=args.bounces, n_rays=args.rays)
    print(f"{detector.name}: {detector.n_sensors} sensors; truth {TRUTH}; {args.rays} rays,"
          f" {args.bounces} bounces; {args.photons:g} photons x {flashes} flashes;"
          f" machine {platform.machine()} {platform.processor() or ''}", flush=True)
    rows = []
    for experiment in range(args.experiments):
        seed = args.seed + experiment
        rng = np.random.default_rng(seed)
        truth = true_params(detector, rng)
        start = start_params(truth, optics, rng)
        began = time.perf_counter()
        runs = make_runs(detector, truth, config, seed, args.photons, flashes)
        simulated = time.perf_counter() - began
        row = fit_all(detector, runs, start, truth, optics, config, args.iterations)
        row["seed"], row["simulation_s"] = seed, simulated
        rows.append(row)
        shown = "; ".join(
            f"{method}: " + ", ".join(f"{name[:4]} {row[method][name]['fitted']:.4g}"
                                      for name in optics)
            + f" ({row[method]['wall_time_s']:.0f} s)"
            for method in METHODS
        )
        print(f"[{experiment + 1}/{args.experiments}] seed {seed}: {shown}", flush=True)
        if args.json:
            with open(args.json, "w") as handle:
                json.dump({"args": vars(args), "truth": TRUTH, "rows": rows}, handle, indent=1)
    print()
    print(table(rows, optics))


if __name__ == "__main__":
    main()
