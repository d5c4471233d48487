"""How much the light and the range of one 1 GeV muon in SK fluctuate from event to
event: the total charge of 40 events sampled at one track (the generator and the
sampled mode, the preset's parameters), and the primary's track length and the number
of Cherenkov photons of 40 generator runs.

    python studies/reconstruction/sk_muon_light_fluctuation.py

Prints the relative rms of each (and the Poisson share of the total charge's).
"""

from __future__ import annotations

import numpy as np

import photonflow as pf
from photonflow.generator import generate
from photonflow.generator.track import Track as GeneratorTrack
from photonflow.transport.pseudo_data import sample_events

EVENTS = 40
START, DIRECTION, ENERGY = [0.0, 0.0, 0.0], [0.6, 0.0, 0.8], 1000.0


def main() -> None:
    detector = pf.load_detector("SK")
    params = pf.default_params(detector)
    track = pf.Track("mu-", START, DIRECTION, ENERGY, 0.0)
    config = pf.TransportConfig(n_rays=1024, emission_model="tables")
    charge = np.array([float(np.sum(event.charge)) for event in
                       sample_events(detector, params, track, 99, EVENTS, config=config)])
    print(f"total charge: mean {charge.mean():.0f} p.e., rms"
          f" {100 * charge.std(ddof=1) / charge.mean():.2f} % (Poisson alone"
          f" {100 / np.sqrt(charge.mean()):.2f} %)")
    runs = [generate(GeneratorTrack("mu-", START, DIRECTION, ENERGY, 0.0), seed)
            for seed in range(EVENTS)]
    length = np.array([float(run.tracks.length[0]) for run in runs])
    photons = np.array([len(run) for run in runs], float)
    print(f"range: mean {length.mean():.3f} m, rms {100 * length.std(ddof=1) / length.mean():.2f}"
          f" %; Cherenkov photons: rms {100 * photons.std(ddof=1) / photons.mean():.2f} %")


if __name__ == "__main__":
    main()
