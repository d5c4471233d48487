"""SK 1 GeV muons reconstructed from sampled events: accuracy, the pulls of the inverse
Hessian and of a sandwich covariance, and how far the likelihood at the truth lies above
the fitted minimum (charge and first-hit-time terms apart).

    photonflow simulate --detector SK --particle mu- --energy 1000 --events 20 --seed 11 \\
        --out sk20.h5
    python studies/reconstruction/sk_muon_pulls.py sk20.h5 out.jsonl [--events 16]
        [--first 0] [--overdispersion 0.3] [--rays 1024] [--fits 1]

One JSON row per event (appended as each is done): the fit, its covariance, the
sandwich H^-1 J H^-1 (J: the sum over sensors of the outer products of the per-sensor
scores of the negative log-likelihood in the covariance's coordinates) and the charge
and time parts of nll(truth) - nll(fit). ``RecoSettings(fits=1)`` (``--fits``), float32,
1,024 rays unless ``--rays`` says otherwise,
the likelihood's overdispersion from ``--overdispersion`` (default 0: Poisson).
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np

import photonflow as pf
from photonflow.likelihood import dense_sensor_nll
from photonflow.reconstruction import RecoSettings, reconstruct
from photonflow.reconstruction import fit as fitting
from photonflow.reconstruction.coordinates import (
    fit_frame,
    free_from_track,
    local_from_track,
    track_from_local,
)

CONFIG = pf.TransportConfig(n_rays=1024)
DTYPE = jnp.float32


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("events")
    parser.add_argument("out")
    parser.add_argument("--events", dest="count", type=int, default=16)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--overdispersion", type=float, default=0.0)
    parser.add_argument("--rays", type=int, default=CONFIG.n_rays)
    parser.add_argument("--fits", type=int, default=1)
    args = parser.parse_args()
    config = dataclasses.replace(CONFIG, n_rays=args.rays)
    settings = RecoSettings(fits=args.fits, overdispersion=args.overdispersion)
    with pf.read_events(args.events) as events, open(args.out, "a") as out:
        detector, params = events.detector, events.params
        functions = fitting.likelihood_functions(detector, DTYPE, config, settings.overdispersion)
        predict = pf.expected_function(detector, DTYPE, config=config)
        window = tuple(float(x) for x in config.window)
        energy_range = functions.emission("mu-").energy_range

        @jax.jit
        def scores(local, frame, reference, data):
            def per_sensor(y):
                prediction = predict(data.params, track_from_local(frame, y), None,
                                     reference, emission=data.emission, arrays=data.sensors)
                return dense_sensor_nll(prediction, data.hit, data.charge, data.time,
                                        data.dark_rate, data.spe_width, window,
                                        overdispersion=settings.overdispersion)
            return jax.jacfwd(per_sensor)(local)

        def parts(track, data, reference):
            """(charge, time) terms of the negative log-likelihood at ``track``, the rays
            of the indirect light fixed by ``reference`` (one ray sample for the truth
            and the fit: with another, the difference would carry the rays' noise)."""
            cast = fitting.cast_track(track, DTYPE)
            frame = fit_frame(detector.shape, track.direction, energy_range, "mu-", 0.0, DTYPE)
            free = free_from_track(frame, cast)
            reference = fitting.cast_track(reference, DTYPE)
            full = float(functions.value(free, frame, reference, data, 1.0))
            charge = float(functions.value(free, frame, reference, data, 0.0))
            return charge, full - charge

        for k in range(args.first, min(args.first + args.count, len(events))):
            event = events[k]
            truth = pf.Track("mu-", event.truth.position, event.truth.direction,
                             event.truth.energy, event.truth.time)
            result = reconstruct(detector, params, event, "mu-", config=config,
                                 settings=settings)
            row = {"event": k, "overdispersion": settings.overdispersion, "rays": config.n_rays,
                   "fits": settings.fits,
                   "seconds": result.seconds, "evaluations": result.evaluations,
                   "converged": result.converged, "failure": result.failure,
                   "nll": result.nll, "position": result.position.tolist(),
                   "direction": result.direction.tolist(), "energy": result.energy,
                   "time": result.time, "covariance": result.covariance.tolist(),
                   "truth": {"position": np.asarray(truth.position).tolist(),
                             "direction": np.asarray(truth.direction).tolist(),
                             "energy": float(truth.energy), "time": float(truth.time)}}
            if result.failure is None:
                fitted = pf.Track("mu-", result.position, result.direction, result.energy,
                                  result.time)
                data = fitting.event_data(detector, params, event, DTYPE, functions)
                data = dataclasses.replace(data, emission=functions.emission("mu-"))
                cast = fitting.cast_track(fitted, DTYPE)
                frame = fit_frame(detector.shape, fitted.direction, energy_range, "mu-",
                                  0.0, DTYPE)
                jacobian = np.asarray(scores(local_from_track(cast, DTYPE), frame, cast,
                                             data), np.float64)
                inverse = np.asarray(result.covariance)
                row["sandwich"] = (inverse @ (jacobian.T @ jacobian) @ inverse).tolist()
                (q_truth, t_truth), (q_fit, t_fit) = (parts(truth, data, fitted),
                                                        parts(fitted, data, fitted))
                row["nll_excess_charge"] = q_truth - q_fit
                row["nll_excess_time"] = t_truth - t_fit
            out.write(json.dumps(row) + "\n")
            out.flush()
            print(k, f"{result.seconds:.0f} s", result.failure or "", flush=True)


if __name__ == "__main__":
    main()
