"""The independent-ray root's ray-noise bias, and its removal by extrapolating in the
number of rays (docs/calibration.md, "Ray noise and the independent-ray score").

One sampled-mode data set on TOY_CYLINDER (two isotropic flashes and a downward laser,
strong scattering), absorption, scattering and wall reflectivity free. The reference is
the root of the independent-ray score with the expected charges M_a and the derivatives
J_b each averaged over ``--reference-sets`` ray sets (its ray-noise bias is that much
smaller). Then for ``--keys`` independent ray keys of ``--rays`` rays the fit's stage
(``independent_ray_stage.independent_ray_steps``) gives the one-set root theta_1 and
the extrapolated root; printed per key and on average is each one's distance from the reference in
units of the one-set root's error:

    python examples/calibration/ray_extrapolation.py [--rays 64] [--keys 8]
        [--photons 1e6] [--reference-sets 32]

The data set is the same for every key, so the data's noise cancels in the distances and
what is left is the ray noise: scatter around a mean, the mean being the bias.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import numpy as np

import photonflow as pf
from photonflow.calibration.independent_ray_stage import independent_ray_steps, root_steps
from photonflow.calibration.layout import free_layout
from photonflow.calibration.objective import CalibrationProblem
from photonflow.calibration.runs import prepare_runs
from photonflow.params import to_unconstrained
from photonflow.transport.optics import TransportConfig
from photonflow.transport.pseudo_data import sample_events

FREE = ("absorption_length", "scattering_length", "wall_reflectivity")
TRUTH = {"absorption_length": 30.0, "scattering_length": 20.0, "wall_reflectivity": 0.2}


def unconstrained_vector(layout, theta: dict) -> np.ndarray:
    """The dense free entries of ``theta`` (log lengths, logit probabilities)."""
    return np.asarray(layout.split(theta)[0], np.float64)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rays", type=int, default=64, help="expected-mode rays per set")
    parser.add_argument("--keys", type=int, default=8, help="independent ray keys")
    parser.add_argument("--photons", type=float, default=1e6, help="photons per flash")
    parser.add_argument("--reference-sets", type=int, default=32)
    args = parser.parse_args()
    began = time.perf_counter()

    config = TransportConfig(n_bounces=2, n_rays=args.rays)
    detector = pf.load_detector("TOY_CYLINDER")
    truth = pf.default_params(detector).replace(**TRUTH)
    sources = [
        pf.IsotropicSource(position=[0.0, 0.0, 0.0], n_photons=args.photons),
        pf.IsotropicSource(position=[0.8, 0.0, -0.5], n_photons=args.photons),
        pf.LaserSource(position=[0.0, 0.0, 1.5], direction=[0.0, 0.0, -1.0],
                       opening_angle=0.1, n_photons=args.photons),
    ]
    runs = prepare_runs(
        [(s, list(sample_events(detector, truth, s, 90 + k, 1, config=config)))
         for k, s in enumerate(sources)], detector, "charge")
    layout = free_layout(list(FREE), detector.n_sensors)

    def problem(key: int) -> CalibrationProblem:
        return CalibrationProblem(detector, runs, truth, layout, "charge", config,
                                  jax.random.key(key))

    # the reference: M_a and J_b over many ray sets, the Jensen correction included
    sets = args.reference_sets
    reference_problem = problem(999)
    steps = dict(history=[], started=0.0, step_tolerance=0.01, callback=None, stage="ref",
                 charge_sets=sets)
    reference, parts, noise, *_ = root_steps(
        reference_problem, reference_problem.initial_theta(), ray_noise=None, **steps)
    frozen = dataclasses.replace(
        parts, jacobians=reference_problem.independent_jacobians(reference, sets))
    reference, *_ = root_steps(reference_problem, reference, ray_noise=noise,
                                frozen=frozen, **steps)
    reference_vector = unconstrained_vector(layout, reference)
    print(f"reference ({sets} x {args.rays} rays), unconstrained:"
          f" {np.round(reference_vector, 4)} ({time.perf_counter() - began:.0f} s)", flush=True)

    one_set, extrapolated = [], []
    for key in range(args.keys):
        fit = problem(key)
        history = []
        theta, _, covariance, converged, _ = independent_ray_steps(
            fit, reference, history, 0.0, 0.01, None, extrapolate=True)
        sigma = np.sqrt(np.diag(covariance.covariance()[0]))
        last_one = [h for h in history if h["stage"] == "independent rays"][-1]["values"]
        theta_one = layout.select(to_unconstrained(truth.replace(**last_one)))
        one_set.append((unconstrained_vector(layout, theta_one) - reference_vector) / sigma)
        extrapolated.append((unconstrained_vector(layout, theta) - reference_vector) / sigma)
        print(f"key {key}: converged {converged}; one set {np.round(one_set[-1], 2)},"
              f" extrapolated {np.round(extrapolated[-1], 2)}", flush=True)

    print(f"\nmean distance from the reference in sigma ({', '.join(FREE)}), {args.keys} keys:")
    for label, rows in (("one set", one_set), ("extrapolated", extrapolated)):
        rows = np.array(rows)
        error = rows.std(axis=0, ddof=1) / np.sqrt(len(rows))
        print(f"  {label:13s} " + "  ".join(f"{m:+.2f} +- {e:.2f}"
                                             for m, e in zip(rows.mean(0), error, strict=True)))
    print(f"{time.perf_counter() - began:.0f} s")


if __name__ == "__main__":
    main()
