"""The energy of fitted muons refitted with a free scale of the light's extent.

For the converged mu- fits of an e/mu study (``examples/reconstruction/sk_mu_e.py``:
its event file and its reconstruction file, or that file's ``.partial``), the energy is
fitted again at the reported track, its other coordinates held, three ways: alone
("fixed": the extent as the model has it), with the extent scale lambda free ("free",
``sk_muon_extent_scale.Stretched``) and with a Gaussian prior of 4 % on ln lambda
("prior4": the extent's fluctuation, ``light_extent_fluctuation.py``).

    python studies/reconstruction/sk_muon_extent_refit.py EVENTS.h5 RECO.h5 \
        [--events 120] [--out rows.jsonl]

Prints the 68 % quantile of |E/E_true - 1|, the median bias and the 68 % spread about
it for the reported energies and the three refits.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import h5py
import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from sk_muon_extent_scale import Stretched  # the study beside this one

import photonflow as pf
from photonflow.reconstruction import fit
from photonflow.reconstruction.coordinates import fit_frame, free_from_track, track_from_free
from photonflow.reconstruction.minimisers import cast_track, staged_data
from photonflow.reconstruction.settings import RecoSettings

#: (name, prior width on ln lambda): 0 free, None held at 1.
REFITS = (("fixed", None), ("free", 0.0), ("prior4", 0.04))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("events", type=Path)
    parser.add_argument("reco", type=Path)
    parser.add_argument("--events", dest="count", type=int, default=120)
    parser.add_argument("--out", default=None, help="per-event rows (JSON lines)")
    args = parser.parse_args()
    config = pf.TransportConfig(n_rays=1024, emission_model="tables")
    dtype = jnp.float32
    rows = []
    with pf.read_events(args.events) as events, h5py.File(args.reco, "r") as reco:
        detector, params = events.detector, events.params
        functions = fit.likelihood_functions(detector, dtype, config)
        model = functions.emission("mu-")

        def nll(theta, start, frame, reference, data, width):
            free = start.at[6].add(theta[0])
            stretched = dataclasses.replace(data, emission=Stretched(model,
                                                                     jnp.exp(theta[1])))
            prior = jnp.where(width > 0, 0.5 * (theta[1] / jnp.where(width > 0, width, 1.0))
                              ** 2, 0.0)
            return functions.value(free, frame, reference, stretched,
                                   jnp.ones((), dtype)) + prior

        value_and_grad = jax.jit(jax.value_and_grad(nll))
        for i in range(min(args.count, len(reco["reco/event"]))):
            if reco["reco/particle"][i] != b"mu-" or not reco["reco/converged"][i]:
                continue
            track = pf.Track("mu-", reco["reco/position"][i], reco["reco/direction"][i],
                             float(reco["reco/energy"][i]), float(reco["reco/time"][i]))
            frame = fit_frame(detector.shape, np.asarray(track.direction),
                              model.energy_range, "mu-", 0.0, dtype)
            reference = cast_track(track, dtype)
            start = free_from_track(frame, reference)
            data = dataclasses.replace(fit.event_data(detector, params, events[i], dtype,
                                                      functions), emission=model)
            data = staged_data(functions, data, reference, RecoSettings(), slopes=False)
            row = {"event": i, "true": float(reco["truth/energy"][i]),
                   "fit": float(track.energy)}
            for name, width in REFITS:
                def objective(theta, width=width, start=start, frame=frame,
                              reference=reference, data=data):
                    full = np.array([theta[0], 0.0 if width is None else theta[1]])
                    value, gradient = value_and_grad(
                        jnp.asarray(full, dtype), start, frame, reference, data,
                        jnp.asarray(width or 0.0, dtype))
                    gradient = np.asarray(gradient, np.float64)
                    if width is None:
                        gradient[1] = 0.0
                    return float(value), gradient

                result = scipy.optimize.minimize(objective, [0.0, 0.0], jac=True,
                                                 method="L-BFGS-B")
                row[name] = float(track_from_free(frame, start.at[6].add(result.x[0])).energy)
                row[name + "_lambda"] = float(np.exp(result.x[1]))
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.out:
        with open(args.out, "w") as out:
            out.writelines(json.dumps(row) + "\n" for row in rows)
    for key in ("fit", *(name for name, _ in REFITS)):
        error = np.array([row[key] / row["true"] - 1.0 for row in rows])
        bias = np.median(error)
        print(f"{key}: 68 % {100 * np.percentile(np.abs(error), 68):.2f} %, median bias"
              f" {100 * bias:+.2f} %, spread {100 * np.percentile(np.abs(error - bias), 68):.2f} %")


if __name__ == "__main__":
    main()
