"""How much the extent of a particle's light fluctuates from event to event: 40
generator runs (water, default settings) of mu- at 300, 1,000 and 3,000 MeV and e- at
100, 500 and 2,000 MeV, each giving the mean emission distance of its photons along the
initial direction, the primary's track length and its photon count.

    python studies/reconstruction/light_extent_fluctuation.py

Prints their relative rms and the correlation of the mean distance with the count:
the width a prior on the emission model's extent scale would have
(``sk_muon_extent_scale.py``).
"""

from __future__ import annotations

import numpy as np

from photonflow.generator import generate
from photonflow.generator.track import Track

RUNS = 40
ENERGIES = {"mu-": (300.0, 1000.0, 3000.0), "e-": (100.0, 500.0, 2000.0)}


def main() -> None:
    for particle, energies in ENERGIES.items():
        for energy in energies:
            runs = [generate(Track(particle, [0, 0, 0], [0, 0, 1], energy, 0.0), seed)
                    for seed in range(RUNS)]
            distance = np.array([run.position[:, 2].mean() for run in runs])
            length = np.array([float(run.tracks.length[0]) for run in runs])
            count = np.array([len(run) for run in runs], float)
            rms = {name: 100 * x.std(ddof=1) / x.mean()
                   for name, x in (("distance", distance), ("length", length),
                                   ("count", count))}
            print(f"{particle} {energy:5.0f} MeV: mean emission distance {distance.mean():.3f}"
                  f" m, rms {rms['distance']:.2f} %; primary length rms {rms['length']:.2f} %;"
                  f" photons rms {rms['count']:.2f} %; correlation of the distance with the"
                  f" count {np.corrcoef(distance, count)[0, 1]:+.2f}")


if __name__ == "__main__":
    main()
