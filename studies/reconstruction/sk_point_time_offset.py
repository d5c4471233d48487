"""The time test of ``sk_muon_time_offset.py`` with a point source: is the expected
mode's light early against the sampled mode's without a track?

20 events of an isotropic source of 10^5 photons at (1.0, 0.0, 1.3) m in SK (near the
middle of that study's muon; the sampled mode, the preset's parameters, 1,024 rays),
each fitted in the source's time alone with the expected mode and ``photonflow.nll``.

    python studies/reconstruction/sk_point_time_offset.py

Prints the mean fitted time (ns; positive: the model's light arrives early) with its
standard error.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

import photonflow as pf
from photonflow.transport.pseudo_data import sample_events

POSITION = (1.0, 0.0, 1.3)
PHOTONS = 1.0e5
EVENTS = 20


def main() -> None:
    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    config = pf.TransportConfig(n_rays=1024)
    position = jnp.asarray(POSITION)
    key = jax.random.key(3)

    def nll(time, event):
        source = pf.IsotropicSource(position=position, n_photons=PHOTONS, time=time)
        return pf.nll(pf.expected(detector, params, source, config=config, key=key), event,
                      params)

    value_and_grad = jax.jit(jax.value_and_grad(nll))
    truth = pf.IsotropicSource(position=position, n_photons=PHOTONS, time=0.0)
    shifts = []
    for event in sample_events(detector, params, truth, 5, EVENTS, config=config):
        def objective(theta, event=event):
            value, gradient = value_and_grad(jnp.asarray(theta[0], jnp.float32), event)
            return float(value), np.atleast_1d(np.asarray(gradient, np.float64))

        shifts.append(float(scipy.optimize.minimize(objective, [0.0], jac=True,
                                                    method="L-BFGS-B").x[0]))
    shifts = np.asarray(shifts)
    print(f"point source, time alone: mean {shifts.mean():+.3f} ns, standard error"
          f" {shifts.std(ddof=1) / np.sqrt(shifts.size):.3f} ns")


if __name__ == "__main__":
    main()
