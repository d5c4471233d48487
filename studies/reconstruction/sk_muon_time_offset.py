"""Is the expected mode's light of a muon early or late against the sampled mode's?

20 events sampled at one 1 GeV muon in SK (the track of
``sk_muon_light_fluctuation.py``; the generator and the sampled mode, the preset's
parameters), each fitted in its start time alone, then in time and energy, the other
coordinates at the truth (the indirect light held at the truth without slopes, the
tables emission model).

    python studies/reconstruction/sk_muon_time_offset.py [--events 20]

Prints the mean fitted time (ns; positive: the model's light arrives early, so the fit
starts the track later) with its standard error.
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from sk_muon_extent_scale import TRUTH, truth_pieces  # the study beside this one

from photonflow.reconstruction import fit
from photonflow.reconstruction.minimisers import staged_data
from photonflow.reconstruction.settings import RecoSettings
from photonflow.transport.pseudo_data import sample_events


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=20)
    args = parser.parse_args()
    detector, params, config, functions, model, frame, reference, start = truth_pieces()
    dtype = jnp.float32

    def nll(theta, data):  # theta: (time shift ns, shift of the free energy coordinate)
        free = start.at[3].add(theta[0]).at[6].add(theta[1])
        return functions.value(free, frame, reference, data, jnp.ones((), dtype))

    value_and_grad = jax.jit(jax.value_and_grad(nll))
    shifts = {"time alone": [], "time and energy": []}
    for event in sample_events(detector, params, TRUTH, 99, args.events, config=config):
        data = dataclasses.replace(fit.event_data(detector, params, event, dtype, functions),
                                   emission=model)
        data = staged_data(functions, data, reference, RecoSettings(), slopes=False)
        for name, size in (("time alone", 1), ("time and energy", 2)):
            def objective(theta, size=size, data=data):
                full = np.zeros(2)
                full[:size] = theta
                value, gradient = value_and_grad(jnp.asarray(full, dtype), data)
                return float(value), np.asarray(gradient, np.float64)[:size]

            result = scipy.optimize.minimize(objective, np.zeros(size), jac=True,
                                             method="L-BFGS-B")
            shifts[name].append(float(result.x[0]))
    for name, values in shifts.items():
        values = np.asarray(values)
        print(f"{name}: mean {values.mean():+.3f} ns, standard error"
              f" {values.std(ddof=1) / np.sqrt(values.size):.3f} ns")


if __name__ == "__main__":
    main()
