"""Does a free scale of the light's extent decouple a muon's energy from its range?

40 events sampled at one 1 GeV muon in SK (the track of
``sk_muon_light_fluctuation.py``; the generator and the sampled mode, the preset's
parameters), each fitted in its energy alone (vertex, time and direction at the truth,
the indirect light held at the truth without slopes, the tables emission model) twice:
with the model as it is, and with the model's extent S(E) scaled by a free factor
lambda (the density per metre divided by it, so that the yield stays the model's at E).

    python studies/reconstruction/sk_muon_extent_scale.py [--events 40] [--out rows.jsonl]

Prints the mean and rms of the fitted energies of both fits, and lambda's.
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

import photonflow as pf
from photonflow.emission.moments import TabulatedSlice
from photonflow.pytree import pytree_dataclass
from photonflow.reconstruction import fit
from photonflow.reconstruction.coordinates import fit_frame, free_from_track, track_from_free
from photonflow.reconstruction.minimisers import cast_track, staged_data
from photonflow.reconstruction.settings import RecoSettings
from photonflow.transport.pseudo_data import sample_events

TRUTH = pf.Track("mu-", [0.0, 0.0, 0.0], [0.6, 0.0, 0.8], 1000.0, 0.0)


@pytree_dataclass
class Stretched:
    """A tables emission model whose extent is scaled by ``scale`` at every energy."""

    model: object
    scale: jax.Array

    def __getattr__(self, name):
        if name in ("model", "scale"):
            raise AttributeError(name)
        return getattr(self.model, name)

    def at(self, energy):
        piece = self.model.at(energy)
        inner = dataclasses.replace(piece.slice, extent=piece.slice.extent * self.scale,
                                    scale=piece.slice.scale / self.scale)
        return TabulatedSlice(inner, piece.log_distance, piece.table_cos, piece.moment_root)


def truth_pieces():
    """SK, its preset parameters, the transport settings (1,024 rays, the tables), the
    fit's float32 likelihood functions, the mu- emission model, the fit frame at
    ``TRUTH``'s direction, ``TRUTH`` as the reference track and its free coordinates."""
    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    config = pf.TransportConfig(n_rays=1024, emission_model="tables")
    functions = fit.likelihood_functions(detector, jnp.float32, config)
    model = functions.emission("mu-")
    frame = fit_frame(detector.shape, np.asarray(TRUTH.direction), model.energy_range,
                      "mu-", 0.0, jnp.float32)
    reference = cast_track(TRUTH, jnp.float32)
    return (detector, params, config, functions, model, frame, reference,
            free_from_track(frame, reference))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=40)
    parser.add_argument("--out", default=None, help="per-event rows (JSON lines)")
    args = parser.parse_args()
    detector, params, config, functions, model, frame, reference, start = truth_pieces()
    dtype = jnp.float32

    def nll(theta, data):  # theta: (shift of the free energy coordinate, log lambda)
        free = start.at[6].add(theta[0])
        stretched = dataclasses.replace(data, emission=Stretched(model, jnp.exp(theta[1])))
        return functions.value(free, frame, reference, stretched, jnp.ones((), dtype))

    value_and_grad = jax.jit(jax.value_and_grad(nll))

    def energy(shift):
        return float(track_from_free(frame, start.at[6].add(shift)).energy)

    rows = []
    for index, event in enumerate(sample_events(detector, params, TRUTH, 99, args.events,
                                                config=config)):
        data = dataclasses.replace(fit.event_data(detector, params, event, dtype, functions),
                                   emission=model)
        data = staged_data(functions, data, reference, RecoSettings(), slopes=False)

        def objective(theta, fixed, data):
            full = np.array([theta[0], 0.0 if fixed else theta[1]])
            value, gradient = value_and_grad(jnp.asarray(full, dtype), data)
            gradient = np.asarray(gradient, np.float64)
            return float(value), gradient[:1] if fixed else gradient

        alone = scipy.optimize.minimize(objective, [0.0], args=(True, data), jac=True,
                                        method="L-BFGS-B")
        both = scipy.optimize.minimize(objective, [alone.x[0], 0.0], args=(False, data),
                                       jac=True, method="L-BFGS-B")
        row = {"event": index, "energy_fixed_extent": energy(alone.x[0]),
               "energy_free_extent": energy(both.x[0]), "extent_scale": float(np.exp(both.x[1])),
               "nll_gain": float(alone.fun - both.fun), "charge": float(np.sum(event.charge))}
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.out:
        with open(args.out, "w") as out:
            out.writelines(json.dumps(row) + "\n" for row in rows)
    for key in ("energy_fixed_extent", "energy_free_extent"):
        error = np.array([row[key] for row in rows]) / TRUTH.energy - 1.0
        print(f"{key}: mean {100 * error.mean():+.2f} %, rms {100 * error.std(ddof=1):.2f} %")
    scale = np.array([row["extent_scale"] for row in rows])
    print(f"extent_scale: mean {scale.mean():.4f}, rms {100 * scale.std(ddof=1):.2f} %")


if __name__ == "__main__":
    main()
