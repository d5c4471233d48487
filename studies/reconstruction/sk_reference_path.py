"""Whether an SK fit's end depends on its path through the indirect light's reference:
events simulated at one true track, each fitted from its hits (the settings given) and,
with ``--from-truth``, also from the truth, with -log L of the fits evaluated with the
rays of each of them (no hold: the rays traced at every evaluation).

    python examples/reconstruction/sk_mu_e.py --events 300 --out-dir runs/sk_mu_e_300
    python studies/reconstruction/sk_reference_path.py runs/sk_mu_e_300/events.h5 \\
        out.jsonl --event 1 --events 12 [--from-truth]
        [--frozen-stages 0 --refresh-distance 0.05 --refresh-angle 1.0]  # the old fit

One JSON row per simulated event: for each fit its -log L as reported, whether it
converged, its iterations, and its errors along and across the true track (cm), in
direction (degrees) and energy (fraction); with ``--from-truth``, ``nll_with_rays_of``:
-log L of the truth and of both fits with the rays of each. Events: the generator and
the sampled mode at the ``--event``-th truth of the event file, seeds 1000 + that index,
1,024 rays, the shipped tables, float32, no simulated variability.
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import jax.numpy as jnp
import numpy as np

import photonflow as pf
from photonflow.io import read_events
from photonflow.reconstruction import RecoSettings
from photonflow.reconstruction.coordinates import fit_frame, local_from_track
from photonflow.reconstruction.fit import event_data, likelihood_functions
from photonflow.reconstruction.minimisers import cast_track, local_value_and_grad, staged_data
from photonflow.transport.pseudo_data import sample_events


def errors(fit, truth) -> dict:
    """The fit's errors against the truth: along and across its track (cm), direction
    (degrees), energy (fraction)."""
    axis = np.asarray(truth.direction)
    offset = np.asarray(fit.position) - np.asarray(truth.position)
    along = float(offset @ axis)
    cosine = float(np.clip(np.dot(fit.direction, axis), -1.0, 1.0))
    return {"along_cm": round(100 * along, 1),
            "across_cm": round(100 * float(np.linalg.norm(offset - along * axis)), 1),
            "direction_deg": round(float(np.degrees(np.arccos(cosine))), 2),
            "energy_frac": round(float(fit.energy / truth.energy - 1.0), 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("events_file")
    parser.add_argument("out")
    parser.add_argument("--event", type=int, default=1)
    parser.add_argument("--events", type=int, default=12)
    parser.add_argument("--from-truth", action="store_true")
    parser.add_argument("--frozen-stages", type=int, default=RecoSettings.frozen_stages)
    parser.add_argument("--refreshes", type=int, default=RecoSettings.refreshes)
    parser.add_argument("--refresh-distance", type=float,
                        default=RecoSettings.refresh_distance)
    parser.add_argument("--refresh-angle", type=float, default=RecoSettings.refresh_angle)
    args = parser.parse_args()
    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    config = pf.TransportConfig(n_rays=1024, emission_model="tables")
    with read_events(args.events_file) as events:
        truth = events[args.event].truth
    track = pf.Track(truth.particle, truth.position, truth.direction, truth.energy,
                     truth.time)
    settings = RecoSettings(variability_events=0, frozen_stages=args.frozen_stages,
                            refreshes=args.refreshes,
                            refresh_distance=args.refresh_distance,
                            refresh_angle=args.refresh_angle)
    dtype = jnp.float32
    functions = likelihood_functions(detector, dtype, config)
    model = functions.emission(truth.particle)
    starts = {"seeded": None, **({"from_truth": track} if args.from_truth else {})}
    simulated = sample_events(detector, params, track, 1000 + args.event, args.events,
                              config=config)
    with open(args.out, "a") as out:
        for index, event in enumerate(simulated):
            row, fitted = {"event": args.event, "simulated": index}, {"truth": track}
            for name, start in starts.items():
                fit = pf.reconstruct(detector, params, event, truth.particle, config=config,
                                     settings=settings, start=start)
                fitted[name] = pf.Track(fit.particle, fit.position, fit.direction,
                                        fit.energy, fit.time)
                row[name] = {"nll": round(float(fit.nll), 2), "converged": fit.converged,
                             "iterations": fit.iterations, **errors(fit, truth)}
            if args.from_truth:
                data = dataclasses.replace(event_data(detector, params, event, dtype,
                                                      functions), emission=model)
                traced = RecoSettings(hold_indirect=False)
                row["nll_with_rays_of"] = {}
                for name, reference in fitted.items():
                    reference = cast_track(reference, dtype)
                    frame = fit_frame(detector.shape, reference.direction,
                                      model.energy_range, truth.particle, 0.0, dtype)
                    value = local_value_and_grad(functions, frame, reference,
                                                 staged_data(functions, data, reference,
                                                             traced))
                    row["nll_with_rays_of"][name] = {
                        other: round(value(np.asarray(local_from_track(
                            cast_track(t, dtype), dtype), np.float64))[0], 2)
                        for other, t in fitted.items()}
            print(json.dumps(row), file=out, flush=True)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
