"""How much the light of one SK track fluctuates from event to event, sensor by sensor:
variance / mean of the p.e. counts and the number of hit sensors against Poisson, by
the expected count (studies/reconstruction-validation.md).

    python studies/reconstruction/sk_track_overdispersion.py [--events 100]

One 1 GeV mu- from the centre along +x; generator + sampled transport, p.e. counted
before the charge response, no dark noise; expected mode with 4,096 rays.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

import photonflow as pf
from photonflow.transport.pseudo_data import sample_track_tally
from photonflow.transport.tracks import track_light

BINS = ((0.0, 0.3), (0.3, 1.0), (1.0, 3.0), (3.0, 10.0), (10.0, 30.0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=100)
    args = parser.parse_args()
    detector = pf.load_detector("SK")
    base = pf.default_params(detector)
    params = base.replace(dark_rate=base.dark_rate * 0)
    track = pf.Track("mu-", [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 1000.0, 0.0)
    light = track_light(detector)
    counts = np.zeros((args.events, detector.n_sensors))
    for index in range(args.events):
        tally = sample_track_tally(detector, params, track, jax.random.key(index), 7, index,
                                   light)
        counts[index] = np.asarray(tally.n_pe)
    expected = np.asarray(pf.expected(detector, params, track,
                                      config=pf.TransportConfig(n_rays=4096)).charge, float)
    mean, variance = counts.mean(axis=0), counts.var(axis=0, ddof=1)
    hit = (counts > 0).mean(axis=0)
    print(f"total p.e.: sampled {mean.sum():.0f}, expected {expected.sum():.0f}")
    print(f"hit sensors per event: sampled {hit.sum():.1f}, Poisson of the sampled means "
          f"{np.sum(1 - np.exp(-mean)):.1f}, Poisson of the expected "
          f"{np.sum(1 - np.exp(-expected)):.1f}")
    for low, high in BINS:
        chosen = (expected >= low) & (expected < high)
        excess = (variance[chosen] - mean[chosen]).sum() / (mean[chosen] ** 2).sum()
        print(f"expected {low:4.1f}-{high:4.1f} p.e. ({chosen.sum():5d} sensors): "
              f"variance/mean {variance[chosen].sum() / mean[chosen].sum():.2f}, "
              f"r = (var - mean) / mean^2 {excess:.2f}, hit sensors {hit[chosen].sum():.1f} "
              f"(Poisson {np.sum(1 - np.exp(-mean[chosen])):.1f})")


if __name__ == "__main__":
    main()
