"""Reconstruction benchmark (issue 25): ``python benchmarks/reconstruction.py [--events N]
[--minuit M] [--out FILE.jsonl] [--fits F] [--emission-model spline|siren|tables]
[--rays-every-evaluation] [--particle mu-|e-] [--energy MEV] [--overdispersion R]
[--variability-events N]``.

SK with the default parameters, 1 GeV muons (or ``--particle`` at ``--energy``) from the
generator and the sampled mode
(vertices uniform at least 2 m inside the walls, isotropic directions, seed 7), each
reconstructed by ``reconstruct(..., method="gradient")`` from its hits alone, the first
``--minuit`` of them also by MINUIT. One JSON line per fit (written as it ends, so an
interrupted run keeps what it measured): seconds, likelihood evaluations, converged,
the vertex error (m), direction error (degrees) and energy error (fraction), and the
reported 1-sigma errors. The first fit of each method includes its compilation.
Prints the medians at the end.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys

import numpy as np


def _truths(detector, count: int, seed: int, particle: str = "mu-", energy: float = 1000.0):
    """``count`` tracks of ``particle`` with kinetic ``energy`` (MeV), vertices uniform at
    least 2 m inside SK's walls, isotropic directions."""
    import photonflow as pf

    rng = np.random.default_rng(seed)
    radius, half = detector.shape.radius - 2.0, 0.5 * detector.shape.height - 2.0
    tracks = []
    while len(tracks) < count:
        x, y = rng.uniform(-radius, radius, 2)
        if x * x + y * y > radius * radius:
            continue
        direction = rng.normal(size=3)
        tracks.append(pf.Track(particle, [x, y, rng.uniform(-half, half)],
                               direction / np.linalg.norm(direction), energy, 0.0))
    return tracks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=5)
    parser.add_argument("--minuit", type=int, default=1)
    parser.add_argument("--out", default=None)
    parser.add_argument("--fits", type=int, default=None,
                        help="RecoSettings.fits (default: RecoSettings' own)")
    parser.add_argument("--emission-model", default="spline",
                        help="TransportConfig.emission_model: spline, siren or tables")
    parser.add_argument("--rays-every-evaluation", action="store_true",
                        help="RecoSettings(hold_indirect=False): trace the indirect light's"
                        " rays at every evaluation instead of holding it per fit stage")
    parser.add_argument("--particle", default="mu-", help="mu- or e-")
    parser.add_argument("--overdispersion", type=float, default=0.0,
                        help="RecoSettings.overdispersion (r, dimensionless; 0: Poisson)")
    parser.add_argument("--energy", type=float, default=1000.0, help="kinetic energy, MeV")
    parser.add_argument("--variability-events", type=int, default=None,
                        help="events simulated at each fit for its covariance (default:"
                             " RecoSettings'; 0: H^-1 alone, no bias correction)")
    args = parser.parse_args()
    import photonflow as pf
    from photonflow.benchmarking import machine_description

    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    config = pf.TransportConfig(n_rays=1024, emission_model=args.emission_model)
    settings = pf.RecoSettings(hold_indirect=not args.rays_every_evaluation,
                               overdispersion=args.overdispersion)
    if args.fits is not None:
        settings = dataclasses.replace(settings, fits=args.fits)
    if args.variability_events is not None:
        settings = dataclasses.replace(settings, variability_events=args.variability_events)
    out = open(args.out, "a") if args.out else None  # noqa: SIM115
    rows = []
    print(f"Machine: {machine_description()}", flush=True)
    for k, truth in enumerate(_truths(detector, args.events, 7, args.particle,
                                                   args.energy)):
        event = pf.sample(detector, params, truth, seed=100 + k)
        for method in ("gradient", "minuit")[: 2 if k < args.minuit else 1]:
            fit = pf.reconstruct(detector, params, event, args.particle, method, config=config,
                                 settings=settings)
            row = {"event": k, "method": method, "seconds": fit.seconds,
                   "evaluations": fit.evaluations, "converged": fit.converged,
                   "failure": fit.failure}
            if fit.failure is None:
                row.update(
                    vertex_m=float(np.linalg.norm(fit.position - truth.position)),
                    direction_deg=math.degrees(math.acos(min(1.0, float(
                        fit.direction @ truth.direction)))),
                    energy_frac=fit.energy / args.energy - 1.0, errors=fit.errors)
            rows.append(row)
            line = json.dumps(row)
            print(line, flush=True)
            if out:
                out.write(line + "\n")
                out.flush()
    for method in ("gradient", "minuit"):
        done = [r for r in rows if r["method"] == method and r["failure"] is None]
        if done:
            later = [r["seconds"] for r in done[1:]] or [done[0]["seconds"]]
            print(f"{method}: {len(done)} fits, median {np.median(later):.1f} s per event"
                  f" after the first, vertex {np.median([r['vertex_m'] for r in done]):.3f} m,"
                  f" direction {np.median([r['direction_deg'] for r in done]):.2f} deg,"
                  f" |energy| {np.median([abs(r['energy_frac']) for r in done]):.3f}",
                  file=sys.stdout)


if __name__ == "__main__":
    main()
